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
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

import jaxgenus as jg
from _report import publish, pyplot


def shared_dir() -> Path | None:
    env = os.environ.get("JAXGENUS_SHARED_MESHES")
    p = Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "meshes"
    return p if (p / "manifest.json").is_file() else None


def shared_names() -> list[str]:
    root = shared_dir()
    if root is None:
        return []
    manifest = json.loads((root / "manifest.json").read_text())
    entries = manifest["meshes"] if isinstance(manifest, dict) and "meshes" in manifest else manifest
    return [e["name"] for e in entries]


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
                seconds=rec.history["seconds"], start=rec.history["start"], fine=rec.history["fine"], trace=trace,
                sil_iou_min=min(rec.history["silhouette_iou"]), ok=rec.history["ok"])


def run_one(args):
    """One shape, one method, in this process: prints the result row as JSON."""
    spec, method = args.one
    gt, genus = load_shape(spec)
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    targets = jg.render_targets(gt, cams)
    opts = jg.ReconstructOptions.nicolet() if method == "nicolet" else jg.ReconstructOptions()
    fine = spec in args.fine
    opts = opts.fine() if fine else dataclasses.replace(opts, n_cycles=args.cycles)
    opts = opts.replaced(steps_per_cycle=args.steps, one_jit=args.one_jit)
    r = run(targets, cams, genus, gt, opts, args.trace_samples)
    settings = ("fine" if fine else "fine (auto)" if r["fine"] else "default") + ("+one_jit" if args.one_jit else "")
    r.update(shape=spec, true_genus=genus, method=method, settings=settings)
    print(json.dumps(r, default=float))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=None,
                    help="builtin:NAME or shared:NAME (default: every built-in scene and every shared mesh)")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--cycles", type=int, default=4)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--trace-samples", type=int, default=10_000)
    ap.add_argument("--fine", nargs="*", default=[],
                    help="shapes forced to ReconstructOptions.fine() (both methods; without it, reconstruct switches "
                         "to fine() by itself for thin shapes: options.fine_below)")
    ap.add_argument("--one-jit", action="store_true", help="ReconstructOptions.one_jit for both methods")
    ap.add_argument("--methods", nargs="+", default=["ours", "nicolet"], choices=["ours", "nicolet"])
    ap.add_argument("--out", default="docs")
    ap.add_argument("--resume", action="store_true", help="keep the rows already in OUT/reconstruction_benchmark.json")
    ap.add_argument("--report-only", action="store_true", help="rewrite table and plot from OUT's JSON rows")
    ap.add_argument("--one", nargs=2, metavar=("SHAPE", "METHOD"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        return run_one(args)

    if args.shapes is None:
        args.shapes = [f"builtin:{n}" for n in jg.SCENES] + [f"shared:{n}" for n in shared_names()]
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "reconstruction_benchmark.json"
    rows = json.loads(saved.read_text()) if (args.resume or args.report_only) and saved.is_file() else []
    if args.report_only:
        return write_report(rows, args, out)
    done = {(r["shape"], r["method"]) for r in rows}
    for spec in args.shapes:
        if spec.startswith("shared:") and shared_dir() is None:
            print(f"skip {spec}: ../shared/meshes is absent")
            continue
        for method in args.methods:
            if (spec, method) in done:
                continue
            # one fresh process per run: compiled executables of earlier shapes do not pile up
            cmd = [sys.executable, __file__, "--one", spec, method, "--views", str(args.views), "--res", str(args.res),
                   "--cycles", str(args.cycles), "--steps", str(args.steps), "--trace-samples", str(args.trace_samples),
                   "--fine", *args.fine] + (["--one-jit"] if args.one_jit else [])
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"{spec} {method}: failed\n{proc.stderr[-2000:]}", flush=True)
                continue
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            genus = r["true_genus"]
            rows.append(r)
            print(f"{spec:24s} {method:8s} genus {r['genus']:>2}/{genus:<2} CD {r['cd_l1']:.4f} "
                  f"CD2 {r['cd_l2']:.2e} IoU {r['iou']:.3f} faces {r['faces']:>6} {r['seconds']:.0f}s "
                  f"verdict {'ok' if r.get('ok', True) else 'NOT OK'} (silhouette IoU min {r.get('sil_iou_min', float('nan')):.3f})",
                  flush=True)
            (out / "reconstruction_benchmark.json").write_text(json.dumps(rows, default=float))  # partial results

    write_report(rows, args, out)


def _verdict(r) -> str:
    if "ok" not in r:
        return ""  # rows from before the verdict existed
    return f"{'ok' if r['ok'] else 'NOT OK'} ({r['sil_iou_min']:.3f})"


def write_report(rows, args, out: Path):
    """Markdown table, JSON rows and a plot (CD and IoU against seconds; ours vs baseline CD)."""
    order = {spec: k for k, spec in enumerate(args.shapes)}
    rows = sorted(rows, key=lambda r: (order.get(r["shape"], len(order)), r["method"] != "ours"))
    cmd = (f"python benchmarks/reconstruct.py --views {args.views} --res {args.res} --cycles {args.cycles} "
           f"--steps {args.steps}" + (f" --fine {' '.join(args.fine)}" if args.fine else "")
           + (" --one-jit" if args.one_jit else ""))
    head = (f"Settings: {args.views} views at {args.res}^2, {args.cycles} x {args.steps} steps (settings `fine`: "
            f"`ReconstructOptions.fine()`, 5 x {args.steps}; `fine (auto)`: chosen by `reconstruct` for a visual hull "
            f"thinner than `fine_below`), every run in a fresh process, `{cmd}`\n\n"
            "| shape | genus | method | settings | start | result genus | CD L1 | CD ours / baseline | CD L2 (PyTorch3D) "
            "| IoU | faces | seconds | verdict (min view silhouette IoU) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    base = {r["shape"]: r["cd_l1"] for r in rows if r["method"] == "nicolet"}
    ratio = lambda r: f"{r['cd_l1'] / base[r['shape']]:.2f}" if r["method"] == "ours" and r["shape"] in base else ""
    table = head + "".join(
        f"| {r['shape']} | {r['true_genus']} | {r['method']} | {r.get('settings', 'default')} | {r.get('start', '')} "
        f"| {r['genus']} | {r['cd_l1']:.4f} "
        f"| {ratio(r)} | {r['cd_l2']:.2e} | {r['iou']:.3f} | {r['faces']} | {r['seconds']:.0f} | {_verdict(r)} |\n"
        for r in rows)
    publish(out / "reconstruction_benchmark.md", table)
    (out / "reconstruction_benchmark.json").write_text(json.dumps(rows, default=float))
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(1, 3, figsize=(17, 5))
    shapes = list(dict.fromkeys(r["shape"] for r in rows))
    colors = {sh: plt.cm.tab20(k % 20) for k, sh in enumerate(shapes)}
    for r in rows:
        tr = np.array(r["trace"])
        style = "-" if r["method"] == "ours" else "--"
        label = r["shape"] if r["method"] == "ours" else None
        ax[0].plot(tr[:, 0], tr[:, 1], style, color=colors[r["shape"]], marker="o", ms=3, label=label)
        ax[1].plot(tr[:, 0], tr[:, 2], style, color=colors[r["shape"]], marker="o", ms=3)
    ax[0].set(xlabel="wall-clock seconds", ylabel="chamfer L1 (unit sphere)", yscale="log",
              title="CD after each cycle (solid: ours, dashed: Nicolet 2021)")
    ax[1].set(xlabel="wall-clock seconds", ylabel="volume IoU", title="IoU after each cycle")
    ours = {r["shape"]: r for r in rows if r["method"] == "ours"}
    pairs = [(base[sh], ours[sh]["cd_l1"], sh) for sh in shapes if sh in base and sh in ours]
    if pairs:
        b, o, names = zip(*pairs)
        ax[2].scatter(b, o, c=[colors[n] for n in names])
        lim = [min(b + o) * 0.8, max(b + o) * 1.2]
        ax[2].plot(lim, lim, "k:", label="equal")
        ax[2].plot(lim, [0.7 * x for x in lim], "k--", label="0.7x (target for genus >= 1)")
        ax[2].set(xscale="log", yscale="log", xlabel="baseline CD L1 (after ICP)", ylabel="ours CD L1 (after ICP)",
                  title="final chamfer, ours vs baseline")
        ax[2].legend(fontsize=7)
    ax[0].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(out / "reconstruction_benchmark.png", dpi=110)


if __name__ == "__main__":
    main()
