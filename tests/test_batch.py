"""`jaxgenus batch`: a good capture and a broken one; the good one's mesh is written, the broken one
is reported, the summary lists both, and a rerun skips the finished one."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

import jaxgenus as jg
from jaxgenus.__main__ import main


def _capture(folder, broken: bool):
    cams = jg.sphere_cameras(8, radius=3.0, resolution=48)
    alpha = np.asarray(jg.render_targets(jg.builtin_scene("torus"), cams))[..., 3]
    (folder / "images").mkdir(parents=True)
    for i, a in enumerate(alpha):
        Image.fromarray((a * 255).round().astype(np.uint8)).save(folder / "images" / f"view_{i}.png")
    R, t = np.asarray(cams.rotation, float), np.asarray(cams.translation, float)
    f, c = np.asarray(cams.focal, float), np.asarray(cams.principal_point, float)
    views = [{"name": f"view_{i}.png", "K": [[f[i, 0], 0, c[i, 0]], [0, f[i, 1], c[i, 1]], [0, 0, 1]],
              "R": R[i].tolist(), "t": t[i].tolist()} for i in range(len(cams) - (2 if broken else 0))]
    (folder / "cameras.json").write_text(json.dumps({"height": 48, "width": 48, "cameras": views}))


def test_batch_writes_the_good_capture_and_reports_the_broken_one(tmp_path, capsys):
    root, out = tmp_path / "captures", tmp_path / "out"
    _capture(root / "good", broken=False)
    _capture(root / "broken", broken=True)  # 8 images, 6 cameras
    code = main(["batch", str(root), "--out", str(out), "--genus", "1", "--option", "n_cycles=2", "steps_per_cycle=30"])
    printed = capsys.readouterr().out
    assert code == 4, printed  # one capture failed
    assert (out / "good" / "mesh.obj").exists() and not (out / "broken" / "mesh.obj").exists()
    rows = {r["capture"]: r for r in json.loads((out / "summary.json").read_text())}
    assert rows["good"]["exit"] == 0 and rows["good"]["genus"] == 1 and rows["good"]["ok"]
    assert rows["broken"]["exit"] == 1 and "camera" in rows["broken"]["reason"], rows["broken"]
    assert "| broken | 1 |" in (out / "summary.md").read_text()
    assert jg.genus(jg.load_mesh(out / "good" / "mesh.obj")) == 1
    again = main(["batch", str(root), "--out", str(out), "--genus", "1", "--option", "n_cycles=2", "steps_per_cycle=30"])
    printed = capsys.readouterr().out
    assert "good: finished before, skipped" in printed and again == 4  # the broken one is tried again


def test_batch_refuses_a_folder_without_captures(tmp_path, capsys):
    assert main(["batch", str(tmp_path), "--out", str(tmp_path / "out")]) == 1
    assert "no capture subfolders" in capsys.readouterr().err


def test_batch_jobs_run_captures_side_by_side(tmp_path, capsys):
    """`--jobs 2`: two worker processes take a capture each; the parent writes one summary of both."""
    root, out = tmp_path / "captures", tmp_path / "out"
    _capture(root / "good", broken=False)
    _capture(root / "broken", broken=True)
    code = main(["batch", str(root), "--out", str(out), "--jobs", "2", "--genus", "1", "--option", "n_cycles=2",
                 "steps_per_cycle=30"])
    printed = capsys.readouterr().out
    assert code == 4, printed
    rows = {r["capture"]: r for r in json.loads((out / "summary.json").read_text())}
    assert rows["good"]["exit"] == 0 and rows["good"]["genus"] == 1 and rows["broken"]["exit"] == 1, rows
    assert "summary: 1 of 2 captures fitted" in printed


def test_device_groups_split_the_visible_gpus(monkeypatch):
    import pytest

    from jaxgenus._batch import device_groups

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1,2,3")
    assert device_groups(2) == ["0,1", "2,3"] and device_groups(3) == ["0", "1,2", "3"]
    with pytest.raises(ValueError, match="--jobs 5: more jobs than the 4 GPUs"):
        device_groups(5)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    assert device_groups(2) == [None, None]  # no GPU: the workers share the host
