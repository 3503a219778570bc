import gc
import os
from pathlib import Path

import jax
import pytest


def _mapped_regions() -> int | None:
    """How many memory mappings this process holds (Linux), None where that cannot be read."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return None


def _mapping_limit() -> int:
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read())
    except (OSError, ValueError):
        return 65530


@pytest.fixture(autouse=True, scope="module")
def _fresh_executables_when_mappings_run_low():
    """Drop jax's compiled executables after a test module once the process holds many mappings.

    XLA CPU keeps every executable it compiles, each with its own JIT-code memory mappings; one
    process running the whole suite (hundreds of shapes, plans and buckets) otherwise runs out
    of them and crashes inside the compiler (`LLVM ERROR: Unable to allocate section memory`,
    docs/results.md). Until then the executables stay, so modules that fit the same small scenes
    share their programs. Where the count cannot be read, every module starts fresh. Tests
    count compilations only within a test.
    """
    yield
    held = _mapped_regions()
    if held is None or held > _mapping_limit() // 3:
        jax.clear_caches()
        gc.collect()


def shared_meshes_dir() -> Path | None:
    """`../shared/meshes` beside the repo (or $JAXGENUS_SHARED_MESHES); None when absent."""
    env = os.environ.get("JAXGENUS_SHARED_MESHES")
    path = Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
    return path if (path / "MANIFEST.md").is_file() else None


def shared_mesh_table() -> list[tuple[str, int]]:
    """(file name, genus) rows of MANIFEST.md; empty when the folder is absent."""
    root = shared_meshes_dir()
    if root is None:
        return []
    rows = []
    for line in (root / "MANIFEST.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > 3 and cells[1].endswith(".obj") and cells[2].isdigit():
            rows.append((cells[1], int(cells[2])))
    return rows


@pytest.fixture
def shared_meshes():
    root = shared_meshes_dir()
    if root is None:
        pytest.skip("../shared/meshes is absent")
    return root


@pytest.fixture
def cpu_device():
    """Runs a test on the CPU device. The native kernels are registered for the CPU platform;
    tests that call them directly (the library reaches them from other platforms through
    `host_ffi_call`) use this so that they also pass where the default backend is a GPU."""
    with jax.default_device(jax.devices("cpu")[0]):
        yield
