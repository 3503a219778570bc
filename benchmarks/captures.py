"""A published capture at its own size and downsampled: time, memory, ETA and held-out quality.

    python benchmarks/captures.py --capture DIR --genus 0 --downsample 4 1 [--cli-args "--targets silhouette"]
    python benchmarks/captures.py --report-only --out OUT

DIR is a capture in the NeuS/IDR layout as published (`image/000000.png` or `images/000000.png`,
`mask/000.png`, `cameras_sphere.npz`), e.g. DTU scan65 from a public copy (github.com/jingz666/NeuF,
`data/DTU/dtu_scan65`), DTU scan24 and scan37 from another (github.com/wqrray/nerf_baseline,
`data/dtu_scan24`, `data/dtu_scan37`); the data stays outside this repository. `--holdout K` views
(every N/K-th) are held out: the rest are linked into OUT/train (renumbered, a camera file
with their cameras) and fitted by the CLI, `jaxgenus reconstruct --images train/image --masks
train/mask --cameras train/cameras_sphere.npz --genus G --downsample N`, in a fresh process
per run (`--masks-only`: `--images train/mask`, silhouettes alone). Per run: wall seconds (the process, loading included), the process's peak resident
memory, the first ETA the progress line printed against the time that really remained after
it, the result's faces and exit code, and the held-out re-projection PSNR
(`jaxgenus.metrics.reprojection_psnr`: the training photos at full size predicted onto the
held-out views through the mesh, object pixels, evaluated at 1/`--eval-downsample` (default 1: the
photos' own size; before 2026-11-30 the default was 1/2, about 0.5 dB higher on DTU scan24); "inside":
over the pixels both the held-out mask and the mesh cover, the surface without its outline).
Writes OUT/captures.{json,md,png} (time against pixels, log-log, with the 2x-per-4x line).
`--processes P`: P processes joined by `jax.distributed` on this host (one CPU device each, each
reading only its views); the peak memory is the largest process's.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

# The fits run in child processes; this one only evaluates. On a GPU it must not take 75 % of the
# device's memory as its pool first (the child's fit then ran out of memory loading a kernel).
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import numpy as np
from _report import publish, pyplot

import jaxgenus as jg
from jaxgenus.metrics import reprojection_psnr

_RSS = ("import resource, subprocess, sys; rc = subprocess.run(sys.argv[1:]).returncode; "
        "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, flush=True); sys.exit(rc)")


def _photos(capture: Path) -> list[Path]:
    """The capture's photos, sorted (`image/` or `images/`)."""
    folder = capture / "image" if (capture / "image").is_dir() else capture / "images"
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg"))


def split(capture: Path, out: Path, holdout: int) -> tuple[list[int], list[int]]:
    """Link the training views of a NeuS-layout capture into out/train, renumbered 0..; returns
    (train, held) view indices."""
    cams = np.load(capture / "cameras_sphere.npz")
    n = len([k for k in cams.files if k.startswith("world_mat_") and not k.startswith("world_mat_inv")])
    held = sorted({int(round(i * n / holdout)) for i in range(holdout)})
    train = [i for i in range(n) if i not in held]
    images = _photos(capture)
    masks = sorted(p for p in (capture / "mask").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    if len(images) != n or len(masks) != n:
        raise SystemExit(f"{capture}: {len(images)} images and {len(masks)} masks for {n} cameras")
    for sub in ("image", "mask"):
        (out / "train" / sub).mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, i in enumerate(train):
        for src, sub, width in ((images[i], "image", 6), (masks[i], "mask", 3)):
            link = out / "train" / sub / f"{k:0{width}d}{src.suffix}"
            if not link.exists():
                link.symlink_to(src.resolve())
        for key in ("world_mat", "scale_mat", "camera_mat"):
            if f"{key}_{i}" in cams.files:
                arrays[f"{key}_{k}"] = cams[f"{key}_{i}"]
    np.savez(out / "train" / "cameras_sphere.npz", **arrays)
    return train, held


def first_eta(log: str, wall: float) -> tuple[float | None, float | None]:
    """The first ETA the progress printed and the seconds that really remained after that line."""
    for line in log.splitlines():
        m = re.match(r"\[\s*([\d.]+)s\].*ETA (\d+)s", line)
        if m:
            return float(m.group(2)), wall - float(m.group(1))
    return None, None


def held_out(capture: Path, held: list[int]):
    """Held-out photos (float RGB), masks and cameras at full size."""
    files = _photos(capture)
    masks = sorted(p for p in (capture / "mask").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    loaded = jg.load_images([str(files[i]) for i in held], masks=[str(masks[i]) for i in held])
    h, w = loaded.images.shape[1:3]
    cams, _ = jg.load_cameras(capture / "cameras_sphere.npz", image_size=(h, w))
    return loaded.images[..., :3], loaded.images[..., 3], cams[np.array(held)]


def training_photos(out: Path):
    loaded = jg.load_images(str(out / "train" / "image"), masks=str(out / "train" / "mask"))
    h, w = loaded.images.shape[1:3]
    cams, _ = jg.load_cameras(out / "train" / "cameras_sphere.npz", image_size=(h, w))
    return loaded.images[..., :3], cams


def run_one(out: Path, genus: str, downsample: int, cli_args: list[str], tag: str, masks_only: bool,
            processes: int = 1) -> dict:
    """One CLI run (`processes` > 1: that many processes joined on this host, one CPU device each,
    each reading its own views; the peak RSS is the largest process's)."""
    mesh = out / f"{tag}.obj"
    images = ["--images", str(out / "train" / "mask")] if masks_only else [
        "--images", str(out / "train" / "image"), "--masks", str(out / "train" / "mask")]
    cmd = [sys.executable, "-c", _RSS, sys.executable, "-m", "jaxgenus", "reconstruct", *images,
           "--cameras", str(out / "train" / "cameras_sphere.npz"), "--genus", genus,
           "--downsample", str(downsample), "--out", str(mesh), *cli_args]
    env = None
    if processes > 1:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        cmds = [cmd + ["--coordinator", f"127.0.0.1:{port}", "--num-processes", str(processes), "--process-id",
                       str(i)] for i in range(processes)]
        env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1", JAX_PLATFORMS="cpu")
    else:
        cmds = [cmd]
    t0 = time.perf_counter()
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) for c in cmds]
    logs = [p.communicate()[0] for p in procs]
    wall = time.perf_counter() - t0
    (out / f"{tag}.log").write_text("\n".join(logs))
    rss = [int(m.group(1)) for log in logs for m in [re.search(r"PEAK_RSS_KB (\d+)", log)] if m]
    eta, remaining = first_eta(logs[0], wall)
    return dict(tag=tag, downsample=downsample, args=cli_args, exit=max(p.returncode for p in procs), seconds=wall,
                peak_rss_gb=max(rss) / 2**20 if rss else None, first_eta=eta, remaining=remaining,
                mesh=str(mesh) if mesh.exists() else None, processes=processes)


def write_report(rows: list[dict], out: Path) -> None:
    head = ("| run | downsample | fitted size | exit | seconds | time / full-size | peak RSS GB | first ETA s | "
            "remaining s | ETA / remaining | held-out PSNR dB | inside dB | coverage | evaluated at |\n|" + "---|" * 14 + "\n")
    full = {r["args_key"]: r["seconds"] for r in rows if r["downsample"] == 1}
    lines = []
    for r in rows:
        ratio = r["seconds"] / full[r["args_key"]] if r["args_key"] in full else float("nan")
        eta = (f"{r['first_eta']:.0f} | {r['remaining']:.0f} | {r['first_eta'] / r['remaining']:.2f}"
               if r["first_eta"] is not None else "- | - | -")
        inside = f"{r['psnr_inside']:.2f}" if r.get("psnr_inside") is not None else "-"
        psnr = f"{r['psnr']:.2f} | {inside} | {r['coverage']:.3f}" if r.get("psnr") is not None else "- | - | -"
        lines.append(f"| {r['tag']} | {r['downsample']} | {r['size']} | {r['exit']} | {r['seconds']:.0f} | "
                     f"{ratio:.2f} | {r['peak_rss_gb']:.2f} | {eta} | {psnr} | 1/{r.get('eval_downsample', 2)} |")
    publish(out / "captures.md", head + "\n".join(lines) + "\n")
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for key in sorted({r["args_key"] for r in rows}):
        rs = sorted((r for r in rows if r["args_key"] == key), key=lambda r: r["pixels"])
        px, t = np.array([r["pixels"] for r in rs]), np.array([r["seconds"] for r in rs])
        ax.loglog(px / 1e6, t, "o-", label=key or "defaults")
    if rows:
        r0 = min(rows, key=lambda r: r["pixels"])
        px = np.geomspace(r0["pixels"], max(r["pixels"] for r in rows), 8)
        ax.loglog(px / 1e6, r0["seconds"] * np.sqrt(px / r0["pixels"]), "k:", label="2x time per 4x pixels")
    ax.set_xlabel("pixels per view fitted (millions)")
    ax.set_ylabel("wall seconds (whole run)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "captures.png", dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", type=Path)
    ap.add_argument("--genus", default="0")
    ap.add_argument("--holdout", type=int, default=8)
    ap.add_argument("--downsample", type=int, nargs="+", default=[4, 1])
    ap.add_argument("--cli-args", default="", help="more CLI arguments for every run (quoted)")
    ap.add_argument("--eval-downsample", type=int, default=1,
                    help="evaluate the held-out views at 1/N size (1: the photos' own size)")
    ap.add_argument("--masks-only", action="store_true", help="fit the masks alone (silhouettes), not the photos")
    ap.add_argument("--processes", type=int, default=1,
                    help="processes joined by jax.distributed on this host, one CPU device each")
    ap.add_argument("--out", type=Path, default=Path("captures_out"))
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    saved = args.out / "captures.json"
    rows = json.loads(saved.read_text()) if saved.exists() else []
    if not args.report_only:
        if args.capture is None:
            raise SystemExit("--capture is needed (or --report-only)")
        train, held = split(args.capture, args.out, args.holdout)
        photos, cams = training_photos(args.out)
        hp, hm, hc = held_out(args.capture, held)
        extra = shlex.split(args.cli_args)
        for ds in args.downsample:
            tag = ("masks-" if args.masks_only else "") + f"ds{ds}" + (
                "-" + "-".join(a.strip("-") for a in extra) if extra else "") + (
                f"-p{args.processes}" if args.processes > 1 else "")
            row = run_one(args.out, args.genus, ds, extra, tag, args.masks_only, args.processes)
            row.update(args_key=("masks only " if args.masks_only else "") + " ".join(extra)
                       + (f" {args.processes} processes" if args.processes > 1 else ""), size=f"{-(-cams.width // ds)}x{-(-cams.height // ds)}",
                       pixels=-(-cams.width // ds) * -(-cams.height // ds), views=len(train), held=held)
            if row["mesh"]:
                v, f = jg.load_mesh(row["mesh"]).to_numpy()
                r = reprojection_psnr((v, f), photos, cams, hp, hc, hm, downsample=args.eval_downsample)
                row.update(psnr=r.mean, psnr_inside=float(np.mean(r.psnr_inside)), coverage=float(np.mean(r.coverage)),
                           psnr_views=r.psnr.tolist(), eval_downsample=args.eval_downsample)
            print(json.dumps({k: row[k] for k in ("tag", "exit", "seconds", "peak_rss_gb", "first_eta",
                                                    "remaining") if k in row} | {"psnr": row.get("psnr"), "psnr_inside": row.get("psnr_inside")}),
                  flush=True)
            rows = [r for r in rows if r["tag"] != tag] + [row]
            saved.write_text(json.dumps(rows, indent=1))
    write_report(rows, args.out)


if __name__ == "__main__":
    main()
