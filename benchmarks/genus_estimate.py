"""How often `jaxgenus.genus_estimate` (what `reconstruct` does without a genus) is right.

    python benchmarks/genus_estimate.py [--views 24 --res 128] [--capture DIR GENUS ...] [--keep 12]

Shapes: the shared meshes (`../shared/meshes` or `$JAXGENUS_SHARED_MESHES`), centred and scaled
into the unit ball, their silhouettes from `--views` cameras on a sphere at `--res`^2. Captures:
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
import time
from pathlib import Path

import numpy as np
from _report import publish
from reconstruct import load_shape, shared_names

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


def row(label: str, genus: int, images, cams) -> dict:
    t0 = time.perf_counter()
    e = jg.genus_estimate(images, cams)
    grids = {}
    for ev in e.evidence:
        grids.setdefault(ev.resolution, []).append(ev.genus)
    return dict(shape=label, genus=genus, estimate=e.genus, agreement=e.agreement, plausible=list(e.plausible),
                grids={str(k): v for k, v in grids.items()}, seconds=time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--shapes", nargs="*", default=None, help="shared mesh names (default: all)")
    ap.add_argument("--capture", nargs=2, action="append", default=[], metavar=("DIR", "GENUS"))
    ap.add_argument("--keep", type=int, default=None, help="views of each capture to use")
    ap.add_argument("--out", type=Path, default=Path("genus_estimate_out"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    for name in (args.shapes if args.shapes is not None else shared_names()):
        gt, genus = load_shape("shared:" + name)
        if gt is None:
            print(f"{name}: the shared meshes are absent, skipped")
            continue
        alpha = np.asarray(jg.render_targets(gt, cams))[..., 3]
        rows.append(row(f"{name} ({args.views} views of {args.res}^2)", genus, alpha, cams))
        print(json.dumps(rows[-1]), flush=True)
    for folder, genus in args.capture:
        alpha, ccams, label = capture_views(Path(folder), args.keep)
        rows.append(row(label, int(genus), alpha, ccams))
        print(json.dumps(rows[-1]), flush=True)
    (args.out / "genus_estimate.json").write_text(json.dumps(rows, indent=1))
    text = ("| shape | genus | estimate | agreement | plausible | genus per closing 0-3, per grid | seconds |\n"
            "|---|---|---|---|---|---|---|\n")
    for r in rows:
        mark = "" if r["estimate"] == r["genus"] else " **(wrong)**"
        grids = "; ".join(f"{k}: {' '.join(map(str, v))}" for k, v in r["grids"].items())
        text += (f"| {r['shape']} | {r['genus']} | {r['estimate']}{mark} | {r['agreement']:.2f} | {r['plausible']} | "
                 f"{grids} | {r['seconds']:.1f} |\n")
    right = sum(r["estimate"] == r["genus"] for r in rows)
    text += f"\n{right} of {len(rows)} right.\n"
    publish(args.out / "genus_estimate.md", text)


if __name__ == "__main__":
    main()
