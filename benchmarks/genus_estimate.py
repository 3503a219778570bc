"""How often `jaxgenus.genus_estimate` (what `reconstruct` does without a genus) is right.

    python benchmarks/genus_estimate.py [--views 24 --res 128] [--targets normals] [--reconstruct]
                                        [--capture DIR GENUS ...] [--keep 12]

Shapes: the shared meshes (`../shared/meshes` or `$JAXGENUS_SHARED_MESHES`), centred and scaled
into the unit ball, and shapes of ours whose holes no silhouette shows (`tests/_hidden.py`: the
covered plate, the long-tunnel plate, the perforated plate, the mug, the wheel), seen from `--views` cameras on a sphere at
`--res`^2 and ray cast with trimesh (`tests/_raycast.py`, independent of our renderer):
`--targets normals` (the default: normal maps, so the estimate also tests holes in the images'
interior), `silhouette` (masks only) or `photo` (Lambertian photos of a grey albedo).
`--reconstruct [given]` also runs `reconstruct` without a genus (or with the true one) and scores the handles' placement
(`jaxgenus.metrics.handle_placement`, b1 of object / result / both / either) and the volume IoU. Captures:
`--capture DIR GENUS` for a folder with `image/`, `mask/` and one camera file (any format
`jaxgenus.load_cameras` reads), e.g. Middlebury's templeSparseRing (genus 3) and
dinoSparseRing (genus 0) with masks of your own; `--keep K` fits K of its views (every
(N/(N-K))-th held out, as the Middlebury bar does with 12 of 16). The data stays outside this
repository. Per row: the true genus, the estimate, its agreement and plausible genera, the
genus per closing on each grid, seconds. Writes OUT/genus_estimate.{md,json}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _report import publish
from reconstruct import load_shape, shared_names

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _raycast import raycast, raycast_lambert  # noqa: E402  (the independent ray caster of the tests)

import jaxgenus as jg


def capture_views(folder: Path, keep: int | None):
    """Images (photos with masks), cameras and a label of a capture folder, `keep` of its views."""
    files = sorted(p for p in (folder / "image").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    if keep:
        drop = len(files) - keep
        held = {int(round(i * len(files) / drop)) + (len(files) // drop - 1) for i in range(drop)} if drop > 0 else set()
        files = [f for i, f in enumerate(files) if i not in held]
    masks = [folder / "mask" / f.name for f in files]
    loaded = jg.load_images([str(f) for f in files], masks=[str(m) for m in masks])
    camera_file = next(p for p in sorted(folder.iterdir()) if p.is_file() and p.suffix in (".json", ".txt", ".npz"))
    cams, names = jg.load_cameras(camera_file)
    order, _ = jg.pair_images(loaded.names, names, n_images=len(loaded.images), n_cameras=len(cams))
    return loaded.images[..., 3], cams[np.asarray(order)], f"{folder.name} ({len(files)} views)"


def row(label: str, genus: int, images, cams, gt=None, whole: bool = False) -> dict:
    t0 = time.perf_counter()
    e = jg.genus_estimate(images, cams)
    grids = {}
    for ev in e.evidence:
        grids.setdefault(ev.resolution, []).append(ev.genus)
    out = dict(shape=label, genus=genus, estimate=e.genus, agreement=e.agreement, plausible=list(e.plausible),
               cue=e.cue, holes=f"{sum(h['kept'] for h in e.holes)}/{len(e.holes)}",
               grids={str(k): v for k, v in grids.items()}, seconds=time.perf_counter() - t0)
    if whole and gt is not None:
        print(json.dumps(out), flush=True)  # the estimate before the (long) reconstruction
        t0 = time.perf_counter()
        rec = jg.reconstruct(images, cams, genus if whole == "given" else None)
        p = jg.metrics.handle_placement(gt, rec.mesh, resolution=160)
        estimate = rec.history.get("genus_estimate")
        out.update(rec_genus=rec.genus, rec_estimate=None if estimate is None else estimate.genus, ok=rec.history["ok"],
                   placement="/".join(str(b.b1) for b in (p.object, p.result, p.intersection, p.union)),
                   iou=jg.metrics.volume_iou(rec.mesh, gt, n_samples=100_000), rec_seconds=time.perf_counter() - t0)
    return out


def shapes(names):
    """`(name, Mesh, genus)`: the shared meshes (all, or `names`) and ours with hidden holes."""
    import _hidden

    ours = {make.__name__: make for make in (_hidden.covered_plate, _hidden.long_tunnel_plate, _hidden.perforated_plate, _hidden.mug, _hidden.wheel)}
    for name in (names if names is not None else shared_names() + list(ours)):
        if name in ours:
            v, f, genus = ours[name]()
            yield name, jg.Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32)), genus
            continue
        gt, genus = load_shape("shared:" + name)
        if gt is None:
            print(f"{name}: the shared meshes are absent, skipped")
            continue
        yield name, gt, genus


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--shapes", nargs="*", default=None, help="shared mesh names or covered_plate, long_tunnel_plate, perforated_plate, mug, wheel (default: all)")
    ap.add_argument("--targets", choices=("normals", "silhouette", "photo"), default="normals")
    ap.add_argument("--reconstruct", nargs="?", const="estimated", choices=("estimated", "given"), default=None,
                    help="also reconstruct, without a genus or ('given') with the true one; placement, IoU")
    ap.add_argument("--capture", nargs=2, action="append", default=[], metavar=("DIR", "GENUS"))
    ap.add_argument("--keep", type=int, default=None, help="views of each capture to use")
    ap.add_argument("--out", type=Path, default=Path("genus_estimate_out"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    for name, gt, genus in shapes(args.shapes):
        if args.targets == "photo":
            images = raycast_lambert(cams, gt, light_direction=(0.3, -0.5, 0.8), ambient=0.3)
        else:
            images = raycast(cams, gt)
        if args.targets == "silhouette":
            images = images[..., 3]
        rows.append(row(f"{name} ({args.views} {args.targets} views of {args.res}^2)", genus, images, cams, gt,
                        args.reconstruct))
        print(json.dumps(rows[-1]), flush=True)
    for folder, genus in args.capture:
        alpha, ccams, label = capture_views(Path(folder), args.keep)
        rows.append(row(label, int(genus), alpha, ccams))
        print(json.dumps(rows[-1]), flush=True)
    (args.out / "genus_estimate.json").write_text(json.dumps(rows, indent=1))
    text = ("| shape | genus | estimate | agreement | plausible | cue | holes kept/tested | genus per closing 0-3, "
            "per grid | seconds | reconstruct: genus, ok, placement o/r/both/either, IoU, s |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n")
    for r in rows:
        mark = "" if r["estimate"] == r["genus"] else " **(wrong)**"
        grids = "; ".join(f"{k}: {' '.join(map(str, v))}" for k, v in r["grids"].items())
        whole = (f"{r['rec_genus']}, {r['ok']}, {r['placement']}, {r['iou']:.3f}, {r['rec_seconds']:.0f}"
                 if "rec_genus" in r else "")
        text += (f"| {r['shape']} | {r['genus']} | {r['estimate']}{mark} | {r['agreement']:.2f} | {r['plausible']} | "
                 f"{r.get('cue', '')} | {r.get('holes', '')} | {grids} | {r['seconds']:.1f} | {whole} |\n")
    right = sum(r["estimate"] == r["genus"] for r in rows)
    confident = sum(r["estimate"] != r["genus"] and r["agreement"] >= 0.9 for r in rows)
    text += f"\n{right} of {len(rows)} right; {confident} wrong at agreement >= 0.9.\n"
    publish(args.out / "genus_estimate.md", text)


if __name__ == "__main__":
    main()
