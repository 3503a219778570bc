"""Execute the notebooks' code cells at small settings (JAXGENUS_NOTEBOOK_QUICK=1)."""

import json
import os
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    monkeypatch.setenv("JAXGENUS_NOTEBOOK_QUICK", "1")
    monkeypatch.chdir(tmp_path)
    cells = json.loads(path.read_text())["cells"]
    namespace = {"__name__": "__main__"}
    for cell in cells:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), f"{path.name}", "exec"), namespace)
    if path.name == "01_quickstart.ipynb":
        assert (tmp_path / "quickstart_result.obj").is_file()
        assert namespace["ours"].genus == namespace["genus"]
        assert namespace["base"].genus == 0
    if path.name == "03_photometric.ipynb":
        rec = namespace["photo"]
        assert rec.genus == namespace["genus"] and rec.albedo.shape == (len(rec.mesh.to_numpy()[0]), 3)
        assert (tmp_path / "photometric_result.ply").is_file()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_saved_with_its_outputs(path):
    """A reader sees what each notebook shows without running it: saved outputs, a picture among
    them, and a file small enough to open in a browser."""
    cells = json.loads(path.read_text())["cells"]
    outputs = [o for c in cells if c["cell_type"] == "code" for o in c.get("outputs", [])]
    assert any("image/png" in o.get("data", {}) for o in outputs), "no saved picture"
    assert path.stat().st_size < 2_000_000
