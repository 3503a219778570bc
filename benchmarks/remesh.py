"""Benchmark `jaxgenus.remesh` against `gpytoolbox.remesh_botsch` on shared test meshes.

Both run in this process at the same uniform target length (the input's mean edge
length) for the same number of iterations; the adaptive mode is reported beside
them. Prints a markdown table (and writes it to `--out` when given):

    python benchmarks/remesh.py [--meshes pretzel,kitten,botijo,heptoroid] [--iterations 5] [--repeat 3]

Needs `gpytoolbox` (the `bench` extra) and the shared meshes (`$JAXGENUS_SHARED_MESHES`
or `../shared/meshes` beside the repo). Times are the best of `--repeat` calls:
wall clock and process CPU time (both single-threaded here), so the ratio is
meaningful even on a loaded machine. Targets: time <= 0.5x gpytoolbox, chi always
preserved, 1st-percentile min angle >= 25 degrees.
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np
import trimesh

import jaxgenus as jg


def shared_meshes() -> Path:
    env = os.environ.get("JAXGENUS_SHARED_MESHES")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "meshes"


def _trimesh(v, f):
    return trimesh.Trimesh(vertices=np.asarray(v, np.float64), faces=np.asarray(f), process=False)


def min_angles(v, f):
    """Smallest angle of every face in degrees (trimesh, an independent reference)."""
    return np.degrees(_trimesh(v, f).face_angles.min(axis=1))


def euler(v, f):
    return _trimesh(v, f).euler_number


def timed(fn, repeat):
    best_wall, best_cpu, out = np.inf, np.inf, None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        best_wall = min(best_wall, time.perf_counter() - w)
        best_cpu = min(best_cpu, time.process_time() - c)
    return out, best_wall, best_cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", default="pretzel,kitten,botijo,heptoroid")
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=None, help="also write the table to this markdown file")
    args = parser.parse_args()
    import gpytoolbox

    root = shared_meshes()
    if not (root / "MANIFEST.md").is_file():
        raise SystemExit(f"shared meshes not found at {root} (set JAXGENUS_SHARED_MESHES)")
    lines = [
        f"iterations = {args.iterations}, target = mean input edge length, best of {args.repeat}",
        "",
        "| mesh | F in | method | wall (s) | cpu (s) | cpu ratio | F out | min angle p1 / p5 / p50 (deg) | chi in -> out |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    print("\n".join(lines), flush=True)
    jg.remesh(jg.genus_primitive(0, n_faces=200))  # warm up jax and the extension
    for name in args.meshes.split(","):
        tm = trimesh.load(root / f"{name}.obj", process=False)
        v = np.asarray(tm.vertices, np.float64)
        f = np.asarray(tm.faces, np.int32)
        h = float(np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=-1).mean())
        chi_in = euler(v, f)
        (gv, gf), g_wall, g_cpu = timed(lambda: gpytoolbox.remesh_botsch(v, f, args.iterations, h), args.repeat)
        runs = [("gpytoolbox.remesh_botsch", gv, gf, g_wall, g_cpu)]
        for label, opts in (
            ("jaxgenus uniform", jg.RemeshOptions(target_edge_length=h, iterations=args.iterations)),
            ("jaxgenus adaptive", jg.RemeshOptions(target_edge_length=h, adaptive=True, iterations=args.iterations)),
        ):
            (mesh, info), wall, cpu = timed(lambda: jg.remesh((v, f), opts), args.repeat)
            mv, mf = mesh.to_numpy()
            runs.append((label, mv, mf, wall, cpu))
        for label, ov, of, wall, cpu in runs:
            a = min_angles(ov, of)
            p1, p5, p50 = np.percentile(a, [1, 5, 50])
            row = (
                f"| {name} | {len(f)} | {label} | {wall:.3f} | {cpu:.3f} | {cpu / g_cpu:.2f} | {len(of)} "
                f"| {p1:.1f} / {p5:.1f} / {p50:.1f} | {chi_in} -> {euler(np.asarray(ov), np.asarray(of))} |"
            )
            lines.append(row)
            print(row, flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
