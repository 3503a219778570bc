"""The command line's parsers: every subcommand's flags, each with its help and default.

`__main__` runs the commands; this module only says what they accept (`build_parser`).
"""

from __future__ import annotations

import argparse
from typing import Callable

from jaxgenus._batch import add_batch_command

__all__ = ["PRESETS", "build_parser"]

#: `reconstruct --preset`: the `ReconstructOptions` constructors it names (`__main__._options`).
PRESETS = ("default", "fine", "nicolet", "nicolet-fine")


def build_parser(description: str, runs: dict[str, Callable], main: Callable) -> argparse.ArgumentParser:
    """The `jaxgenus` parser; `runs` maps "primitives", "reconstruct" and "demo" to their functions,
    `main` is what `batch` runs per capture."""
    parser = argparse.ArgumentParser(prog="jaxgenus", description=description)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("primitives", help="build genus-g primitives, save them as OBJ and print chi")
    p.add_argument("--genus", type=int, nargs="+", default=[0, 1, 2, 3, 5, 8], help="the genera (default 0 1 2 3 5 8)")
    p.add_argument("--faces", type=int, default=5000, help="faces of each primitive (default 5000)")
    p.add_argument("--out", default="jaxgenus_out", help="output folder (default jaxgenus_out)")
    p.set_defaults(run=runs["primitives"])
    r = sub.add_parser("reconstruct", help="reconstruct a mesh of a given genus from images",
                       epilog="every other setting: --option NAME=VALUE (--option list shows them all). exit codes: "
                              "0 ok; 1 bad input; 2 usage; 3 the result's genus is not the requested one; 4 the "
                              "result does not match its images (see the verdict)")
    _input_arguments(r)
    f = r.add_argument_group("the fit")
    f.add_argument("--genus", default="auto", help="the object's genus, or 'auto' (default): estimated from the silhouettes "
                   "and, for normal maps, the holes the images confirm after a first fit (the log says which decided)")
    f.add_argument("--preset", choices=list(PRESETS), default="default",
                   help="default; fine: thin structures a few pixels wide (sharper edges, up to 20k faces, 5 cycles; "
                        "chosen by the run for a visual hull under 3 px thick); nicolet: the Nicolet et al. 2021 "
                        "baseline (sphere, no remeshing); nicolet-fine: both (default: default)")
    f.add_argument("--max-faces", type=int, default=None, help="face budget, held as given (default 12000; photos "
                   "that resolve more: up to 40000)")
    f.add_argument("--downsample", type=int, default=None, metavar="N",
                   help="fit copies of the images downsampled N times (area average), cameras scaled to match: "
                        "speed over detail (default 1)")
    f.add_argument("--seed", type=int, default=0, help="seed of the views each step samples (default 0; a seed gives "
                   "one result, and other seeds show the run-to-run spread)")
    f.add_argument("--option", action="extend", nargs="+", metavar="NAME=VALUE",
                   help="any setting of ReconstructOptions or of its parts by its own name, held as given, e.g. "
                        "n_cycles=3 steps_per_cycle=100 consistency=0 lighting=directional refits=0 crop=256; "
                        "'list': every setting with its value (repeatable; applied last; default: none)")
    d = r.add_argument_group("devices and processes")
    d.add_argument("--devices", type=int, default=None, metavar="N",
                   help="split the views over the first N devices (default: all of them; 1: one)")
    d.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="join other processes with jax.distributed (with --num-processes, --process-id; 'env': "
                        "from the environment); the views are split over every process's devices, process 0 writes "
                        "(default: one process)")
    d.add_argument("--num-processes", type=int, default=None, metavar="N",
                   help="with --coordinator: the number of processes (default: from the environment)")
    d.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="with --coordinator: this process's index, 0 to N-1 (default: from the environment)")
    r.add_argument_group("output").add_argument(
        "--out", default="jaxgenus_out/reconstruction.obj",
        help="the mesh to write (.obj or .ply; its history beside it as .json; checked before the run; "
             "default jaxgenus_out/reconstruction.obj)")
    r.set_defaults(run=runs["reconstruct"])
    _add_batch_and_demo(sub, runs["demo"], main)
    return parser


def _add_batch_and_demo(sub, demo: Callable, main: Callable) -> None:
    add_batch_command(sub, main)
    d = sub.add_parser("demo", help="reconstruct a built-in scene and print chamfer, IoU and genus")
    d.add_argument("--scene", default="three_tori", choices=["torus", "tilted_tori", "three_tori"],
                   help="the built-in scene (default three_tori, genus 3)")
    d.add_argument("--views", type=int, default=16, help="views rendered on a sphere (default 16)")
    d.add_argument("--res", type=int, default=64, help="their size in pixels (default 64)")
    d.add_argument("--cycles", type=int, default=4, help="optimize/remesh cycles (default 4)")
    d.add_argument("--steps", type=int, default=150, help="optimizer steps per cycle (default 150)")
    d.add_argument("--one-jit", action="store_true", help="all cycles in one compiled scan (ReconstructOptions.one_jit; default: off)")
    d.add_argument("--out", default="jaxgenus_out", help="output folder: SCENE.obj, its history SCENE.json and "
                   "SCENE.png, the targets beside the result (default jaxgenus_out)")
    d.set_defaults(run=demo)


def _input_arguments(r) -> None:
    """The arguments of `reconstruct` about the images and cameras (or the mesh that renders them)."""
    g = r.add_argument_group("images and cameras")
    g.add_argument("--images", help="images: a folder, a quoted glob ('dir/*.png') or a .npy: RGBA PNGs "
                   "(alpha = mask), mask PNGs, or photos with --masks (default: none; give --images or --mesh)")
    g.add_argument("--masks", metavar="FOLDER|white|black[:T]",
                   help="the photos' masks: a folder of mask images paired with them by file name, or 'white' / "
                        "'black': the object is where a pixel's largest channel differs from that uniform "
                        "background by more than T (default 0.1; check the masks; ./white for a folder of that "
                        "name) (default: none, the masks are in the images)")
    g.add_argument("--cameras", help="camera file: OpenCV JSON, COLMAP sparse model, transforms.json, "
                   "IDR/NeuS cameras.npz or Middlebury *_par.txt (paired with the images by name; required with --images)")
    g.add_argument("--targets", choices=["silhouette", "normals", "photo"],
                   help="what RGB images hold (default: inferred); photos are fitted through Lambertian shading "
                        "with an estimated albedo (written as vertex colours, and exactly in OUT.albedo.npy) and light")
    g.add_argument("--region", default="auto", help="a sphere X,Y,Z,R (camera units) the object lies in, cutting the "
                   "visual hull; 'auto' (default): an IDR/NeuS camera file's scale_mat sphere; 'none'")
    s = r.add_argument_group("synthetic targets (instead of --images)")
    s.add_argument("--mesh", help="ground-truth mesh: render normal maps from it and score the result against it "
                   "(default: none; give --mesh or --images)")
    s.add_argument("--views", type=int, default=24, help="with --mesh: views rendered on a sphere (default 24)")
    s.add_argument("--res", type=int, default=128, help="with --mesh: their size in pixels (default 128)")
