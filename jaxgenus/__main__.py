"""Command line: `python -m jaxgenus <command>` (also installed as `jaxgenus`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="jaxgenus", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("primitives", help="build genus-g primitives, save them as OBJ and print chi")
    p.add_argument("--genus", type=int, nargs="+", default=[0, 1, 2, 3, 5, 8])
    p.add_argument("--faces", type=int, default=5000)
    p.add_argument("--out", default="jaxgenus_out")
    p.set_defaults(run=_primitives)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
