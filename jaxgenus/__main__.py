"""Command line: `python -m jaxgenus <command>` (also installed as `jaxgenus`)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from jaxgenus._cli import build_parser


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


#: Exit codes of `jaxgenus reconstruct` and `jaxgenus demo` (documented in the README).
EXIT_OK, EXIT_INPUT, EXIT_USAGE, EXIT_GENUS, EXIT_NOT_OK = 0, 1, 2, 3, 4


class _InputError(Exception):
    """Bad input: reported as one `error:` line, exit code EXIT_INPUT."""


class _UsageError(_InputError):
    """A flag the run cannot use (an --out it cannot write, a value out of range): exit code EXIT_USAGE."""


def _clock(t0):
    def say(line):
        print(f"[{time.perf_counter() - t0:6.1f}s] {line}", flush=True)

    return say


def _progress(say):
    seconds = []  # per cycle, over every fit

    def show(row, mesh):
        seconds.append(row["seconds"])
        done, total = len(seconds), row["fits"] * row["n_cycles"]  # the fits share their cycle count
        if row["eta"] is None:  # one jit: no cost model
            eta = sum(seconds) / done * max(total - done, 0)
        else:  # this fit's estimate (later levels by their pixels, the verdict); a refit costs as much
            this_fit = sum(seconds[done - row["cycle"] - 1:]) + row["eta"]
            eta = row["eta"] + (row["fits"] - row["fit"] - 1) * this_fit
        bar = "#" * done + "." * max(total - done, 0)
        fit = f"fit {row['fit'] + 1}/{row['fits']} " if row["fits"] > 1 else ""
        what = "polish cycle" if row["polish"] else "cycle"
        say(f"[{bar}] {fit}{what} {row['cycle'] + 1}/{row['n_cycles']}  loss {row['loss']:.4f}  faces {row['faces']}"
            f"  chi {row['chi']}  {sum(seconds):.0f}s in cycles, ETA {eta:.0f}s")

    return show


def _report(rec, gt=None):
    import jaxgenus as jg

    h = rec.history
    est = h["genus_estimate"]  # the cue that decided and the agreement of the cues, or the genus asked for
    asked = f"estimated from the {est.cue}, agreement {est.agreement:.0%}" if est is not None else f"requested {h['requested_genus']}"
    print(f"genus {rec.genus} ({asked})  faces {int(rec.mesh.n_faces)}"
          f"  time {h['seconds']:.1f}s  start {h['start']}"
          + ("  (thin visual hull: fine() settings)" if h["fine"] else ""))
    iou = np.asarray(h["silhouette_iou"])
    print(f"silhouette IoU per view: min {iou.min():.3f}  mean {iou.mean():.3f}  (start: mean "
          f"{np.mean(h['start_silhouette_iou']):.3f})")
    if gt is not None:
        cd = jg.metrics.chamfer_distance(rec.mesh, gt, n_samples=30_000)
        viou = jg.metrics.volume_iou(rec.mesh, gt, n_samples=100_000)
        print(f"chamfer L1 {cd.l1:.5f}  chamfer L2 (PyTorch3D) {cd.l2_pytorch3d:.3e}  volume IoU {viou:.3f}")
    print(f"verdict: {'ok' if h['ok'] else 'NOT OK: the result does not match its images'}")
    for w in h["warnings"]:
        print(f"  - {w}")


def _write(rec, out):
    import json

    import jaxgenus as jg

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    jg.save_mesh(rec.mesh, out, vertex_colors=rec.albedo)  # photo targets: the albedo as vertex colours
    if rec.albedo is not None:
        np.save(out.with_suffix(".albedo.npy"), rec.albedo)
    out.with_suffix(".json").write_text(json.dumps(rec.history.to_json(), default=float))
    print(f"wrote {out} and {out.with_suffix('.json')}")


def _exit_code(rec) -> int:
    if not rec.genus_ok:
        return EXIT_GENUS
    return EXIT_OK if rec.history["ok"] else EXIT_NOT_OK


def _options(args):
    """The options of a run: the `--preset`'s, with `--max-faces`, `--downsample`, `--devices` and
    every `--option` held as given (`ReconstructOptions.updated`)."""
    import jaxgenus as jg

    base = jg.ReconstructOptions.nicolet() if args.preset.startswith("nicolet") else jg.ReconstructOptions()
    base = base.fine() if args.preset.endswith("fine") else base
    change = {name: getattr(args, name) for name in ("max_faces", "downsample", "devices")
              if getattr(args, name, None) is not None}
    for item in args.option or []:
        name, value = _setting(item)
        change[name] = value
    if not base.remesh and "max_faces" in change:  # no remeshing: the start's faces are the budget
        change["initial_faces"] = min(base.initial_faces, change.pop("max_faces"))
    try:
        return base.updated(**change)
    except ValueError as err:  # name the flag that gave the setting
        named = next((n for n in change if f"options.{n} " in str(err) or f"'{n}'" in str(err)), None)
        flag = f"--{named.replace('_', '-')}" if named in ("max_faces", "downsample", "devices") else "--option"
        raise _UsageError(f"{flag}: {err}") from None


def _settings_list(opts) -> str:
    """Every name `--option` takes, `name=value` per line: the settings, then the plan entries."""
    from jaxgenus.pipeline._options import ENTRIES

    names = [f.name for f in dataclasses.fields(opts) if f.name not in ("entries", "held")]
    return "\n".join(["settings: " + ", ".join(f"{n}={getattr(opts, n)!r}" for n in names),
                      "plan entries (the run decides them where not given): "
                      + ", ".join(f"{n}={getattr(opts, n)!r}" for n in ENTRIES)])


def _setting(item: str):
    """`NAME=VALUE` of `--option`: VALUE as a Python literal (number, True/False, None, tuple), else a string."""
    import ast

    name, eq, text = item.partition("=")
    if not eq or not name.strip().isidentifier():
        raise _InputError(f"--option: expected NAME=VALUE (a setting of ReconstructOptions or a plan entry), got {item!r}")
    try:
        value = ast.literal_eval(text.strip())
    except (ValueError, SyntaxError):
        value = text.strip()
    return name.strip(), value


def _mask_source(text):
    """`(masks folder, background, threshold)` of `--masks`: a folder, or `white` / `black` with an optional
    `:T` threshold (default 0.1)."""
    colour, _, t = (text or "").partition(":")
    if colour not in ("white", "black"):
        return text, None, 0.1
    try:
        threshold = float(t) if t else 0.1
    except ValueError:
        threshold = -1.0
    if not 0.0 < threshold < 1.0:
        raise _UsageError(f"--masks {text}: expected white or black with a threshold T in (0, 1) after ':', got {t!r}")
    return None, colour, threshold


def _captured(args, say, devices):
    """Images and cameras from files, paired; prints what was read and how it was paired. With
    processes joined, each reads only the views its devices render (`held_views`); returns
    `(images, cams, targets, views)` (views: None when all were read)."""
    import jax

    import jaxgenus as jg

    share = jax.process_count() > 1
    masks, background, threshold = _mask_source(args.masks)
    files = not str(args.images).lower().endswith(".npy")  # 8-bit pixels as read: a quarter of the memory
    loaded = jg.load_images(args.images, masks=masks, background=background, targets=args.targets,
                            background_threshold=threshold, dtype=np.uint8 if files else np.float32,
                            views=(lambda n: jg.optim.held_views(n, devices)) if share else None)
    size = loaded.images.shape[1:3]
    cams, cam_names = jg.load_cameras(args.cameras, image_size=tuple(int(x) for x in size))
    order, how = jg.pair_images(loaded.names, cam_names, n_images=loaded.count, n_cameras=len(cams))
    cams = cams[np.asarray(order)]
    say(f"images: {loaded.source}; {loaded.count} views of {size[1]}x{size[0]} px, targets {loaded.targets}")
    say(f"cameras: {args.cameras}; {how}")
    return loaded.images, cams, loaded.targets, loaded.views


def _region(args, images, cams, say):
    """The sphere the object lies in: `--region X,Y,Z,R`, none, or (auto) the camera file's (IDR/NeuS
    `scale_mat`) when every silhouette's rays meet it (one process; joined ones let `reconstruct` judge)."""
    import jax

    import jaxgenus as jg

    if args.region == "none" or not args.cameras:
        return None
    if args.region != "auto":
        try:
            x, y, z, r = (float(v) for v in args.region.split(","))
        except ValueError:
            raise _InputError(f"--region: expected auto, none or X,Y,Z,R, got {args.region!r}") from None
        return np.array([x, y, z]), r
    region, a = jg.load_region(args.cameras), np.asarray(images)
    if region is None or jax.process_count() > 1:
        return region
    misses = jg.capture.region_misses(a[..., -1] if a.ndim == 4 else a, cams, region)
    if misses.max() > 0.01:
        say(f"region: the sphere of {args.cameras} (scale_mat) misses {misses.max():.0%} of the silhouette of view "
            f"{int(misses.argmax())}: not used")
        return None
    return region


def _plan_line(opts, targets) -> str:
    """Cycles, steps and the face budget (with the rise photos may get, `detail_faces`)."""
    from jaxgenus.pipeline import TEXTURE_SETTINGS

    more = targets == "photo" and opts.remesh and opts.detail_faces > opts.face_budget
    cycles = f"{opts.n_cycles} cycles"
    five = TEXTURE_SETTINGS["n_cycles"]
    if targets == "photo" and opts.fine_texture and "n_cycles" not in opts.held and opts.n_cycles < five:
        cycles += f" ({five} for photos of a fine texture that resolve under 4x the faces)"
    return (f"{cycles} x {opts.steps_per_cycle} steps, up to {opts.face_budget} faces"
            + (f" (photos that resolve more: up to {opts.detail_faces})" if more else ""))


def _check_writable(out: Path, *, folder_wanted: bool = False) -> None:
    """Refuse, before any work, an --out that cannot be written: a mesh path that is a folder (or an
    output folder that is a file), under a file, or in a folder without write permission."""
    folder = out if folder_wanted else out.parent
    while not folder.exists():
        folder = folder.parent
    why = ("is a folder; give the mesh's file name" if out.is_dir() and not folder_wanted
           else "is a file, not a folder" if folder_wanted and out.is_file()
           else f"{folder} is a file, not a folder" if not folder.is_dir()
           else f"the folder {folder} is not writable" if not os.access(folder, os.W_OK) else "")
    if why:
        raise _UsageError(f"--out {out}: cannot be written: {why}")


def _check_outputs(args):
    """Refuse, before any work, an --out that cannot be written or whose mesh or JSON history would
    overwrite an input file, and a --downsample under 1."""
    out = Path(args.out)
    _check_writable(out)
    if getattr(args, "downsample", None) is not None and args.downsample < 1:
        raise _UsageError(f"--downsample: expected an integer >= 1 (1: the images as they are), got {args.downsample}")
    inputs = [Path(p) for p in (args.mesh, args.images, _mask_source(args.masks)[0], args.cameras) if p]
    for target in (out, out.with_suffix(".json")):
        for src in inputs:
            if src.exists() and target.exists() and target.resolve() == src.resolve():
                raise _InputError(f"--out {args.out}: writing {target} would overwrite the input {src}")


def _join(args) -> None:
    """`jax.distributed.initialize` from `--coordinator/--num-processes/--process-id`, or from the
    environment (`JAX_COORDINATOR_ADDRESS`, SLURM, ...) when `--coordinator` is `env`; CPU devices
    talk over gloo. Nothing when no flag asks for it."""
    if not args.coordinator:
        return
    import jax

    if args.coordinator != "env" and (args.num_processes is None or args.process_id is None):
        raise _InputError("--coordinator HOST:PORT needs --num-processes N and --process-id I")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    if args.coordinator == "env":
        jax.distributed.initialize()
    else:
        jax.distributed.initialize(coordinator_address=args.coordinator, num_processes=args.num_processes,
                                   process_id=args.process_id)


def _reconstruct(args) -> int:
    import jax

    import jaxgenus as jg

    if "list" in (args.option or []):
        given = argparse.Namespace(**{**vars(args), "option": [o for o in args.option if o != "list"]})
        print(_settings_list(_options(given)))
        return EXIT_OK
    _join(args)
    _check_outputs(args)
    say = _clock(time.perf_counter())
    opts = _options(args)
    gt, targets, views, region = None, args.targets, None, None
    if args.mesh:
        gt = jg.load_mesh(args.mesh)
        v, f = gt.to_numpy()
        v = v - 0.5 * (v.min(0) + v.max(0))
        gt = jg.Mesh.from_numpy(v / np.linalg.norm(v, axis=1).max(), f)
        cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
        images = jg.render_targets(gt, cams)
        say(f"targets: {args.views} normal maps of {args.mesh} at {args.res}px (synthetic)")
    elif args.images and args.cameras:
        images, cams, targets, views = _captured(args, say, opts.devices)
        region = _region(args, images, cams, say)
    else:
        raise _InputError("give --mesh GT.obj (synthetic targets) or --images PATH --cameras FILE")
    genus = None if args.genus == "auto" else int(args.genus)
    say(f"genus: {'estimated from the images' if genus is None else genus}; {_plan_line(opts, targets)}")
    rec = jg.reconstruct(images, cams, genus, targets=targets, options=opts, callback=_progress(say), log=say,
                         views=views, region=region, key=jax.random.key(args.seed))
    _report(rec, gt)
    if jax.process_index() == 0:  # one mesh: the first process writes it
        _write(rec, args.out)
    return _exit_code(rec)


def _picture(images, rec, cams, path: Path, columns: int = 4) -> None:
    """A PNG of `columns` of the views: the targets (normals as colours over grey) above the result
    rendered the same way from the same cameras."""
    import jaxgenus as jg
    from PIL import Image

    views = np.linspace(0, len(cams) - 1, min(columns, len(cams))).round().astype(int)
    rows = []
    for rgba in (np.asarray(images)[views], np.asarray(jg.render_targets(rec.mesh, cams[views]))):
        over_grey = rgba[..., :3] * rgba[..., 3:] + 0.35 * (1 - rgba[..., 3:])
        rows.append(np.concatenate(list(over_grey), axis=1))
    picture = np.uint8(np.clip(np.concatenate(rows, axis=0), 0, 1) * 255)
    scale = max(1, 256 // int(cams.height))  # small views drawn larger, pixel for pixel
    Image.fromarray(picture).resize((picture.shape[1] * scale, picture.shape[0] * scale), Image.NEAREST).save(path)
    print(f"wrote {path} (top: {len(views)} of the target views; bottom: the result in the same views)")


def _demo(args) -> int:
    import jaxgenus as jg

    _check_writable(Path(args.out), folder_wanted=True)
    gt = jg.builtin_scene(args.scene)
    g = jg.SCENES[args.scene]
    cams = jg.sphere_cameras(args.views, radius=3.0, fov_deg=40.0, resolution=args.res)
    t0 = time.perf_counter()
    images = jg.render_targets(gt, cams)
    print(f"scene {args.scene!r} (genus {g}, {int(gt.n_faces)} faces): {args.views} target views at {args.res}px "
          f"rendered in {time.perf_counter() - t0:.1f}s")
    opts = jg.ReconstructOptions(n_cycles=args.cycles, steps_per_cycle=args.steps, one_jit=args.one_jit)
    say = _clock(time.perf_counter())
    rec = jg.reconstruct(images, cams, g, options=opts, callback=_progress(say), log=say)
    _report(rec, gt)
    _write(rec, Path(args.out) / f"{args.scene}.obj")
    _picture(images, rec, cams, Path(args.out) / f"{args.scene}.png")
    return _exit_code(rec)


def main(argv=None) -> int:
    parser = build_parser(__doc__, {"primitives": _primitives, "reconstruct": _reconstruct, "demo": _demo}, main)
    args, rest = parser.parse_known_args(argv)
    if rest and args.command != "batch":
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    args.rest = rest
    if args.command == "reconstruct" and args.genus != "auto" and not str(args.genus).isdigit():
        parser.error(f"--genus must be an int >= 0 or 'auto', got {args.genus!r}")
    try:
        return args.run(args)
    except (_InputError, ValueError, FileNotFoundError) as err:
        msg = " ".join(str(err).split())
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_USAGE if isinstance(err, _UsageError) else EXIT_INPUT


if __name__ == "__main__":
    sys.exit(main())
