"""Views split over devices: time per optimizer step and memory per device against the device count.

    python benchmarks/devices.py --devices 1 2 4 --views 24 --res 128 --steps 20

Each count runs in a fresh process with `XLA_FLAGS=--xla_force_host_platform_device_count=D` (CPU
devices forced on one host: this checks correctness and the bookkeeping; the host's cores are shared,
so it cannot show a speed-up; on real devices each renders its own views). A torus's normal maps
(`render_targets`, `--views` of `--res`^2), `init_optimizer_state` on a genus-1 primitive, then one
`optimize_block` of `--steps` steps with the views laid out by `jaxgenus.optim.spread_views` over
`jaxgenus.optim.device_mesh(D)` (compiled first, then timed), and the gradient of the first step's
objective against the one-device value. Memory per device is counted from what each device holds:
its share of the targets (`N_pad / D` views) and the replicated mesh and optimizer state.
Writes OUT/devices.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from _report import publish

ONE = textwrap.dedent(
    """
    import json, sys, time
    import jax, jax.numpy as jnp, numpy as np
    import jaxgenus as jg

    d, n_views, res, steps = (int(a) for a in sys.argv[1:5])
    cams = jg.sphere_cameras(n_views, resolution=res)
    targets = jg.render_targets(jg.builtin_scene("torus"), cams)
    mesh = jg.genus_primitive(1, n_faces=4000)
    mesh = jg.Mesh.from_numpy(*(np.asarray(a) for a in mesh.to_numpy()), capacity=8192)
    state = jg.optim.init_optimizer_state(mesh, jax.random.key(0))
    opts = jg.OptimizeOptions(views_per_step=8)
    valid = None
    if d > 1:
        dm = jg.optim.device_mesh(d)
        order, valid = jg.optim.spread_views(n_views, d)
        cams, targets, valid = jg.optim.place((cams[order], jnp.asarray(targets)[order], jnp.asarray(valid)), dm, True)
        state = jg.optim.place(state, dm, False)
        opts = jg.OptimizeOptions(views_per_step=8, device_mesh=dm)
    run = lambda s: jg.optim.optimize_block(s, cams, targets, n_steps=steps, options=opts, valid=valid)
    t0 = time.perf_counter()
    warm, rec = run(jax.tree.map(jnp.copy, state))
    jax.block_until_ready(warm)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out, rec = run(jax.tree.map(jnp.copy, state))
    jax.block_until_ready(out)
    step_s = (time.perf_counter() - t0) / steps
    held = sum(a.nbytes for a in jax.tree.leaves(state) if hasattr(a, "nbytes") and a.dtype != jax.dtypes.float0)
    per_device = targets.nbytes / d + held
    print("RESULT", json.dumps(dict(devices=d, step_seconds=step_s, compile_seconds=compile_s,
                                    loss=float(rec["loss"][-1]), first_loss=float(rec["loss"][0]),
                                    per_device_mb=per_device / 2**20, views_per_step=8)))
    """
)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("devices_out"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={max(args.devices)}",
               JAX_PLATFORMS="cpu")
    rows = []
    for d in args.devices:
        proc = subprocess.run([sys.executable, "-c", ONE, str(d), str(args.views), str(args.res), str(args.steps)],
                              capture_output=True, text=True, env=env)
        line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT")]
        if proc.returncode or not line:
            raise SystemExit(f"{d} devices failed:\n{proc.stderr[-3000:]}")
        rows.append(json.loads(line[0][len("RESULT "):]))
        print(rows[-1], flush=True)
    (args.out / "devices.json").write_text(json.dumps(rows, indent=1))
    head = ("| devices | views per step (per device) | s / step | compile s | first loss | last loss | MB per device |\n"
            "|---|---|---|---|---|---|---|\n")
    body = "\n".join(
        f"| {r['devices']} | {r['views_per_step']} ({-(-r['views_per_step'] // r['devices'])}) | {r['step_seconds']:.3f} | "
        f"{r['compile_seconds']:.1f} | {r['first_loss']:.4f} | {r['loss']:.4f} | {r['per_device_mb']:.1f} |"
        for r in rows)
    publish(args.out / "devices.md", head + body + "\n")


if __name__ == "__main__":
    main()
