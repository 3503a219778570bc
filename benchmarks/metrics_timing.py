"""Time the evaluation metrics and measure the Monte-Carlo spread of volume_iou.

Usage:
    python benchmarks/metrics_timing.py [--mesh PATH] [--n-samples N] [--seeds K]

The prediction is the mesh itself, normalized, then moved by a small rigid motion
and a smooth radial bump, so every metric has something to measure. Prints a
markdown table of timings and values, then the mean and standard deviation of
volume_iou over K seeds next to the predicted standard error
sqrt(iou * (1 - iou) / (n * union_fraction)).
"""

import argparse
import time

import numpy as np
import trimesh

from jaxgenus import metrics


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", help="OBJ path (default: icosphere, 5 subdivisions)")
    parser.add_argument("--n-samples", type=int, default=100_000)
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()

    if args.mesh:
        gt = trimesh.load(args.mesh, process=False)
    else:
        gt = trimesh.creation.icosphere(subdivisions=5)
    v, f, _, _ = metrics.normalize_to_unit_sphere(gt)
    bump = 1.0 + 0.02 * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])
    angle = 0.05
    ca, sa = np.cos(angle), np.sin(angle)
    rot = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    pred_v = (v * bump[:, None]) @ rot.T + [0.01, -0.02, 0.0]
    pred = (pred_v, f)
    gt_n = (v, f)
    n = args.n_samples

    rows = []

    def timed(name, fn, describe):
        t = time.perf_counter()
        out = fn()
        rows.append((name, time.perf_counter() - t, describe(out)))
        return out

    aligned = timed(
        "icp_align (10k samples)",
        lambda: metrics.icp_align(pred, gt_n),
        lambda r: f"residual={r.residual:.3e}",
    )
    moved = (aligned.vertices, f)
    timed(
        "chamfer_distance",
        lambda: metrics.chamfer_distance(moved, gt_n, n_samples=n),
        lambda c: f"l1={c.l1:.4e}, l2_pytorch3d={c.l2_pytorch3d:.4e}",
    )
    timed("hausdorff_distance", lambda: metrics.hausdorff_distance(moved, gt_n, n_samples=n), str)
    timed("volume_iou", lambda: metrics.volume_iou(moved, gt_n, n_samples=n), str)

    print(f"mesh: {args.mesh or 'icosphere(5)'}, {len(v)} vertices, {len(f)} faces, n_samples={n}")
    print("| metric | seconds | value |")
    print("|---|---|---|")
    for name, sec, value in rows:
        print(f"| {name} | {sec:.3f} | {value} |")

    ious = np.array([metrics.volume_iou(pred, gt_n, n_samples=n, seed=s) for s in range(args.seeds)])
    lo = np.minimum(pred_v.min(0), v.min(0))
    hi = np.maximum(pred_v.max(0), v.max(0))
    iou = ious.mean()
    volumes = trimesh.Trimesh(pred_v, f, process=False).volume + trimesh.Trimesh(v, f, process=False).volume
    union = volumes / (1.0 + iou)  # |A u B| = (|A| + |B|) / (1 + IoU)
    union_fraction = union / np.prod(hi - lo)
    predicted = np.sqrt(iou * (1 - iou) / (n * union_fraction))
    print(
        f"volume_iou over {args.seeds} seeds: mean {iou:.5f}, std {ious.std(ddof=1):.5f}, "
        f"predicted standard error {predicted:.5f} (union fraction {union_fraction:.3f})"
    )


if __name__ == "__main__":
    main()
