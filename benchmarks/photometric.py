"""Photometric targets against silhouettes and normal maps, from independent ray-cast photos.

    python benchmarks/photometric.py                          # kitten and bunny, every case
    python benchmarks/photometric.py --shapes bunny --albedo textured --targets photo
    python benchmarks/photometric.py --report-only             # table + plot from the saved JSON
    python benchmarks/photometric.py --shapes eight mother_child --albedo highfreq --res 256   # issue 31

For every shape (`../shared/meshes/NAME.obj`, centred and scaled into the unit
sphere): 24 views (`sphere_cameras(24, radius=3, fov 40)`) at 128^2, ray cast with
trimesh + embree (`tests/_raycast.py`, which shares nothing with the renderer, one
ray per pixel centre): photos with smooth-normal Lambertian shading under one
directional light plus ambient that the library is not told (direction
(0.4, 0.8, 0.45), ambient 0.25; the library fits its own spherical-harmonic
lighting), with a constant albedo (0.75, 0.6, 0.45), a textured one (a smooth
3D pattern per channel, varying over about a quarter of the object) or a high-frequency
one (`highfreq`: 3D cells of 0.09 with hashed colours, about 10 px at 256^2, which a
per-vertex albedo cannot hold: photo-consistency's case). Runs, each in
a fresh process with default `ReconstructOptions` (`--options` overrides):

* `silhouette`: the photos' masks only (the baseline of the bar);
* `photo`: the RGBA photos, `targets="photo"` (per albedo case);
* `normals`: ray-cast normal maps of the same views (the upper reference).

Metrics: CD L1 and volume IoU after ICP (docs/metrics.md), the mean angle between the
result's normals and the true surface's nearest ones (`normal_angle`), the genus, seconds,
the verdict; for photo runs the recovered albedo (`Reconstruction.albedo`)
against the true albedo function at the result's ICP-aligned vertices: the
Pearson correlation per channel (textured; for a constant albedo its spread,
std / mean) and the median ratio to the truth (the light's mean strength `m`
under the library's convention). Writes OUT/photometric_benchmark.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from _report import publish, pyplot

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))

GENUS = {"kitten": 1, "bunny": 0}
LIGHT, AMBIENT = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45]), 0.25
CONSTANT = (0.75, 0.6, 0.45)


def textured(p):
    """A smooth 3D pattern per channel in [0.25, 0.85] (points in the unit-sphere frame)."""
    p = np.asarray(p, np.float64)
    a = np.stack([np.sin(7.0 * p[:, 0] + 0.3), np.sin(7.0 * p[:, 1] - 1.0), np.sin(5.0 * (p[:, 0] + p[:, 2]))], 1)
    return 0.55 + 0.3 * a


def highfreq(p):
    """A high-frequency texture: 3D cells of 0.09 (about 10 px at 256^2) with hashed colours in [0.1, 0.9]."""
    c = np.floor(np.asarray(p, np.float64) / 0.09).astype(np.int64)
    h = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791)
    return np.stack([0.1 + 0.8 * (((h * (2 * k + 1) * 2654435761) >> 11) % 256) / 255.0 for k in range(3)], 1)


ALBEDOS = {"constant": CONSTANT, "textured": textured, "highfreq": highfreq}


def run_one(shape: str, albedo: str, targets: str, res: int, views: int, options: dict, seed: int) -> dict:
    import jax
    import jaxgenus as jg
    from _raycast import raycast, raycast_lambert
    from reconstruct import load_shape

    gt, genus = load_shape(f"shared:{shape}")
    options = dict(options)
    options.update(options.pop("weights", {}))  # the older form: LossWeights fields as a dict under "weights"
    cams = jg.sphere_cameras(views, radius=3.0, fov_deg=40.0, resolution=res)
    photos = raycast_lambert(cams, gt, light_direction=LIGHT, ambient=AMBIENT,
                             albedo=ALBEDOS[albedo])
    if targets == "silhouette":
        images = photos[..., 3]
    elif targets == "normals":
        images = raycast(cams, gt)
    else:
        images = photos
    rec = jg.reconstruct(images, cams, genus, targets=targets, options=jg.ReconstructOptions().updated(**options),
                         key=jax.random.key(seed))
    aligned = jg.metrics.icp_align(rec.mesh, gt).vertices
    _, f = rec.mesh.to_numpy()
    cd = jg.metrics.chamfer_distance((aligned, f), gt)
    row = dict(shape=shape, albedo=albedo if targets == "photo" else "-", targets=targets, res=res, views=views,
               true_genus=genus, genus=rec.genus, cd_l1=cd.l1, iou=jg.metrics.volume_iou((aligned, f), gt),
               normal_deg=normal_angle((aligned, f), gt),
               seconds=rec.history["seconds"], ok=rec.history["ok"], warnings=rec.history["warnings"],
               options=json.loads(json.dumps(options, default=str)), seed=seed)
    if rec.albedo is not None:
        truth = ALBEDOS[albedo](np.asarray(aligned)) if albedo != "constant" else np.broadcast_to(CONSTANT, rec.albedo.shape)
        row["albedo_ratio"] = np.median(rec.albedo / truth, axis=0).tolist()
        if albedo != "constant":
            row["albedo_corr"] = [float(np.corrcoef(rec.albedo[:, c], truth[:, c])[0, 1]) for c in range(3)]
        else:
            row["albedo_spread"] = (rec.albedo.std(axis=0) / rec.albedo.mean(axis=0)).tolist()
        row["photo_error_median"] = float(np.median(rec.history["photo_error"]))
        _, row["light_mean"] = jg.rendering.directional_lighting(LIGHT, AMBIENT)
    return row


def normal_angle(mesh, gt, n: int = 100_000) -> float:
    """The mean angle (degrees) between the result's face normals at area-uniform samples of its
    surface and the normal of the true surface's nearest face (trimesh's closest point; seed 0)."""
    import trimesh

    v, f = mesh
    ours = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f), process=False)
    tv, tf = gt.to_numpy()
    truth = trimesh.Trimesh(np.asarray(tv, np.float64), np.asarray(tf), process=False)
    points, face = trimesh.sample.sample_surface(ours, n, seed=0)
    _, _, near = trimesh.proximity.closest_point(truth, points)
    cos = np.einsum("ij,ij->i", ours.face_normals[face], truth.face_normals[near])
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).mean())


def _bar(rows) -> list[str]:
    lines = []
    for shape in sorted({r["shape"] for r in rows}):
        sil = next((r for r in rows if r["shape"] == shape and r["targets"] == "silhouette"), None)
        for r in (r for r in rows if r["shape"] == shape and r["targets"] == "photo"):
            if sil is None:
                continue
            limit = {"constant": 0.6, "textured": 0.75, "highfreq": 0.5}[r["albedo"]]
            ratio = r["cd_l1"] / sil["cd_l1"]
            checks = [f"CD {ratio:.2f}x (<= {limit}x): {'yes' if ratio <= limit else 'NO'}",
                      f"IoU {r['iou']:.3f} >= {sil['iou']:.3f}: {'yes' if r['iou'] >= sil['iou'] else 'NO'}",
                      f"genus kept: {'yes' if r['genus'] == r['true_genus'] else 'NO'}"]
            nrm = next((n for n in rows if n["shape"] == shape and n["targets"] == "normals"), None)
            if r["albedo"] == "highfreq" and nrm is not None:
                rn = r["cd_l1"] / nrm["cd_l1"]
                checks.append(f"CD {rn:.2f}x the normal maps' (<= 1.3x): {'yes' if rn <= 1.3 else 'NO'}")
                if "normal_deg" in r and "normal_deg" in nrm:
                    checks.append(f"normal angle {r['normal_deg']:.2f} deg, {r['normal_deg'] / nrm['normal_deg']:.2f}x the "
                                  "normal maps'")
            if "albedo_corr" in r and r["albedo"] != "highfreq":
                checks.append(f"albedo corr >= 0.8: {'yes' if min(r['albedo_corr']) >= 0.8 else 'NO'}")
            lines.append(f"- {shape}, {r['albedo']} albedo: " + "; ".join(checks))
    return lines


def write_report(rows, out: Path):
    order = {"silhouette": 0, "photo": 1, "normals": 2}
    rows = sorted(rows, key=lambda r: (r["shape"], order[r["targets"]], r["albedo"]))
    lines = ["| shape | albedo | targets | CD L1 | CD / silhouette CD | IoU | normal angle deg | genus ok | albedo corr "
             "(r, g, b) or spread | albedo / truth | photo error | seconds | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sil = next((s for s in rows if s["shape"] == r["shape"] and s["targets"] == "silhouette"), None)
        rel = f"{r['cd_l1'] / sil['cd_l1']:.2f}" if sil else ""
        alb = ", ".join(f"{x:.3f}" for x in r.get("albedo_corr", r.get("albedo_spread", [])))
        if "albedo_spread" in r:
            alb = f"spread {alb}"
        ratio = ", ".join(f"{x:.3f}" for x in r.get("albedo_ratio", []))
        perr = f"{r['photo_error_median']:.4f}" if "photo_error_median" in r else ""
        angle = f"{r['normal_deg']:.2f}" if "normal_deg" in r else ""
        lines.append(f"| {r['shape']} | {r['albedo']} | {r['targets']} | {r['cd_l1']:.5f} | {rel} | {r['iou']:.4f} | {angle} | "
                     f"{'yes' if r['genus'] == r['true_genus'] else 'NO'} | {alb} | {ratio} | {perr} | "
                     f"{r['seconds']:.0f} | {'ok' if r['ok'] else 'NOT OK'} |")
    text = "\n".join(lines + [""] + _bar(rows)) + "\n"
    publish(out / "photometric_benchmark.md", text)
    plt = pyplot()
    if plt is None:
        return
    shapes = sorted({r["shape"] for r in rows})
    fig, ax = plt.subplots(1, len(shapes), figsize=(5 * len(shapes), 3.6), squeeze=False)
    for a, shape in zip(ax[0], shapes):
        rs = [r for r in rows if r["shape"] == shape]
        names = [r["targets"] + (f"\n({r['albedo']})" if r["targets"] == "photo" else "") for r in rs]
        a.bar(range(len(rs)), [r["cd_l1"] for r in rs], color=["C0" if r["targets"] == "photo" else "C7" for r in rs])
        a.set_xticks(range(len(rs)), names, fontsize=8)
        a.set_title(f"{shape}: CD L1 (lower is better)")
    fig.tight_layout()
    fig.savefig(out / "photometric_benchmark.png", dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=["kitten", "bunny"])
    ap.add_argument("--albedo", nargs="+", default=["constant", "textured"])
    ap.add_argument("--targets", nargs="+", default=["silhouette", "photo", "normals"])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--options", default="{}",
                    help="ReconstructOptions settings and plan entries by name, as JSON")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="docs")
    ap.add_argument("--resume", action="store_true", help="keep the rows already saved")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        row = run_one(*args.one, args.res, args.views, json.loads(args.options), args.seed)
        print(json.dumps(row, default=float))
        return
    from reconstruct import shared_dir

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "photometric_benchmark.json"
    rows = json.loads(saved.read_text()) if (args.resume or args.report_only) and saved.is_file() else []
    if not args.report_only:
        root = shared_dir()
        done = {(r["shape"], r["albedo"], r["targets"]) for r in rows}
        for shape in args.shapes:
            if root is None or not (root / f"{shape}.obj").is_file():
                print(f"{shape}: not in ../shared/meshes, skipped", flush=True)
                continue
            for targets in args.targets:
                for albedo in (args.albedo if targets == "photo" else [args.albedo[0]]):
                    if (shape, albedo if targets == "photo" else "-", targets) in done:
                        continue
                    cmd = [sys.executable, __file__, "--one", shape, albedo, targets, "--res", str(args.res),
                           "--views", str(args.views), "--options", args.options, "--seed", str(args.seed)]
                    proc = subprocess.run(cmd, capture_output=True, text=True)
                    if proc.returncode != 0:
                        print(f"{shape} {albedo} {targets}: failed\n{proc.stderr[-2000:]}", flush=True)
                        continue
                    r = json.loads(proc.stdout.strip().splitlines()[-1])
                    rows.append(r)
                    print(f"{shape:8s} {r['albedo']:9s} {targets:10s} genus {r['genus']}/{r['true_genus']}  "
                          f"CD {r['cd_l1']:.5f}  IoU {r['iou']:.4f}  {r['seconds']:.0f}s  "
                          f"{'ok' if r['ok'] else 'NOT OK'}", flush=True)
                    saved.write_text(json.dumps(rows, default=float))
    write_report(rows, out)


if __name__ == "__main__":
    main()
