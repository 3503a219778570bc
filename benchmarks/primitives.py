"""Benchmark `genus_primitive`: size, topology, triangle quality and construction time.

Prints a markdown table (and writes it to `--out` when given):

    python benchmarks/primitives.py [--n-faces 5000] [--genera 0,1,2,3,5,8,13,22,30] [--repeat 3]

The time is the best of `--repeat` calls (wall clock, single process).
"""

import argparse
import time

import numpy as np
import trimesh

import jaxgenus


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-faces", type=int, default=5000)
    parser.add_argument("--genera", default="0,1,2,3,5,8,13,22,30")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=None, help="also write the table to this markdown file")
    args = parser.parse_args()

    lines = [
        f"n_faces = {args.n_faces}",
        "",
        "| genus | V | F | chi | 2-2g | 1st pct min angle (deg) | min angle (deg) "
        "| max dihedral (deg) | time (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    print("\n".join(lines), flush=True)
    for g in (int(s) for s in args.genera.split(",")):
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            mesh = jaxgenus.genus_primitive(g, n_faces=args.n_faces)
            times.append(time.perf_counter() - t0)
        v, f = mesh.to_numpy()
        tm = trimesh.Trimesh(vertices=v, faces=f, process=False)
        min_angle = np.degrees(tm.face_angles.min(axis=1))
        row = (
            f"| {g} | {len(v)} | {len(f)} | {tm.euler_number} | {2 - 2 * g} "
            f"| {np.percentile(min_angle, 1):.1f} | {min_angle.min():.1f} "
            f"| {np.degrees(tm.face_adjacency_angles.max()):.1f} | {min(times):.3f} |"
        )
        lines.append(row)
        print(row, flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
