"""Per-step cost of large-steps Adam on a ~10k-vertex mesh, and CG vs a sparse factorization.

1. The `(I + lambda L) x = b` solve alone (3 right-hand sides, float32):
   matrix-free Jacobi-PCG cold and warm-started (the warm start is the solution
   for a nearby `b`, as in an optimizer step) against scipy's sparse LU
   (`scipy.sparse.linalg.factorized`: factorize once per topology, then solve).
2. One `optimize_block` step (timed over a block after compiling it):
   the full step with `jaxgenus.render` and the optimizer-only part
   (image weights 0, bilaplacian only), with the CG iterations it took.

    python benchmarks/step_cost.py --subdivisions 5 --views 24 --views-per-step 6 --resolution 128 --steps 20
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl
import trimesh

import jaxgenus as jg
from _problem import stretched_fit


def best_of(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3, out


def scipy_matrix(f, n, lam):
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)
    lap = sp.diags(np.asarray(a.sum(axis=1)).ravel()) - a
    return (sp.eye(n) + lam * lap).tocsc()


def solver_table(mesh, repeats):
    v, f = mesh.to_numpy()
    n = len(v)
    lap = jg.geometry.uniform_laplacian(mesh.faces, mesh.vertex_capacity)
    rng = np.random.default_rng(0)
    x_true = np.asarray(mesh.vertices)
    x_near = x_true.copy()
    x_near[:n] += 1e-3 * rng.normal(size=(n, 3))  # a previous step's solution
    rows = []
    for lam in (1.0, 19.0, 100.0, 1e3, 1e4):
        b = jnp.asarray(x_true + lam * np.asarray(lap(jnp.asarray(x_true))), jnp.float32)
        solve = jax.jit(lambda b, x0: jg.optim.largesteps_solve(lap, b, lam, x0))
        cold_ms, (_, cold) = best_of(lambda: solve(b, jnp.zeros_like(b)), repeats)
        warm_ms, (_, warm) = best_of(lambda: solve(b, jnp.asarray(x_near)), repeats)
        a = scipy_matrix(f, n, lam)
        t0 = time.perf_counter()
        factor = spl.factorized(a)
        fact_ms = (time.perf_counter() - t0) * 1e3
        bn = np.asarray(b, np.float64)[:n]
        t0 = time.perf_counter()
        for _ in range(repeats):
            np.stack([factor(bn[:, c]) for c in range(3)], axis=1)
        sol_ms = (time.perf_counter() - t0) * 1e3 / repeats
        rows.append(
            f"| {lam:g} | {int(cold.iterations)} | {cold_ms:.1f} | {float(cold.residual):.1e} | "
            f"{int(warm.iterations)} | {warm_ms:.1f} | {fact_ms:.1f} | {sol_ms:.1f} |"
        )
    head = (
        "| lambda | PCG cold iters | PCG cold ms | true rel. residual (f32) | PCG warm iters | PCG warm ms | "
        "scipy LU factorize ms | scipy LU solve ms (3 rhs) |\n|---|---|---|---|---|---|---|---|"
    )
    return head + "\n" + "\n".join(rows)


def step_table(mesh, args):
    cams, targets, plan = stretched_fit(mesh, args.views, args.resolution)
    rows = []
    settings = [
        ("full step (render alpha+normal)", jg.LossWeights()),
        ("optimizer only (bilaplacian, no render)", jg.LossWeights(alpha=0.0, normal=0.0, bilaplacian=1e-3)),
    ]
    for name, weights in settings:
        for lam in (19.0, 1e4):
            opts = jg.OptimizeOptions(
                lambda_=lam, weights=weights, views_per_step=args.views_per_step, render=jg.RenderSettings(plan=plan),
                learning_rate=3e-2, adam_quantile=1.0,
            )
            state = jg.optim.init_optimizer_state(mesh, jax.random.key(0))
            t0 = time.perf_counter()
            state, rec = jax.block_until_ready(jg.optim.optimize_block(state, cams, targets, n_steps=args.steps, options=opts))
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            state, rec = jax.block_until_ready(jg.optim.optimize_block(state, cams, targets, n_steps=args.steps, options=opts))
            ms = (time.perf_counter() - t0) * 1e3 / args.steps
            rec = jax.tree.map(np.asarray, rec)
            rows.append(
                f"| {name} | {lam:g} | {ms:.1f} | {first - ms * args.steps / 1e3:.1f} | "
                f"{rec['cg_iterations_forward'].mean():.1f} | {rec['cg_iterations_backward'].mean():.1f} | "
                f"{rec['cg_residual'].max():.1e} | {int(rec['status'].max())} |"
            )
    head = (
        "| step | lambda | ms / step | compile s | CG iters x (mean) | CG iters grad (mean) | max rel. residual | "
        "worst status |\n|---|---|---|---|---|---|---|---|"
    )
    return head + "\n" + "\n".join(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subdivisions", type=int, default=5, help="icosphere subdivisions (5: 10242 vertices)")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--views-per-step", type=int, default=6)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    m = trimesh.creation.icosphere(subdivisions=args.subdivisions, radius=0.8)
    vcap, fcap = jg.geometry.capacity_bucket(len(m.faces))
    mesh = jg.Mesh.from_numpy(m.vertices, m.faces, capacity=(vcap, fcap))
    print(f"mesh: {int(mesh.n_vertices)} vertices, {int(mesh.n_faces)} faces, capacity {vcap}/{fcap}\n")
    print(solver_table(mesh, args.repeats) + "\n")
    print(
        f"{args.views_per_step} of {args.views} views per step at {args.resolution}^2, {args.steps} steps timed\n"
    )
    print(step_table(mesh, args))


if __name__ == "__main__":
    main()
