"""Benchmark of `jaxgenus.render`: forward + backward time per iteration.

Each cell (faces x views x resolution) runs in its own subprocess so its peak RSS
is its own. Prints a markdown table (and writes it to --out if given) with:
fwd+bwd ms (min over --iters), evaluated pixel-face pairs, ns/pair, peak RSS,
compile time, the pairs that must be evaluated (pixels within the blur radius of
each visible face), and the ratio of the time to the arithmetic limit
`required pairs x FLOP_PER_PAIR / measured f32 matmul GFLOP/s`.

    python benchmarks/raster.py --quick           # 10k x 12 x 128 and 40k x 36 x 256
    python benchmarks/raster.py                   # the full 3 x 3 x 3 grid
    python benchmarks/raster.py --cells 10000x12x128 2000x4x64 --channels alpha
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

# minimal work per pair: forward ~110 flop, backward ~155 (exp/log1p as ~15 each);
# see docs/rendering.md
FLOP_PER_PAIR = 265


def torus(n_faces: int, big: float = 1.0, small: float = 0.4):
    import numpy as np

    nv = max(3, int(round(math.sqrt(n_faces / 4))))
    nu = max(3, n_faces // (2 * nv))
    a, b = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    th = 2 * np.pi * a.ravel() / nu
    ph = 2 * np.pi * b.ravel() / nv
    verts = np.stack(
        [(big + small * np.cos(ph)) * np.cos(th), small * np.sin(ph), (big + small * np.cos(ph)) * np.sin(th)], 1
    )
    i00 = a * nv + b
    i10 = ((a + 1) % nu) * nv + b
    i01 = a * nv + (b + 1) % nv
    i11 = ((a + 1) % nu) * nv + (b + 1) % nv
    faces = np.concatenate([np.stack([i00, i01, i11], -1).reshape(-1, 3), np.stack([i00, i11, i10], -1).reshape(-1, 3)])
    return verts, faces


def matmul_gflops(n: int = 2048, reps: int = 5) -> float:
    import jax
    import jax.numpy as jnp

    x = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    f = jax.jit(lambda a: a @ a)
    f(x).block_until_ready()
    best = math.inf
    for _ in range(reps):
        t = time.perf_counter()
        f(x).block_until_ready()
        best = min(best, time.perf_counter() - t)
    return 2 * n**3 / best / 1e9


def required_pairs(mesh, cams, sigma: float) -> int:
    """Pixels within the blur radius of each visible face (Minkowski area), all views."""
    import numpy as np

    import jaxgenus as jg

    r = sigma * math.log(1e4)  # blur radius in px (jaxgenus.rendering._render.blur_radius)
    v, f = mesh.to_numpy()
    uv, z = jg.project(cams, v, return_depth=True)
    uv, z = np.asarray(uv), np.asarray(z)
    total = 0.0
    for n in range(len(cams)):
        xc = v @ np.asarray(cams.rotation[n]).T + np.asarray(cams.translation[n])
        tri = xc[f]
        front = np.einsum("fi,fi->f", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri[:, 0]) < 0
        t2 = uv[n][f][front]
        e1, e2 = t2[:, 1] - t2[:, 0], t2[:, 2] - t2[:, 0]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        per = sum(np.linalg.norm(t2[:, (k + 1) % 3] - t2[:, k], axis=1) for k in range(3))
        total += np.sum(area + per * r + math.pi * r * r)
    return int(total)


def run_cell(n_faces: int, n_views: int, res: int, channels: tuple[str, ...], iters: int, sigma: float,
             mode: str = "default") -> dict:
    import resource

    import jax
    import jax.numpy as jnp

    import jaxgenus as jg

    v, f = torus(n_faces)
    mesh = jg.Mesh.from_numpy(v, f, capacity=jg.geometry.capacity_bucket(len(f))[1])
    cams = jg.sphere_cameras(n_views, radius=4.5, fov_deg=40.0, resolution=res)
    # "default": what a user writes, render() under jit with no plan; "plan": a plan from the geometry
    plan = jg.rendering.plan_render(mesh, cams, sigma=sigma) if mode == "plan" else None
    target = jnp.zeros((n_views, res, res, sum(jg.rendering.CHANNEL_SIZES[c] for c in channels)), jnp.float32)

    def loss(verts):
        m = jg.Mesh(verts, mesh.faces, mesh.n_vertices, mesh.n_faces)
        img, info = jg.render(m, cams, channels=channels, sigma=sigma, plan=plan, return_info=True)
        return jnp.sum(jnp.abs(img - target)), info.n_overflow

    step = jax.jit(jax.value_and_grad(loss, has_aux=True))
    t0 = time.perf_counter()
    compiled = step.lower(mesh.vertices).compile()
    compile_s = time.perf_counter() - t0
    (val, overflow), g = compiled(mesh.vertices)
    g.block_until_ready()
    best = math.inf
    for _ in range(iters):
        t = time.perf_counter()
        (val, overflow), g = compiled(mesh.vertices)
        g.block_until_ready()
        best = min(best, time.perf_counter() - t)
    pairs = plan.pairs_per_view() * n_views if plan is not None else required_pairs(mesh, cams, sigma)
    return {
        "faces": len(f),
        "views": n_views,
        "res": res,
        "window": (f"{plan.window}" + (f"+{plan.big_window}" if plan.max_big_faces else "")) if plan else "none",
        "ms": best * 1e3,
        "pairs": pairs,
        "required": required_pairs(mesh, cams, sigma),
        "rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
        "compile_s": compile_s,
        "overflow": int(overflow),
        "finite": bool(jnp.all(jnp.isfinite(g))),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="only 10k x 12 x 128 and 40k x 36 x 256")
    ap.add_argument("--cells", nargs="*", help="cells as FACESxVIEWSxRES, e.g. 10000x12x128")
    ap.add_argument("--faces", nargs="*", type=int, default=[2000, 10000, 40000])
    ap.add_argument("--views", nargs="*", type=int, default=[4, 12, 36])
    ap.add_argument("--res", nargs="*", type=int, default=[64, 128, 256])
    ap.add_argument("--channels", default="alpha,normal", help="comma-separated channels")
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--iters", type=int, default=5)
    ap.add_argument("--mode", default="default", choices=["default", "plan"],
                    help="default: render() with no plan under jit (what a user writes); plan: plan_render() first")
    ap.add_argument("--out", help="also write the markdown table here")
    ap.add_argument("--_cell", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    channels = tuple(args.channels.split(","))

    if args._cell:
        nf, nv, res = (int(x) for x in args._cell.split("x"))
        print(json.dumps(run_cell(nf, nv, res, channels, args.iters, args.sigma, args.mode)))
        return

    if args.cells:
        cells = [tuple(int(x) for x in c.split("x")) for c in args.cells]
    elif args.quick:
        cells = [(10000, 12, 128), (40000, 36, 256)]
    else:
        cells = [(f, v, r) for f in args.faces for v in args.views for r in args.res]

    gflops = matmul_gflops()
    load = os.getloadavg()[0]
    header = (
        f"f32 matmul: {gflops:.0f} GFLOP/s; load average at start {load:.1f}; channels {','.join(channels)}; "
        f"sigma {args.sigma}; mode {args.mode}; torus meshes; limit = required pairs x {FLOP_PER_PAIR} flop / "
        "matmul rate; 'ms @127' = fwd+bwd ms x (matmul rate / 127 GFLOP/s), the time normalized to the reference "
        "machine of the issue's targets; pairs = evaluated (plan) or required (no plan)\n\n"
        "| faces | views | res | window | fwd+bwd ms | ms @127 | pairs (M) | ns/pair | required (M) | limit ms | x limit "
        "| peak RSS GB | compile s | overflow |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    print(header, flush=True)
    lines = [header]
    for nf, nv, res in cells:
        cmd = [sys.executable, __file__, "--_cell", f"{nf}x{nv}x{res}", "--channels", args.channels,
               "--iters", str(args.iters), "--sigma", str(args.sigma), "--mode", args.mode]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            line = f"| {nf} | {nv} | {res} | failed: {out.stderr.strip().splitlines()[-1][:80]} |"
        else:
            r = json.loads(out.stdout.strip().splitlines()[-1])
            limit_ms = r["required"] * FLOP_PER_PAIR / (gflops * 1e9) * 1e3
            line = (
                f"| {r['faces']} | {nv} | {res} | {r['window']} | {r['ms']:.0f} | {r['ms'] * gflops / 127:.0f} | "
                f"{r['pairs'] / 1e6:.2f} | "
                f"{r['ms'] * 1e6 / r['pairs']:.0f} | {r['required'] / 1e6:.2f} | {limit_ms:.1f} | "
                f"{r['ms'] / limit_ms:.0f} | {r['rss_gb']:.2f} | {r['compile_s']:.1f} | {r['overflow']} |"
            )
        print(line, flush=True)
        lines.append(line)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
