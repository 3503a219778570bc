"""lineax CG (`jg.optim.largesteps_solve`) against a hand-written Jacobi-PCG, alone and inside an optimizer step.

`jg.optim.largesteps_solve` solves `(I + lambda L) x = b` with `lineax.CG` (vmapped over
the 3 coordinate columns, Jacobi preconditioner, warm start). `hand_pcg` below
is the hand-written Jacobi-preconditioned CG the library used before, with the
same stopping rule (per column, `||r_c|| <= rtol ||b_c||` by the CG recursion),
the same warm-start rule and the same `SolveInfo`. Meshes: icosphere (2562
vertices), torus (4992), icosphere (10242), padded to their capacity bucket.

1. One solve, jit-compiled, float32, rtol 1e-6: cold (x0 = 0) and warm (x0 =
   the solution plus 1e-3 noise per coordinate, as in `benchmarks/step_cost.py`).
2. One `optimize_block` step (a block of `--steps` steps, after compiling it):
   optimizer only (bilaplacian energy, no render) and the full step (alpha +
   normal images). The hand-written solver is put behind
   `jaxgenus.optim._optimize.largesteps_solve` for this measurement only; its blocks
   use `cg_max_iter=1999` (the library's 2000) so the two compile separately.

The two implementations are timed interleaved (A B A B ...), `--rounds` times;
the tables give the median (and the best) in milliseconds, the CG iterations,
the true relative residual and `converged`.

    python benchmarks/solve.py --rounds 7 --steps 10
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

import jaxgenus as jg
from _problem import stretched_fit
import jaxgenus.optim._optimize as optimize_module  # only to swap the solver for the step measurement


def hand_pcg(laplacian, b, lambda_=19.0, x0=None, *, rtol=1e-6, max_iter=2000):
    """Jacobi-PCG per coordinate column in one `lax.while_loop` (the library's former solver)."""

    def matvec(v):
        return v + lambda_ * laplacian(v)

    def norms(r):
        return jnp.sqrt(jnp.sum(r * r, axis=0))

    inv_diag = (1.0 / (1.0 + lambda_ * laplacian.degree)).astype(b.dtype)[:, None]
    bnorm = norms(b)
    nonzero = bnorm > 0
    if x0 is None:
        x, r = jnp.zeros_like(b), b
    else:
        x = x0.astype(b.dtype)
        r = b - matvec(x)
        keep = nonzero & (norms(r) < bnorm)
        x, r = jnp.where(keep, x, 0.0), jnp.where(keep, r, b)
    tol2 = (rtol * bnorm) ** 2
    tiny = jnp.finfo(b.dtype).tiny

    def active(r):
        return nonzero & (jnp.sum(r * r, axis=0) > tol2)

    def cond(c):
        return (c[0] < max_iter) & jnp.any(active(c[2]))

    def body(c):
        k, x, r, p, rz = c
        on = active(r)
        ap = matvec(p)
        pap = jnp.sum(p * ap, axis=0)
        alpha = jnp.where(on & (pap > tiny), rz / jnp.where(pap > tiny, pap, 1.0), 0.0)
        x, r = x + alpha * p, r - alpha * ap
        z = inv_diag * r
        rz_new = jnp.sum(r * z, axis=0)
        beta = jnp.where(rz > tiny, rz_new / jnp.where(rz > tiny, rz, 1.0), 0.0)
        return k + 1, x, r, jnp.where(on, z + beta * p, p), rz_new

    z = inv_diag * r
    k, x, r, _, _ = jax.lax.while_loop(cond, body, (jnp.int32(0), x, r, z, jnp.sum(r * z, axis=0)))
    rel = jnp.max(jnp.where(nonzero, norms(b - matvec(x)) / jnp.where(nonzero, bnorm, 1.0), 0.0))
    finite = jnp.all(jnp.isfinite(bnorm)) & jnp.isfinite(rel)
    return x, jg.optim.SolveInfo(iterations=k, residual=rel, converged=~jnp.any(active(r)) & finite)


SOLVERS = {"lineax CG": jg.optim.largesteps_solve, "hand-written PCG": hand_pcg}


def meshes():
    out = []
    for name, m in [
        ("icosphere 4", trimesh.creation.icosphere(subdivisions=4, radius=0.8)),
        ("torus 96x52", trimesh.creation.torus(0.6, 0.25, major_sections=96, minor_sections=52)),
        ("icosphere 5", trimesh.creation.icosphere(subdivisions=5, radius=0.8)),
    ]:
        vcap, fcap = jg.geometry.capacity_bucket(len(m.faces))
        out.append((name, jg.Mesh.from_numpy(np.asarray(m.vertices), np.asarray(m.faces), capacity=(vcap, fcap))))
    return out


def timed(fn, reps):
    t0 = time.perf_counter()
    for _ in range(reps):
        out = jax.block_until_ready(fn())
    return (time.perf_counter() - t0) / reps * 1e3, out


def solve_rows(name, mesh, lam, rounds, reps):
    lap = jg.geometry.uniform_laplacian(mesh.faces, mesh.vertex_capacity)
    x = mesh.vertices
    n = int(mesh.n_vertices)
    b = jnp.where(mesh.vertex_mask[:, None], x + lam * lap(x), 0.0)
    noise = 1e-3 * jax.random.normal(jax.random.key(0), x.shape, x.dtype)
    starts = {"cold": jnp.zeros_like(b), "warm": jnp.where(mesh.vertex_mask[:, None], x + noise, 0.0)}
    fns = {k: jax.jit(lambda b, x0, f=f: f(lap, b, lam, x0, rtol=1e-6)) for k, f in SOLVERS.items()}
    compile_s, info = {}, {}
    for k, fn in fns.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn(b, starts["cold"]))
        compile_s[k] = time.perf_counter() - t0
    times = {(k, s): [] for k in fns for s in starts}
    for _ in range(rounds):
        for s, x0 in starts.items():
            for k, fn in fns.items():
                ms, (_, i) = timed(lambda: fn(b, x0), reps)
                times[k, s].append(ms)
                info[k, s] = i
    rows = []
    for (k, s), ts in times.items():
        i = info[k, s]
        rows.append(
            f"| {name} ({n}) | {lam:g} | {s} | {k} | {int(i.iterations)} | {float(i.residual):.1e} | "
            f"{bool(i.converged)} | {np.median(ts):.1f} | {min(ts):.1f} | {compile_s[k]:.1f} |"
        )
    return rows


def step_rows(name, mesh, args):
    cams, targets, plan = stretched_fit(mesh, args.views, args.resolution)
    settings = [
        ("optimizer only", jg.LossWeights(alpha=0.0, normal=0.0, bilaplacian=1e-3)),
        ("full step", jg.LossWeights()),
    ]
    rows = []
    original = optimize_module.largesteps_solve
    try:
        for label, weights in settings:
            opts = {
                k: jg.OptimizeOptions(
                    weights=weights,
                    views_per_step=args.views_per_step,
                    render=jg.RenderSettings(plan=plan),
                    learning_rate=3e-2,
                    adam_quantile=1.0,
                    cg_max_iter=2000 if k == "lineax CG" else 1999,
                )
                for k in SOLVERS
            }

            def run(k):
                optimize_module.largesteps_solve = SOLVERS[k] if k != "lineax CG" else original
                state = jg.optim.init_optimizer_state(mesh, jax.random.key(0))
                t0 = time.perf_counter()
                _, rec = jax.block_until_ready(
                    jg.optim.optimize_block(state, cams, targets, n_steps=args.steps, options=opts[k])
                )
                return (time.perf_counter() - t0) * 1e3 / args.steps, rec

            compile_s, recs, times = {}, {}, {k: [] for k in SOLVERS}
            for k in SOLVERS:
                t0 = time.perf_counter()
                run(k)
                compile_s[k] = time.perf_counter() - t0
            for _ in range(args.step_rounds):
                for k in SOLVERS:
                    ms, recs[k] = run(k)
                    times[k].append(ms)
            for k in SOLVERS:
                rec = jax.tree.map(np.asarray, recs[k])
                rows.append(
                    f"| {name} ({int(mesh.n_vertices)}) | {label} | {k} | {np.median(times[k]):.1f} | "
                    f"{min(times[k]):.1f} | {compile_s[k]:.1f} | {rec['cg_iterations_forward'].mean():.1f} | "
                    f"{rec['cg_iterations_backward'].mean():.1f} | {rec['cg_residual'].max():.1e} | "
                    f"{int(rec['status'].max())} |"
                )
    finally:
        optimize_module.largesteps_solve = original
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lambdas", default="19", help="comma-separated lambda values of the solve table")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rounds of the solve table")
    ap.add_argument("--reps", type=int, default=3, help="solves per timing")
    ap.add_argument("--steps", type=int, default=10, help="steps per timed optimize_block")
    ap.add_argument("--step-rounds", type=int, default=5, help="interleaved rounds of the step table")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--views-per-step", type=int, default=6)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--skip-steps", action="store_true", help="only the solve table")
    args = ap.parse_args()
    print(
        f"jax {jax.__version__} on {jax.default_backend()} ({platform.machine()}, {os.cpu_count()} CPUs), float32; "
        f"medians of interleaved rounds\n"
    )
    ms = meshes()
    print(
        "| mesh (vertices) | lambda | start | solver | CG iterations | true rel. residual | converged | "
        "ms median | ms best | compile s |\n|---|---|---|---|---|---|---|---|---|---|"
    )
    for name, mesh in ms:
        for lam in (float(s) for s in args.lambdas.split(",")):
            print("\n".join(solve_rows(name, mesh, lam, args.rounds, args.reps)), flush=True)
    if args.skip_steps:
        return
    print(
        f"\n{args.views_per_step} of {args.views} views per step at {args.resolution}^2, lambda 19, "
        f"{args.steps} steps per block, {args.step_rounds} interleaved rounds\n"
    )
    print(
        "| mesh (vertices) | step | solver | ms / step median | ms / step best | first block s (compile) | "
        "CG iters x (mean) | CG iters grad (mean) | max rel. residual | worst status |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    for name, mesh in ms:
        print("\n".join(step_rows(name, mesh, args)), flush=True)


if __name__ == "__main__":
    main()
