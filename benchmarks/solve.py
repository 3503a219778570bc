"""The large-steps solve: direct (the native sparse Cholesky factor) against lineax CG, alone and in a step.

`jg.optim.largesteps_solve` solves `(I + lambda L) x = b`. On the CPU `optimize_block`
factors the matrix once per block (`jg.optim.largesteps_factor`) and solves with the
factor; CG (`lineax.CG`, vmapped over the 3 columns, Jacobi preconditioner, warm start)
is what runs where there is no factor (another platform, a factor too large for its
buffer). Meshes: icosphere (2562 vertices), torus (4992), icosphere (10242), padded to
their capacity bucket.

1. One solve, jit-compiled, float32 (CG at rtol 1e-6): cold (x0 = 0) and warm (x0 = the
   solution plus 1e-3 noise per coordinate). The factor's own time is its column.
2. One `optimize_block` step (a block of `--steps` steps, after compiling it): optimizer
   only (bilaplacian energy, no render) and the full step (alpha + normal images). CG is
   forced for this measurement only by a factor buffer of one entry (`ok` False).

The two are timed interleaved (A B A B ...), `--rounds` times; the tables give the median
(and the best) in milliseconds, the CG iterations, the true relative residual and
`converged`; `--plot` writes the step times as a bar chart.

    python benchmarks/solve.py --rounds 7 --steps 10 --plot benchmarks/solve.png
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
import jaxgenus.optim._optimize as optimize_module  # only to force CG for the step measurement

SOLVERS = ("direct", "lineax CG")


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
    factor_fn = jax.jit(lambda lap: jg.optim.largesteps_factor(lap, lam))
    factor = jax.block_until_ready(factor_fn(lap))
    factor_ms = min(timed(lambda: factor_fn(lap), reps)[0] for _ in range(rounds))
    fns = {
        "direct": jax.jit(lambda b, x0: jg.optim.largesteps_solve(lap, b, lam, x0, factor=factor)),
        "lineax CG": jax.jit(lambda b, x0: jg.optim.largesteps_solve(lap, b, lam, x0, rtol=1e-6)),
    }
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
        f_col = f"{factor_ms:.1f} ({int(factor.entries) / n:.0f}/vertex)" if k == "direct" else "-"
        rows.append(
            f"| {name} ({n}) | {lam:g} | {s} | {k} | {f_col} | {int(i.iterations)} | {float(i.residual):.1e} | "
            f"{bool(i.converged)} | {np.median(ts):.1f} | {min(ts):.1f} | {compile_s[k]:.1f} |"
        )
    return rows


def step_rows(name, mesh, args):
    cams, targets, plan = stretched_fit(mesh, args.views, args.resolution)
    settings = [
        ("optimizer only", jg.LossWeights(alpha=0.0, normal=0.0, bilaplacian=1e-3)),
        ("full step", jg.LossWeights()),
    ]
    rows, medians = [], {}
    original = optimize_module.largesteps_factor
    no_factor = lambda lap, lam: original(lap, lam, capacity=1)
    try:
        for label, weights in settings:
            opts = {
                k: jg.OptimizeOptions(
                    weights=weights,
                    views_per_step=args.views_per_step,
                    render=jg.RenderSettings(plan=plan),
                    learning_rate=3e-2,
                    adam_quantile=1.0,
                    cg_max_iter=2000 if k == "direct" else 1999,  # two programs, compiled apart
                )
                for k in SOLVERS
            }

            def run(k):
                optimize_module.largesteps_factor = original if k == "direct" else no_factor
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
                medians[name, label, k] = np.median(times[k])
                rec = jax.tree.map(np.asarray, recs[k])
                rows.append(
                    f"| {name} ({int(mesh.n_vertices)}) | {label} | {k} | {np.median(times[k]):.1f} | "
                    f"{min(times[k]):.1f} | {compile_s[k]:.1f} | {rec['cg_iterations_forward'].mean():.1f} | "
                    f"{rec['cg_iterations_backward'].mean():.1f} | {rec['cg_residual'].max():.1e} | "
                    f"{int(rec['status'].max())} |"
                )
    finally:
        optimize_module.largesteps_factor = original
    return rows, medians


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
    ap.add_argument("--plot", default=None, help="write the step times (ms) as a bar chart to this PNG")
    args = ap.parse_args()
    print(
        f"jax {jax.__version__} on {jax.default_backend()} ({platform.machine()}, {os.cpu_count()} CPUs), float32; "
        f"medians of interleaved rounds\n"
    )
    ms = meshes()
    print(
        "| mesh (vertices) | lambda | start | solver | factor ms (entries) | CG iterations | true rel. residual | "
        "converged | ms median | ms best | compile s |\n|---|---|---|---|---|---|---|---|---|---|---|"
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
    medians = {}
    for name, mesh in ms:
        rows, m = step_rows(name, mesh, args)
        medians.update(m)
        print("\n".join(rows), flush=True)
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        groups = sorted({(n, label) for n, label, _ in medians}, key=lambda g: (g[1], g[0]))
        fig, ax = plt.subplots(figsize=(8, 3.5))
        for i, k in enumerate(SOLVERS):
            ax.bar(np.arange(len(groups)) + 0.4 * i, [medians[g + (k,)] for g in groups], 0.4, label=k)
        ax.set_xticks(np.arange(len(groups)) + 0.2, [f"{n}\n{label}" for n, label in groups], fontsize=7)
        ax.set_ylabel("ms per step (median)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
