"""Hidden handles: are a result's handles the object's own?

Shapes whose holes no silhouette shows (`tests/_hidden.py`: the covered plate,
genus 4; the long-tunnel plate, genus 4, and the perforated plate, genus 8, whose visual hulls have
genus 0; a mug with a strap handle flat against its side, genus 1; a wheel of ten spokes with a narrow
axle hole, genus 11, visual hull 10) and shared meshes (the boot, genus 12, whose lace eyelets are seen
only against the boot) are ray cast with trimesh + embree into normal maps
(24 views), and reconstructed with the default options and the true genus.

Scored by `jaxgenus.metrics.handle_placement`: Betti numbers of object, result,
their intersection and union on one voxel grid: the first of 128, 192, 256,
384 voxels along the longest side on which the object's own voxels have its
genus (the grid resolves it). "placed" means all four have the object's b1 and one
component: every handle of the result goes through one of the object's holes.
The result is scored in the frame it was reconstructed in (the cameras' frame,
no alignment); CD and IoU after ICP alignment, like the other benchmarks.

    python benchmarks/hidden_handles.py [--shapes covered_plate long_tunnel_plate mug shared:boot] [--res 256] [--out docs]

(`--shapes perforated_plate wheel --res 128 --grid 160` for the two added shapes.)

Writes OUT/hidden_handles.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _report import publish, pyplot

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))


def load(spec: str):
    import jaxgenus as jg

    if spec in ("covered_plate", "long_tunnel_plate", "perforated_plate", "mug", "wheel"):
        import _hidden

        v, f, genus = getattr(_hidden, spec)()
        return jg.Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32)), genus
    from reconstruct import load_shape

    return load_shape(spec)


def run_one(spec: str, res: int, views: int, grids, options: dict, seed: int) -> dict | None:
    import jax
    import jaxgenus as jg
    from _raycast import raycast

    gt, genus = load(spec)
    if gt is None:
        print(f"{spec}: shared meshes not found, skipped")
        return None
    cams = jg.sphere_cameras(views, radius=3.0, fov_deg=40.0, resolution=res)
    images = raycast(cams, gt)
    t0 = time.perf_counter()
    rec = jg.reconstruct(images, cams, genus, targets="normals", options=jg.ReconstructOptions().updated(**options),
                         key=jax.random.key(seed))
    seconds = time.perf_counter() - t0
    for g in grids:  # the first grid on which the object's own voxels have its genus
        place = jg.metrics.handle_placement(gt, rec.mesh, resolution=g, genus=genus)
        if place.object_resolved:
            break
    aligned = jg.metrics.icp_align(rec.mesh, gt).vertices
    _, f = rec.mesh.to_numpy()
    row = dict(shape=spec, genus=genus, result_genus=rec.genus, res=res, views=views, grid=place.resolution,
               start=rec.history["start"], tunnels=rec.history["tunnels"],
               handles=[h.to_json() for h in rec.history["handles"]],
               cd_l1=jg.metrics.chamfer_distance((aligned, f), gt).l1, iou=jg.metrics.volume_iou((aligned, f), gt),
               seconds=seconds, ok=rec.history["ok"], placed=place.placed, object_resolved=place.object_resolved,
               options=options, seed=seed)
    for name in ("object", "result", "intersection", "union"):
        row[name] = list(getattr(place, name))
    return row


def write_report(rows, out: Path):
    lines = ["| shape | genus (true / result) | start, drilled | grid | b0 b1 b2: object | result | intersection | union "
             "| placed | CD L1 | IoU | seconds | verdict |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b = [" ".join(str(x) for x in r[k]) for k in ("object", "result", "intersection", "union")]
        lines.append(f"| {r['shape']} | {r['genus']} / {r['result_genus']} | {r['start']}, {r['tunnels']} | {r['grid']} | "
                     f"{b[0]}{'' if r['object_resolved'] else ' (grid does not resolve it)'} | {b[1]} | {b[2]} | {b[3]} "
                     f"| {'yes' if r['placed'] else 'NO'} | {r['cd_l1']:.5f} | {r['iou']:.4f} | {r['seconds']:.0f} "
                     f"| {'ok' if r['ok'] else 'NOT OK'} |")
    text = "\n".join(lines) + "\n"
    publish(out / "hidden_handles_benchmark.md", text)
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(1.8 + 1.6 * len(rows), 3.4))
    names = ["object", "result", "intersection", "union"]
    for i, name in enumerate(names):
        ax.bar(np.arange(len(rows)) + 0.2 * (i - 1.5), [r[name][1] for r in rows], 0.2, label=name)
    ax.set_xticks(np.arange(len(rows)), [r["shape"] for r in rows])
    ax.set_ylabel("b1 on the voxel grid")
    ax.set_title("handles placed when all four bars are equal")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "hidden_handles.png", dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=["covered_plate", "long_tunnel_plate", "mug", "shared:boot"])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--grid", type=int, nargs="+", default=[128, 192, 256, 384],
                    help="voxel grids tried in turn; the first that resolves the object scores it")
    ap.add_argument("--options", default="{}", help="ReconstructOptions overrides as JSON")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="docs")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for spec in args.shapes:
        row = run_one(spec, args.res, args.views, args.grid, json.loads(args.options), args.seed)
        if row is not None:
            rows.append(row)
            (out / "hidden_handles.json").write_text(json.dumps(rows, indent=1, default=float))
    if rows:
        write_report(rows, out)


if __name__ == "__main__":
    main()
