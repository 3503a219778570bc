"""`jaxgenus batch CAPTURES --out OUT`: every capture of a folder reconstructed, one by one.

A capture is a subfolder of CAPTURES holding its images (`images/`, `image/` or `rgb/`), optionally
its masks (`masks/` or `mask/`), and one camera file (`.json`, `.npz`, `*_par.txt`, or a COLMAP
model that `load_cameras` finds in the subfolder).
Each is run as `jaxgenus reconstruct` with the options given after the folder, writing
`OUT/NAME/mesh.obj`, its history `OUT/NAME/mesh.json`, the run's output `OUT/NAME/log.txt` and
`OUT/NAME/status.json` (exit code, genus, verdict, seconds, and the reason when it failed). A
broken capture is reported and the others go on; a rerun skips the captures that finished (a
status with a mesh). With `--num-processes N --process-id I` (no coordinator needed), process I
takes every N-th capture; within a process the views of a capture are split over its devices.
With `--jobs K` a process runs K captures side by side instead, each in a worker process of its
own with its own share of the GPUs (`CUDA_VISIBLE_DEVICES`: the GPUs split into K groups; on a
CPU host the workers share the cores).
`OUT/summary.md` and `OUT/summary.json` list every capture that has a status.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

__all__ = ["add_batch_command", "capture_folders", "run_batch"]

_IMAGES = ("images", "image", "rgb")
_MASKS = ("masks", "mask")


def capture_folders(root: Path) -> list[Path]:
    """The subfolders of `root` (sorted by name; hidden ones skipped)."""
    if not root.is_dir():
        raise ValueError(f"CAPTURES: {root} is not a folder")
    found = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not found:
        raise ValueError(f"CAPTURES: {root} has no capture subfolders")
    return found


def _inputs(folder: Path) -> list[str]:
    images = next((folder / n for n in _IMAGES if (folder / n).is_dir()), None)
    if images is None:
        raise ValueError(f"{folder}: no images folder ({', '.join(_IMAGES)})")
    masks = next((folder / n for n in _MASKS if (folder / n).is_dir()), None)
    return ["--images", str(images), "--cameras", str(_camera_file(folder))] + (["--masks", str(masks)] if masks else [])


def _camera_file(folder: Path) -> Path:
    """The capture's one camera file (`.json`, `.npz`, `*_par.txt`), else the folder itself (a COLMAP
    model in it, which `load_cameras` finds)."""
    files = sorted(p for p in folder.iterdir() if p.is_file() and (p.suffix in (".json", ".npz")
                                                                   or p.name.endswith("_par.txt")))
    if len(files) > 1:
        raise ValueError(f"{folder}: several camera files ({', '.join(p.name for p in files)}); keep one")
    return files[0] if files else folder


def _status(code: int, out: Path, log: str, seconds: float) -> dict:
    status = {"exit": code, "seconds": round(seconds, 1), "genus": None, "ok": False, "reason": None}
    history = out / "mesh.json"
    if history.exists() and code != 1:
        h = json.loads(history.read_text())
        found = re.search(r"^genus (-?\d+) \(", log, re.MULTILINE)  # the result's genus, as the run printed it
        status.update(ok=bool(h.get("ok")), seconds=round(float(h.get("seconds", seconds)), 1),
                      genus=int(found.group(1)) if found else None)
        if not status["ok"]:
            status["reason"] = "; ".join(h.get("warnings", [])[:2]) or "the verdict failed"
    errors = [line for line in log.splitlines() if line.startswith("error:")]
    if code not in (0, 3, 4) or errors:
        status["reason"] = errors[-1][len("error: "):] if errors else f"exit {code}"
    return status


def _one(folder: Path, out: Path, options: list[str], reconstruct: Callable[[list[str]], int]) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    buffer, t0 = io.StringIO(), time.perf_counter()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        try:
            code = reconstruct(["reconstruct", *_inputs(folder), "--out", str(out / "mesh.obj"), *options])
        except ValueError as err:
            print(f"error: {' '.join(str(err).split())}")
            code = 1
        except Exception as err:  # a broken capture must not stop the batch
            print(f"error: {type(err).__name__}: {' '.join(str(err).split())[:300]}")
            code = 1
    (out / "log.txt").write_text(buffer.getvalue())
    status = _status(code, out, buffer.getvalue(), time.perf_counter() - t0)
    (out / "status.json").write_text(json.dumps(status))
    return status


def _summary(out: Path, names: list[str]) -> list[dict]:
    rows = []
    for name in names:
        path = out / name / "status.json"
        if path.exists():
            rows.append({"capture": name, **json.loads(path.read_text())})
    (out / "summary.json").write_text(json.dumps(rows, indent=1))
    lines = ["| capture | exit | genus | verdict | seconds | reason |", "|---|---|---|---|---|---|"]
    for r in rows:
        verdict = "ok" if r["ok"] else "NOT OK"
        lines.append(f"| {r['capture']} | {r['exit']} | {r['genus']} | {verdict} | {r['seconds']} | "
                     f"{r['reason'] or ''} |")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    return rows


def device_groups(jobs: int) -> list[str | None]:
    """Per job, the GPUs it sees (a `CUDA_VISIBLE_DEVICES` value): the visible GPUs
    (`CUDA_VISIBLE_DEVICES`, else those `nvidia-smi -L` lists) in `jobs` contiguous groups;
    None for each job on a host without GPUs."""
    listed = os.environ.get("CUDA_VISIBLE_DEVICES")
    if listed is not None:
        ids = [x.strip() for x in listed.split(",") if x.strip()]
    else:
        try:
            found = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=60).stdout
        except (OSError, subprocess.SubprocessError):
            found = ""
        ids = [str(i) for i, line in enumerate(ln for ln in found.splitlines() if ln.startswith("GPU "))]
    if not ids:
        return [None] * jobs
    if jobs > len(ids):
        raise ValueError(f"--jobs {jobs}: more jobs than the {len(ids)} GPUs; use at most one job per GPU")
    cut = [round(j * len(ids) / jobs) for j in range(jobs + 1)]
    return [",".join(ids[cut[j]:cut[j + 1]]) for j in range(jobs)]


def _side_by_side(root: Path, out: Path, options: list[str], jobs: int, num_processes: int, process_id: int) -> int:
    """`jobs` worker processes (`python -m jaxgenus batch --worker`), worker j taking every
    (N * jobs)-th capture from I * jobs + j, each with its group of GPUs; 0 when all fitted."""
    groups = device_groups(jobs)
    workers = []
    for j, group in enumerate(groups):
        env = dict(os.environ) if group is None else dict(os.environ, CUDA_VISIBLE_DEVICES=group)
        argv = [sys.executable, "-m", "jaxgenus", "batch", str(root), "--out", str(out), "--worker",
                "--num-processes", str(num_processes * jobs), "--process-id", str(process_id * jobs + j), *options]
        workers.append(subprocess.Popen(argv, env=env))
    codes = [w.wait() for w in workers]
    return 0 if all(c == 0 for c in codes) else 4 if all(c in (0, 4) for c in codes) else 1


def run_batch(root: Path, out: Path, options: list[str], reconstruct: Callable[[list[str]], int], *,
              num_processes: int = 1, process_id: int = 0, jobs: int = 1, summary: bool = True) -> int:
    """Reconstruct every capture of `root` into `out` (module doc); `reconstruct(argv)` runs one
    `jaxgenus reconstruct`; `jobs` captures at a time in worker processes (`summary`: False in a
    worker, whose parent writes it). Returns 0 when every capture of this process fitted, else 4
    (1 when a worker itself failed)."""
    if not (num_processes >= 1 and 0 <= process_id < num_processes):
        raise ValueError(f"--process-id must be in [0, {num_processes}), got {process_id}")
    if not (isinstance(jobs, int) and jobs >= 1):
        raise ValueError(f"--jobs must be an int >= 1, got {jobs!r}")
    folders = capture_folders(root)
    if jobs > 1:
        out.mkdir(parents=True, exist_ok=True)
        code = _side_by_side(root, out, options, jobs, num_processes, process_id)
        rows = _summary(out, [f.name for f in folders])
        print(f"summary: {sum(r['exit'] == 0 for r in rows)} of {len(folders)} captures fitted; {out / 'summary.md'}")
        return code
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for folder in folders[process_id::num_processes]:
        target = out / folder.name
        done = target / "status.json"
        if done.exists() and (target / "mesh.obj").exists():
            print(f"{folder.name}: finished before, skipped")
            continue
        status = _one(folder, target, options, reconstruct)
        failed += status["exit"] != 0
        print(f"{folder.name}: exit {status['exit']}, genus {status['genus']}, "
              f"{'ok' if status['ok'] else 'NOT OK'}, {status['seconds']} s"
              + (f" ({status['reason']})" if status["reason"] else ""), flush=True)
    if summary:
        rows = _summary(out, [f.name for f in folders])
        print(f"summary: {sum(r['exit'] == 0 for r in rows)} of {len(folders)} captures fitted; {out / 'summary.md'}")
    return 0 if failed == 0 else 4


def add_batch_command(sub, main: Callable[[list[str]], int]) -> None:
    """The `batch` subcommand on an argparse subparsers object; `main(argv)` runs one reconstruction."""
    import argparse

    b = sub.add_parser("batch", help="reconstruct every capture of a folder (images/, masks/, a camera file each)",
                       epilog="options after CAPTURES are those of `jaxgenus reconstruct` (--genus, --option, ...)")
    b.add_argument("captures", help="a folder of capture subfolders (required)")
    b.add_argument("--out", required=True, help="output folder: OUT/NAME/mesh.obj, OUT/summary.md (required)")
    b.add_argument("--num-processes", type=int, default=1, metavar="N", help="N processes share the captures (default 1)")
    b.add_argument("--process-id", type=int, default=0, metavar="I", help="this process takes every N-th from I (default 0)")
    b.add_argument("--jobs", type=int, default=1, metavar="K",
                   help="K captures side by side, each in a worker process with its share of the GPUs (default 1)")
    b.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)  # a --jobs worker: no summary
    b.set_defaults(run=lambda args: run_batch(Path(args.captures), Path(args.out), list(args.rest), main,
                                              num_processes=args.num_processes, process_id=args.process_id,
                                              jobs=args.jobs, summary=not args.worker))
