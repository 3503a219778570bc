"""The command line's parsers: every subcommand's flags, each with its help and default.

`__main__` runs the commands; this module only says what they accept (`build_parser`).
"""

from __future__ import annotations

import argparse
from typing import Callable

from jaxgenus._batch import add_batch_command

__all__ = ["build_parser"]


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
                       epilog="exit codes: 0 ok; 1 bad input; 2 usage; 3 the result's genus is not the "
                              "requested one; 4 the result does not match its images (see the verdict)")
    r.add_argument("--mesh", help="ground-truth mesh: render synthetic targets from it (default: none; give --mesh or --images)")
    r.add_argument("--seed", type=int, default=0, help="seed of the views each step samples (default 0; a seed gives "
                   "one result, and other seeds show the run-to-run spread)")
    r.add_argument("--images", help="images: a folder, a quoted glob ('dir/*.png') or a .npy: RGBA PNGs "
                   "(alpha = mask), mask PNGs, or photos with --masks / --background (default: none; give --images or --mesh)")
    r.add_argument("--masks", help="folder of mask images paired with the photos by file name (default: none, the masks are in the images)")
    r.add_argument("--background", choices=["black", "white"], help="threshold masks off a uniform background (default: none)")
    r.add_argument("--threshold", type=float, default=0.1, help="with --background: a pixel is the object when its "
                   "largest channel differs from the background by more than this (default 0.1); check the masks")
    _photo_arguments(r)
    r.add_argument("--hidden-handles", choices=["images", "drill"], default=None,
                   help="handles the silhouettes do not show: open them where the normal images show holes "
                        "(default), or drill small tunnels at spread-out sites")
    r.add_argument("--cameras", help="camera file: OpenCV JSON, COLMAP sparse model, transforms.json, "
                   "IDR/NeuS cameras.npz or Middlebury *_par.txt (paired with the images by name; required with --images)")
    r.add_argument("--region", default="auto", help="a sphere X,Y,Z,R (camera units) the object lies in, cutting the "
                   "visual hull; 'auto' (default): an IDR/NeuS camera file's scale_mat sphere; 'none'")
    r.add_argument("--genus", default="auto", help="the object's genus, or 'auto' (default): estimated from the silhouettes and, "
                   "for normal maps, the holes the images confirm after a first fit (the log says which decided)")
    r.add_argument("--refits", type=int, default=None, help="fits after the first, each started from the previous "
                   "result: carves concavities few views see (default: up to 2 for normal maps over 1.5 x the "
                   "coarse resolution, else 0; ReconstructOptions.refits)")
    r.add_argument("--refit-carve", type=float, default=None, help="in refits of normal maps, move the surface away "
                   "from the camera where its normals contradict the images, with this weight (default 1; 0: off; "
                   "ReconstructOptions.refit_carve)")
    r.add_argument("--max-faces", type=int, default=None, help="face budget, held as given (default 12000; photos that resolve more: up to 40000)")
    r.add_argument("--option", action="append", metavar="NAME=VALUE",
                   help="any setting of ReconstructOptions or of its parts by its own name, e.g. --option "
                        "learning_rate=0.05 --option adaptive=True --option sigma=0.03 (repeatable; applied last; default: none)")
    r.add_argument("--devices", type=int, default=None, metavar="N",
                   help="split the views over the first N devices (default: all of them; 1: one)")
    r.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="join other processes with jax.distributed (with --num-processes, --process-id; 'env': "
                        "from the environment); the views are split over every process's devices, process 0 writes (default: one process)")
    r.add_argument("--num-processes", type=int, default=None, metavar="N",
                   help="with --coordinator: the number of processes (default: from the environment)")
    r.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="with --coordinator: this process's index, 0 to N-1 (default: from the environment)")
    r.add_argument("--downsample", type=int, default=None, metavar="N",
                   help="fit copies of the images downsampled N times (area average), cameras scaled to match: "
                        "speed over detail (default 1)")
    r.add_argument("--coarse-resolution", type=int, default=None,
                   help="large images: early cycles fit copies downsampled to about this many pixels (default 128; 0: "
                        "full size throughout)")
    r.add_argument("--crop", type=int, default=None,
                   help="large images: the native-resolution cycles render random crops of this size (default 0: "
                        "whole views)")
    r.add_argument("--edge-length", type=float, default=None, help="final target edge length in pixels (default 1.4)")
    r.add_argument("--views", type=int, default=24, help="with --mesh: views rendered on a sphere (default 24)")
    r.add_argument("--res", type=int, default=128, help="with --mesh: their size in pixels (default 128)")
    r.add_argument("--cycles", type=int, default=None, help="optimize/remesh cycles (default 4; 5 with --fine and for photos of a fine texture)")
    r.add_argument("--steps", type=int, default=150, help="optimizer steps per cycle (default 150)")
    r.add_argument("--nicolet", action="store_true", help="the Nicolet et al. 2021 baseline (sphere, no remeshing; "
                   "default: off)")
    r.add_argument("--fine", action="store_true", help="settings for thin structures a few pixels wide "
                   "(ReconstructOptions.fine(): sharper edges, up to 20k faces, 5 cycles; default: chosen by the run for "
                   "a visual hull under 3 px thick)")
    r.add_argument("--one-jit", action="store_true", help="all cycles in one compiled scan (ReconstructOptions.one_jit; default: off)")
    r.add_argument("--out", default="jaxgenus_out/reconstruction.obj",
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


def _photo_arguments(r) -> None:
    """The arguments of `reconstruct` about what the images hold and how photos are fitted."""
    r.add_argument("--targets", choices=["silhouette", "normals", "photo"],
                   help="what RGB images hold (default: inferred); photos are fitted through Lambertian shading "
                        "with an estimated albedo (written as vertex colours, and exactly in OUT.albedo.npy) and light")
    r.add_argument("--lighting", choices=["sh", "directional"], default=None,
                   help="photo targets: the lighting model, spherical harmonics (default; any smooth light) or one "
                        "lamp plus ambient (exact for a single lamp)")
    r.add_argument("--photo-consistency", type=float, metavar="W", help="photo targets: photo-consistency weight (default 1; 0: off)")
    r.add_argument("--albedo-edges", type=float, metavar="W",
                   help="photo targets: weight of the photometric error next to albedo edges (default 1; 0: left out, "
                        "for a texture finer than the mesh)")
    r.add_argument("--shading", choices=["flat", "smooth"], default=None,
                   help="photo targets: a colour per face, or per vertex interpolated over the faces (smooth; default flat)")
    r.add_argument("--shading-ratio", type=float, metavar="W",
                   help="photo targets: weight of the albedo-free shading term (log ratios of nearby pixels; default: "
                        "6 for photos of a fine texture, else off; 0: off)")
    r.add_argument("--stereo", type=float, metavar="W",
                   help="photo targets: weight of the plane-sweep stereo depth term (default 1; 0: no stereo, "
                        "neither the depth term nor the carving of the start)")
    r.add_argument("--polish-cycles", type=int, metavar="N",
                   help="photo targets with photo-consistency: closing cycles on the silhouettes and colour "
                        "photo-consistency only, no remesh (default: 2 for photos of a fine texture, else none; "
                        "0: none)")
