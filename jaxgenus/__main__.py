"""Command line: `python -m jaxgenus <command>` (also installed as `jaxgenus`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np


def _primitives(args) -> int:
    import jaxgenus as jg

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"{'genus':>5} {'V':>6} {'F':>6} {'chi':>5} {'2-2g':>5} {'closed':>6} {'seconds':>8}  file")
    for g in args.genus:
        t0 = time.perf_counter()
        mesh = jg.genus_primitive(g, n_faces=args.faces)
        dt = time.perf_counter() - t0
        chi = jg.euler_characteristic(mesh)
        path = out / f"genus_{g}.obj"
        jg.save_mesh(mesh, path)
        print(
            f"{g:>5} {int(mesh.n_vertices):>6} {int(mesh.n_faces):>6} {chi:>5} {2 - 2 * g:>5} "
            f"{str(jg.is_closed_manifold(mesh)):>6} {dt:>8.2f}  {path}"
        )
        if chi != 2 - 2 * g:
            print(f"error: genus {g} primitive has chi {chi}", file=sys.stderr)
            return 1
    return 0


def _progress(total_cycles):
    def show(row, mesh):
        done = row["cycle"] + 1
        eta = row["elapsed"] / done * (total_cycles - done)
        bar = "#" * done + "." * (total_cycles - done)
        print(
            f"[{bar}] cycle {done}/{total_cycles}  loss {row['loss']:.4f}  faces {row['faces']}"
            f"  chi {row['chi']}  {row['elapsed']:.0f}s elapsed, ETA {eta:.0f}s",
            flush=True,
        )

    return show


def _load_cameras(path):
    import json

    import jaxgenus as jg

    spec = json.loads(Path(path).read_text())
    try:
        cams = spec["cameras"]
        K = np.array([c["K"] for c in cams], np.float32)
        R = np.array([c["R"] for c in cams], np.float32)
        t = np.array([c["t"] for c in cams], np.float32)
        return jg.cameras_from_opencv(K, R, t, height=int(spec["height"]), width=int(spec["width"]))
    except (KeyError, TypeError, ValueError) as err:
        raise SystemExit(
            f"--cameras: expected JSON {{height, width, cameras: [{{K, R, t}}, ...]}} (OpenCV convention): {err}"
        )


def _load_images(path):
    p = Path(path)
    if p.suffix == ".npy":
        return np.load(p)
    files = sorted(p.glob("*.png"))
    if not files:
        raise SystemExit(f"--images: {path} is neither a .npy file nor a folder of PNG files")
    try:
        from PIL import Image
    except ImportError:
        raise SystemExit("--images: reading PNG files needs Pillow (pip install pillow), or pass a .npy array")
    return np.stack([np.asarray(Image.open(f).convert("RGBA"), np.float32) / 255.0 for f in files])


def _report(rec, gt=None):
    import jaxgenus as jg

    print(f"genus {rec.genus} (requested {rec.history['requested_genus']})  faces {int(rec.mesh.n_faces)}"
          f"  time {rec.history['seconds']:.1f}s  start {rec.history['start']}"
          + ("  (thin visual hull: fine() settings)" if rec.history["fine"] else ""))
    if gt is not None:
        cd = jg.metrics.chamfer_distance(rec.mesh, gt, n_samples=30_000)
        iou = jg.metrics.volume_iou(rec.mesh, gt, n_samples=100_000)
        print(f"chamfer L1 {cd.l1:.5f}  chamfer L2 (PyTorch3D) {cd.l2_pytorch3d:.3e}  volume IoU {iou:.3f}")


def _write(rec, out):
    import json

    import jaxgenus as jg

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    jg.save_mesh(rec.mesh, out)
    out.with_suffix(".json").write_text(json.dumps(rec.history.to_json(), default=float))
    print(f"wrote {out} and {out.with_suffix('.json')}")


def _reconstruct(args) -> int:
    import jaxgenus as jg

    opts = jg.ReconstructOptions.nicolet() if args.nicolet else jg.ReconstructOptions()
    opts = opts.fine() if args.fine else opts
    opts = dataclasses.replace(opts, n_cycles=args.cycles or opts.n_cycles, steps_per_cycle=args.steps, one_jit=args.one_jit)
    gt = None
    if args.mesh:
        gt = jg.load_mesh(args.mesh)
        v, f = gt.to_numpy()
        v = v - 0.5 * (v.min(0) + v.max(0))
        gt = jg.Mesh.from_numpy(v / np.linalg.norm(v, axis=1).max(), f)
        cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
        images = jg.render_targets(gt, cams)
    elif args.images and args.cameras:
        cams = _load_cameras(args.cameras)
        images = _load_images(args.images)
    else:
        raise SystemExit("give --mesh GT.obj (synthetic targets) or --images DIR --cameras cams.json")
    rec = jg.reconstruct(images, cams, args.genus, options=opts, callback=_progress(opts.n_cycles))
    _report(rec, gt)
    _write(rec, args.out)
    return 0 if rec.genus_ok else 2


def _demo(args) -> int:
    import jaxgenus as jg

    gt = jg.builtin_scene(args.scene)
    g = jg.SCENES[args.scene]
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    t0 = time.perf_counter()
    images = jg.render_targets(gt, cams)
    print(f"scene {args.scene!r} (genus {g}, {int(gt.n_faces)} faces): {args.views} target views at {args.res}px "
          f"rendered in {time.perf_counter() - t0:.1f}s")
    opts = jg.ReconstructOptions(n_cycles=args.cycles, steps_per_cycle=args.steps, one_jit=args.one_jit)
    rec = jg.reconstruct(images, cams, g, options=opts, callback=_progress(opts.n_cycles))
    _report(rec, gt)
    _write(rec, Path(args.out) / f"{args.scene}.obj")
    return 0 if rec.genus_ok else 2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="jaxgenus", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("primitives", help="build genus-g primitives, save them as OBJ and print chi")
    p.add_argument("--genus", type=int, nargs="+", default=[0, 1, 2, 3, 5, 8])
    p.add_argument("--faces", type=int, default=5000)
    p.add_argument("--out", default="jaxgenus_out")
    p.set_defaults(run=_primitives)
    r = sub.add_parser("reconstruct", help="reconstruct a mesh of a given genus from images")
    r.add_argument("--mesh", help="ground-truth mesh: render synthetic targets from it")
    r.add_argument("--images", help="RGBA images: a .npy (N, H, W, 4) array or a folder of PNG files")
    r.add_argument("--cameras", help="cameras JSON {height, width, cameras: [{K, R, t}]} (OpenCV convention)")
    r.add_argument("--genus", type=int, required=True)
    r.add_argument("--views", type=int, default=24)
    r.add_argument("--res", type=int, default=128)
    r.add_argument("--cycles", type=int, default=None, help="optimize/remesh cycles (default 4; 5 with --fine)")
    r.add_argument("--steps", type=int, default=150)
    r.add_argument("--nicolet", action="store_true", help="the Nicolet et al. 2021 baseline (sphere, no remeshing)")
    r.add_argument("--fine", action="store_true", help="settings for thin structures a few pixels wide "
                   "(ReconstructOptions.fine(): sharper edges, up to 20k faces, 5 cycles)")
    r.add_argument("--one-jit", action="store_true", help="all cycles in one compiled scan (ReconstructOptions.one_jit)")
    r.add_argument("--out", default="jaxgenus_out/reconstruction.obj")
    r.set_defaults(run=_reconstruct)
    d = sub.add_parser("demo", help="reconstruct a built-in scene and print chamfer, IoU and genus")
    d.add_argument("--scene", default="three_tori", choices=["torus", "tilted_tori", "three_tori"])
    d.add_argument("--views", type=int, default=16)
    d.add_argument("--res", type=int, default=64)
    d.add_argument("--cycles", type=int, default=4)
    d.add_argument("--steps", type=int, default=150)
    d.add_argument("--one-jit", action="store_true", help="all cycles in one compiled scan (ReconstructOptions.one_jit)")
    d.add_argument("--out", default="jaxgenus_out")
    d.set_defaults(run=_demo)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
