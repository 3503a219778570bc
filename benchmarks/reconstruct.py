"""Ours vs the Nicolet et al. 2021 baseline on built-in and shared meshes: error against run time.

    python benchmarks/reconstruct.py --shapes builtin:three_tori shared:pretzel --views 24 --res 128

Every mesh is normalized to the unit sphere; targets are `render_targets` of it
from `sphere_cameras(views)`. Both methods run with the same renderer, optimizer,
views, resolution and step budget (`ReconstructOptions` vs `ReconstructOptions.nicolet`).
Final metrics follow docs/metrics.md (ICP, then chamfer in both conventions and
volume IoU). Writes a markdown table and (with matplotlib) a plot of CD and IoU
against wall-clock seconds to --out.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import jaxgenus as jg


def shared_dir() -> Path | None:
    env = os.environ.get("JAXGENUS_SHARED_MESHES")
    p = Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "meshes"
    return p if (p / "manifest.json").is_file() else None


def load_shape(spec: str):
    kind, name = spec.split(":", 1)
    if kind == "builtin":
        return jg.builtin_scene(name), jg.SCENES[name]
    root = shared_dir()
    if root is None:
        return None, None
    manifest = json.loads((root / "manifest.json").read_text())
    entries = manifest["meshes"] if isinstance(manifest, dict) and "meshes" in manifest else manifest
    genus = next(int(e["genus"]) for e in entries if e["name"] == name)
    v, f = jg.load_mesh(root / f"{name}.obj").to_numpy()
    v = v - 0.5 * (v.min(0) + v.max(0))
    return jg.Mesh.from_numpy(v / np.linalg.norm(v, axis=1).max(), f), genus


def run(targets, cams, genus, gt, options, trace_samples):
    trace = []

    def record(row, mesh):
        cd = jg.metrics.chamfer_distance(mesh, gt, n_samples=trace_samples).l1
        iou = jg.metrics.volume_iou(mesh, gt, n_samples=2 * trace_samples)
        trace.append((row["elapsed"], cd, iou))

    rec = jg.reconstruct(targets, cams, genus, options=options, callback=record)
    aligned = jg.metrics.icp_align(rec.mesh, gt).vertices
    _, f = rec.mesh.to_numpy()
    cd = jg.metrics.chamfer_distance((aligned, f), gt)
    iou = jg.metrics.volume_iou((aligned, f), gt)
    return dict(cd_l1=cd.l1, cd_l2=cd.l2_pytorch3d, iou=iou, genus=rec.genus, faces=int(rec.mesh.n_faces),
                seconds=rec.history["seconds"], trace=trace)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=["builtin:torus", "builtin:tilted_tori", "builtin:three_tori"]
                    + [f"shared:{n}" for n in ("spot_low", "torus", "bob", "eight", "skull", "pretzel", "fertility",
                                               "botijo", "boot", "heptoroid")])
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--cycles", type=int, default=4)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--trace-samples", type=int, default=10_000)
    ap.add_argument("--out", default="docs")
    args = ap.parse_args()

    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    rows = []
    for spec in args.shapes:
        gt, genus = load_shape(spec)
        if gt is None:
            print(f"skip {spec}: ../shared/meshes is absent")
            continue
        targets = jg.render_targets(gt, cams)
        for method, opts in (("ours", jg.ReconstructOptions(n_cycles=args.cycles, steps_per_cycle=args.steps)),
                             ("nicolet", jg.ReconstructOptions.nicolet(n_cycles=args.cycles, steps_per_cycle=args.steps))):
            r = run(targets, cams, genus, gt, opts, args.trace_samples)
            r.update(shape=spec, true_genus=genus, method=method)
            rows.append(r)
            print(f"{spec:24s} {method:8s} genus {r['genus']:>2}/{genus:<2} CD {r['cd_l1']:.4f} "
                  f"CD2 {r['cd_l2']:.2e} IoU {r['iou']:.3f} faces {r['faces']:>6} {r['seconds']:.0f}s", flush=True)

    head = (f"Settings: {args.views} views at {args.res}^2, {args.cycles} x {args.steps} steps, "
            f"`python benchmarks/reconstruct.py {' '.join(os.sys.argv[1:])}`\n\n"
            "| shape | genus | method | result genus | CD L1 | CD L2 (PyTorch3D) | IoU | faces | seconds |\n"
            "|---|---|---|---|---|---|---|---|---|\n")
    table = head + "".join(
        f"| {r['shape']} | {r['true_genus']} | {r['method']} | {r['genus']} | {r['cd_l1']:.4f} | {r['cd_l2']:.2e} "
        f"| {r['iou']:.3f} | {r['faces']} | {r['seconds']:.0f} |\n" for r in rows)
    print(table)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "reconstruction_benchmark.md").write_text(table)
    (out / "reconstruction_benchmark.json").write_text(json.dumps(rows, default=float))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    for r in rows:
        tr = np.array(r["trace"])
        style = "-" if r["method"] == "ours" else "--"
        ax[0].plot(tr[:, 0], tr[:, 1], style, marker="o", label=f"{r['shape']} {r['method']}")
        ax[1].plot(tr[:, 0], tr[:, 2], style, marker="o")
    ax[0].set(xlabel="wall-clock seconds", ylabel="chamfer L1", yscale="log", title="CD (solid: ours, dashed: Nicolet)")
    ax[1].set(xlabel="wall-clock seconds", ylabel="volume IoU", title="IoU")
    ax[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "reconstruction_benchmark.png", dpi=110)


if __name__ == "__main__":
    main()
