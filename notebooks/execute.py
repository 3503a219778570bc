"""Run a notebook's code cells in order and save what they print and draw into it.

    python notebooks/execute.py notebooks/01_quickstart.ipynb [more.ipynb ...]

A stand-in for `jupyter nbconvert --execute --inplace` that needs no kernel: each code cell runs
in one namespace, from a temporary folder (what a notebook writes, meshes and all, stays out of
the repository), and its outputs are stored as a notebook would store them: printed text as a stream, each matplotlib figure it leaves open as a PNG. The
environment is passed on (`JAXGENUS_DATA`, `JAXGENUS_DTU`, `JAXGENUS_NOTEBOOK_QUICK`).
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def _figures(dpi: int) -> list[dict]:
    out = []
    for number in plt.get_fignums():
        buffer = io.BytesIO()
        plt.figure(number).savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
        out.append({"output_type": "display_data", "metadata": {},
                    "data": {"image/png": base64.b64encode(buffer.getvalue()).decode("ascii"),
                             "text/plain": [f"<Figure {number}>"]}})
    plt.close("all")
    return out


def execute(path: Path, dpi: int = 72) -> None:
    notebook = json.loads(path.read_text())
    namespace = {"__name__": "__main__"}
    count = 0
    path = path.resolve()
    here = os.getcwd()
    scratch = tempfile.TemporaryDirectory(prefix="jaxgenus-notebook-")
    os.chdir(scratch.name)
    try:
        for cell in notebook["cells"]:
            if cell["cell_type"] != "code":
                continue
            count += 1
            printed = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(printed):
                exec(compile("".join(cell["source"]), f"{path.name} cell {count}", "exec"), namespace)
            outputs = []
            if printed.getvalue():
                outputs.append({"output_type": "stream", "name": "stdout",
                                "text": printed.getvalue().splitlines(keepends=True)})
            outputs += _figures(dpi)
            cell["outputs"], cell["execution_count"] = outputs, count
            print(f"{path.name}: cell {count} in {time.perf_counter() - t0:.0f} s, {len(outputs)} outputs", file=sys.stderr)
    finally:
        os.chdir(here)
        scratch.cleanup()
    path.write_text(json.dumps(notebook, indent=1, ensure_ascii=False) + "\n")
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB", file=sys.stderr)


if __name__ == "__main__":
    for name in sys.argv[1:]:
        execute(Path(name))
