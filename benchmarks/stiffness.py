"""Stiff and extreme settings of the large-steps optimizer: does anything blow up?

Fits a sphere to an ellipsoid (RGBA normal + silhouette targets rendered by
`jaxgenus.render`) for `--steps` steps per setting and reports CG iterations,
finiteness, final loss, inverted faces and the step status flags, over

* lambda in {1, 19, 100, 1e3, 1e4} x learning rate in {1e-4, 1e-3, 1e-2, 1e-1, 1},
* the bilaplacian weight w1 over six orders of magnitude (lambda = 19 and 1e4,
  learning rate 0.03) and the inversion weight w2 over six orders of magnitude
  plus 0 (lambda = 1 with learning rate 0.5, where faces fold, and lambda = 1e4).

Prints a markdown table and writes it between the table markers of `--out`
(default docs/stability.md; the whole file if it has no markers).

    python benchmarks/stiffness.py --subdivisions 3 --resolution 32 --views 6 --steps 100
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

import jaxgenus as jg


def problem(subdivisions, resolution, n_views):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.8)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    vcap, fcap = jg.geometry.capacity_bucket(len(f))
    mesh = jg.Mesh.from_numpy(v, f, capacity=(vcap, fcap))
    cams = jg.sphere_cameras(n_views, radius=3.0, fov_deg=40.0, resolution=resolution)
    images = jg.render(jg.Mesh.from_numpy(v * np.array([1.25, 0.7, 0.9]), f), cams, channels=("alpha", "normal"))
    targets = jnp.concatenate([(images[..., 1:] + 1.0) / 2.0, images[..., :1]], axis=-1)
    plan = jg.rendering.plan_render(mesh, cams, face_margin=1.5)
    return mesh, cams, targets, plan


def run(mesh, cams, targets, plan, steps, **options):
    opts = jg.OptimizeOptions(render=jg.RenderSettings(plan=plan), adam_quantile=1.0, views_per_step=None, **options)
    state = jg.optim.init_optimizer_state(mesh, jax.random.key(0))
    t0 = time.perf_counter()
    state, rec = jg.optim.optimize_block(state, cams, targets, n_steps=steps, options=opts)
    rec = jax.tree.map(np.asarray, rec)
    seconds = time.perf_counter() - t0
    x = np.asarray(state.mesh.vertices)
    status = rec["status"]
    return {
        "iters_fwd": f"{rec['cg_iterations_forward'].mean():.0f} / {rec['cg_iterations_forward'].max()}",
        "iters_bwd": f"{rec['cg_iterations_backward'].mean():.0f} / {rec['cg_iterations_backward'].max()}",
        "residual": f"{rec['cg_residual'].max():.1e}",
        "finite": bool(np.all(np.isfinite(x)) and np.all(np.isfinite(rec["loss"]))),
        "loss0": f"{rec['loss'][0]:.4f}",
        "loss": f"{rec['loss'][-1]:.4f}",
        "image": f"{rec['alpha'][-1] + rec['normal'][-1]:.4f}",
        "inverted": int(rec["inverted_faces"][-1]),
        "max_inverted": int(rec["inverted_faces"].max()),
        "status": f"{np.sum(status == 0)}/{np.sum(status == 1)}/{np.sum(status == 2)}",
        "seconds": f"{seconds:.1f}",
    }


COLUMNS = [
    ("lambda", "lambda"),
    ("lr", "lr"),
    ("w1", "w1 (bilap.)"),
    ("w2", "w2 (inv.)"),
    ("iters_fwd", "CG iters x: mean / max"),
    ("iters_bwd", "CG iters grad: mean / max"),
    ("residual", "max rel. residual (f32)"),
    ("finite", "finite"),
    ("loss0", "loss step 0"),
    ("loss", "loss last step"),
    ("image", "image loss last step"),
    ("inverted", "inverted faces (end)"),
    ("max_inverted", "max inverted faces"),
    ("status", "steps ok / CG not conv. / skipped"),
    ("seconds", "s (incl. compile)"),
]


def table(rows):
    lines = ["| " + " | ".join(h for _, h in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(str(r[k]) for k, _ in COLUMNS) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subdivisions", type=int, default=3, help="icosphere subdivisions (3: 642 vertices)")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--out", default="docs/stability.md")
    args = ap.parse_args()

    mesh, cams, targets, plan = problem(args.subdivisions, args.resolution, args.views)
    base = jg.LossWeights()
    rows = []

    def add(lam, lr, w1, w2):
        weights = jg.LossWeights(bilaplacian=w1, inversion=w2)
        r = run(mesh, cams, targets, plan, args.steps, lambda_=lam, learning_rate=lr, weights=weights)
        r.update(**{"lambda": f"{lam:g}", "lr": f"{lr:g}", "w1": f"{w1:g}", "w2": f"{w2:g}"})
        rows.append(r)
        print(" | ".join(str(r[k]) for k, _ in COLUMNS), flush=True)

    for lam in (1.0, 19.0, 100.0, 1e3, 1e4):
        for lr in (1e-4, 1e-3, 1e-2, 1e-1, 1.0):
            add(lam, lr, base.bilaplacian, base.inversion)
    for lam in (19.0, 1e4):
        for w1 in (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0):
            add(lam, 3e-2, w1, base.inversion)
    # the inversion weight matters only where faces fold: lambda = 1 with a large step does
    for lam, lr in ((1.0, 0.5), (1e4, 3e-2)):
        for w2 in (0.0, 1.0, 10.0, 1e2, 1e3, 1e4, 1e5):
            add(lam, lr, base.bilaplacian, w2)

    header = (
        f"Sphere (icosphere {args.subdivisions}: {int(mesh.n_vertices)} vertices, {int(mesh.n_faces)} faces, "
        f"capacity {mesh.vertex_capacity}/{mesh.face_capacity}) fitted to an ellipsoid, {args.views} views at "
        f"{args.resolution}^2, RGBA normal + silhouette targets, {args.steps} steps per row, float32, "
        f"{platform.machine()} CPU ({jax.devices()[0].device_kind}).\n"
        "Command: `python benchmarks/stiffness.py "
        f"--subdivisions {args.subdivisions} --resolution {args.resolution} --views {args.views} --steps {args.steps}`\n"
    )
    text = header + "\n" + table(rows) + "\n"
    print(text)
    if args.out:
        write_between_markers(args.out, text)


BEGIN, END = "<!-- stiffness-table:begin -->", "<!-- stiffness-table:end -->"


def write_between_markers(path, text):
    """Replace the text between the table markers of `path` (or write the whole file if it has none)."""
    try:
        with open(path) as fh:
            doc = fh.read()
    except FileNotFoundError:
        doc = ""
    if BEGIN in doc and END in doc:
        doc = doc[: doc.index(BEGIN) + len(BEGIN)] + "\n" + text + doc[doc.index(END) :]
    else:
        doc = BEGIN + "\n" + text + END + "\n"
    with open(path, "w") as fh:
        fh.write(doc)


if __name__ == "__main__":
    main()
