"""Quality and time against image resolution, from independent ray-cast normal views.

    python benchmarks/resolution.py --shapes shared:boot shared:skull --res 128 512
    python benchmarks/resolution.py --report-only        # table + plot from the saved JSON

For every shape and resolution: 24 views (`sphere_cameras(24, radius=3, fov 40)`)
ray cast with trimesh + embree (tests/_raycast.py, which shares nothing with the
renderer), one pixel-centre ray per pixel (binary alpha, like a mask), then
`reconstruct(targets, cams, genus)` with default options, each run in a fresh
process. Metrics as in benchmarks/reconstruct.py (ICP, then CD L1 and volume IoU,
docs/metrics.md; the ICP transform is kept only when it lowers the CD, `aligned_by`),
and the true surface's distance to the result split by how many
of the cameras see each point (`seen_split`): "well seen" (>= 6 of the views see it,
unoccluded and facing) against "few views" (1-5: concavities), where image
resolution matters little. Shapes: `shared:NAME` (../shared/meshes) and `thin:gecko`, a
thin elongated body with legs, fins and a tail built here with manifold3d.
Writes OUT/resolution_benchmark.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _report import publish, pyplot

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def gecko():
    """A thin elongated genus-0 shape: a 2-unit body of radius 0.06, four 0.025-radius
    legs, two 0.02-thick fins and a tapering tail (manifold3d booleans)."""
    import manifold3d as m3

    def cyl(p, q, r):
        p, q = np.asarray(p, float), np.asarray(q, float)
        d = q - p
        length = float(np.linalg.norm(d))
        c = m3.Manifold.cylinder(length, r, r, 24)
        z = np.array([0.0, 0.0, 1.0])
        axis = np.cross(z, d / length)
        s, co = np.linalg.norm(axis), float(np.dot(z, d / length))
        if s > 1e-9:
            ang = np.degrees(np.arctan2(s, co))
            k = axis / s
            # rotate z onto d: manifold3d rotates by Euler angles, so build the matrix ourselves
            kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            rot = np.eye(3) + np.sin(np.radians(ang)) * kx + (1 - np.cos(np.radians(ang))) * kx @ kx
            c = c.transform(np.hstack([rot, p[:, None]]).tolist())
        else:
            c = c.translate(tuple(p))
        return c

    body = cyl([-1.0, 0, 0], [1.0, 0, 0], 0.06) + m3.Manifold.sphere(0.06, 24).translate((1.0, 0, 0))
    body += m3.Manifold.sphere(0.09, 24).translate((1.05, 0, 0))  # head
    for x in (-0.5, 0.45):
        for y in (-1, 1):
            body += cyl([x, 0, 0], [x + 0.1, 0.35 * y, -0.3], 0.025)
    for x in (-0.2, 0.3):
        body += m3.Manifold.cube((0.25, 0.02, 0.18), True).translate((x, 0, 0.12))
    body += m3.Manifold.cylinder(0.6, 0.05, 0.008, 24).rotate((0, -90, 0)).translate((-1.0, 0, 0))
    mesh = body.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], float), np.asarray(mesh.tri_verts, np.int64)


def load(spec: str):
    import jaxgenus as jg
    from reconstruct import load_shape

    if spec == "thin:gecko":
        v, f = gecko()
        v = v - 0.5 * (v.min(0) + v.max(0))
        return jg.Mesh.from_numpy(v / np.linalg.norm(v, axis=1).max(), f), 0
    return load_shape(spec)


def seen_split(gt, cams, result_vf, n_points: int = 50_000, well_seen: int = 6) -> dict:
    """Mean distance from area-uniform points of the true surface to the result surface
    (exact, libigl), over the points seen by at least `well_seen` cameras and over
    those seen by fewer (but at least one), with their area shares. A point is seen
    by a camera when it faces it and the first hit along the ray from the camera
    centre is the point itself (embree, on the true mesh)."""
    import igl
    import trimesh
    from _raycast import intersector

    v, f = gt.to_numpy()
    tm = trimesh.Trimesh(np.asarray(v, float), np.asarray(f, np.int64), process=False)
    pts, face = trimesh.sample.sample_surface(tm, n_points, seed=0)
    normals = tm.face_normals[face]
    rays = intersector(tm)
    seen = np.zeros(len(pts), int)
    for c in np.asarray(cams.centers, float):
        d = pts - c
        length = np.linalg.norm(d, axis=1)
        d /= length[:, None]
        hit, ray, _ = rays.intersects_location(np.repeat(c[None], len(pts), 0), d, multiple_hits=False)
        first = np.full(len(pts), np.inf)
        first[ray] = np.linalg.norm(hit - c, axis=1)
        seen += ((normals * d).sum(1) < 0) & (first > length - 1e-4)
    rv, rf = result_vf
    dist = np.sqrt(igl.point_mesh_squared_distance(pts, np.asarray(rv, float), np.asarray(rf, np.int64))[0])
    well, few = seen >= well_seen, (seen >= 1) & (seen < well_seen)
    return dict(d_well_seen=float(dist[well].mean()), d_few_views=float(dist[few].mean()) if few.any() else 0.0,
                area_few_views=float(few.mean()), area_unseen=float((seen == 0).mean()),
                few_views_error_share=float(dist[few].sum() / dist.sum()))


def run_one(spec: str, res: int, views: int, options: dict) -> dict:
    import jaxgenus as jg
    from _raycast import raycast

    gt, genus = load(spec)
    cams = jg.sphere_cameras(views, radius=3.0, fov_deg=40.0, resolution=res)
    t = time.perf_counter()
    targets = raycast(cams, gt)
    raycast_s = time.perf_counter() - t
    rec = jg.reconstruct(targets, cams, genus, options=jg.ReconstructOptions().updated(**options))
    v, f = rec.mesh.to_numpy()
    icp = jg.metrics.icp_align(rec.mesh, gt).vertices
    # the cameras are the truth's, so the frame is exact; ICP only removes a small drift, and on a
    # thin shape with a stray part it can slide the whole result (gecko at 128²: CD 0.027 -> 0.054)
    cd_icp, cd_none = jg.metrics.chamfer_distance((icp, f), gt), jg.metrics.chamfer_distance((v, f), gt)
    aligned, cd, how = (icp, cd_icp, "icp") if cd_icp.l1 <= cd_none.l1 else (v, cd_none, "none")
    h = rec.history
    r = dict(cd_l1=cd.l1, aligned_by=how, iou=jg.metrics.volume_iou((aligned, f), gt), genus=rec.genus,
             faces=int(rec.mesh.n_faces),
             seconds=h["seconds"], start=h["start"], fine=h["fine"], sil_iou_min=min(h["silhouette_iou"]), ok=h["ok"])
    r.update(seen_split(gt, cams, (aligned, f)))
    r.update(shape=spec, res=res, views=views, true_genus=genus, raycast_s=raycast_s, options=options)
    import resource

    r["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return r


def write_report(rows, out: Path):
    rows = sorted(rows, key=lambda r: (r["shape"], r["res"]))
    lines = [
        "| shape | genus | res | start | result genus | CD L1 | CD / CD at 128 | IoU | well seen: d | few views: d (area) "
        "| faces | seconds | time / time at 128 | verdict | peak RSS GB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    base = {r["shape"]: r for r in rows if r["res"] == 128}
    for r in rows:
        b = base.get(r["shape"])
        rel_cd = f"{r['cd_l1'] / b['cd_l1']:.2f}" if b else ""
        rel_t = f"{r['seconds'] / b['seconds']:.2f}" if b else ""
        lines.append(
            f"| {r['shape']} | {r['true_genus']} | {r['res']} | {r['start']} | {r['genus']} | {r['cd_l1']:.4f} | "
            f"{rel_cd} | {r['iou']:.3f} | {r['d_well_seen']:.4f} | {r['d_few_views']:.4f} ({r['area_few_views']:.0%}) | "
            f"{r['faces']} | {r['seconds']:.0f} | {rel_t} | {'ok' if r['ok'] else 'NOT OK'} | "
            f"{r['peak_rss_gb']:.2f} |"
        )
    table = "\n".join(lines) + "\n"
    publish(out / "resolution_benchmark.md", table)
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(1, 4, figsize=(18, 4))
    for shape in sorted({r["shape"] for r in rows}):
        rs = [r for r in rows if r["shape"] == shape]
        res = [r["res"] for r in rs]
        ax[0].plot(res, [r["cd_l1"] for r in rs], "o-", label=shape)
        ax[1].plot(res, [r["iou"] for r in rs], "o-", label=shape)
        ax[2].plot(res, [r["seconds"] for r in rs], "o-", label=shape)
        ax[3].plot(res, [r["d_well_seen"] for r in rs], "o-", label=f"{shape}, >= 6 views")
        ax[3].plot(res, [r["d_few_views"] for r in rs], "x--", label=f"{shape}, 1-5 views")
    for a, title in zip(ax, ("CD L1 (lower is better)", "volume IoU", "reconstruct seconds (2-core CPU)",
                             "true surface to result, by views that see it")):
        a.set_xscale("log", base=2)
        a.set_xlabel("image resolution (px)")
        a.set_title(title)
    ax[0].set_yscale("log")
    ax[3].set_yscale("log")
    ax[0].legend(fontsize=8)
    ax[3].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "resolution_benchmark.png", dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=["shared:boot", "shared:skull", "shared:heptoroid", "thin:gecko"])
    ap.add_argument("--res", nargs="+", type=int, default=[128, 256, 512, 1024])
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--options", default="{}", help="ReconstructOptions overrides as JSON, e.g. '{\"crop\": 128}'")
    ap.add_argument("--out", default="docs")
    ap.add_argument("--resume", action="store_true", help="keep the rows already saved")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one[0], int(args.one[1]), args.views, json.loads(args.options)), default=float))
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "resolution_benchmark.json"
    rows = json.loads(saved.read_text()) if (args.resume or args.report_only) and saved.is_file() else []
    if not args.report_only:
        done = {(r["shape"], r["res"]) for r in rows}
        for spec in args.shapes:
            for res in args.res:
                if (spec, res) in done:
                    continue
                cmd = [sys.executable, __file__, "--one", spec, str(res), "--views", str(args.views),
                       "--options", args.options]
                proc = subprocess.run(cmd, capture_output=True, text=True)
                if proc.returncode != 0:
                    print(f"{spec} {res}: failed\n{proc.stderr[-2000:]}", flush=True)
                    continue
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                rows.append(r)
                print(f"{spec:18s} {res:5d}  genus {r['genus']}/{r['true_genus']}  CD {r['cd_l1']:.4f}  "
                      f"IoU {r['iou']:.3f}  faces {r['faces']}  {r['seconds']:.0f}s  "
                      f"{'ok' if r['ok'] else 'NOT OK'}", flush=True)
                saved.write_text(json.dumps(rows, default=float))
    write_report(rows, out)


if __name__ == "__main__":
    main()
