import gc
import os
import shutil
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


_CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
_CACHE_LIMIT = 2 << 30  # bytes: a larger cache folder is emptied at the start of a run


def _cache_folder(config) -> Path:
    """`$JAX_COMPILATION_CACHE_DIR`, else `.pytest_cache/jaxgenus-xla` in the repo (git ignores it)."""
    env = os.environ.get(_CACHE_ENV)
    return Path(env) if env else Path(config.rootpath) / ".pytest_cache" / "jaxgenus-xla"


#: XLA CPU compiles the suite's programs with its loop emitters instead of its fusion emitters: the
#: same programs, about a third less compile time on the compile-bound modules (docs/results.md,
#: 2026-12-07). Every test and subprocess of the suite runs them; XLA's defaults are what users run.
TEST_XLA_FLAGS = "--xla_cpu_use_fusion_emitters=false"


def _xla_accepts(flags: str) -> bool:
    """Whether this jaxlib starts with `flags` (XLA aborts the process on a flag it does not know)."""
    import subprocess
    import sys

    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    probe = "import jax; jax.numpy.zeros(1).block_until_ready()"
    return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, timeout=120).returncode == 0


def _with_test_flags():
    """`TEST_XLA_FLAGS` added to `$XLA_FLAGS` (read when the first backend starts, so before any test
    runs; the xdist workers and the subprocesses of tests inherit it) unless set there or refused."""
    flags = os.environ.get("XLA_FLAGS", "")
    name = TEST_XLA_FLAGS.split("=")[0]
    if name not in flags and _xla_accepts(f"{flags} {TEST_XLA_FLAGS}".strip()):
        os.environ["XLA_FLAGS"] = f"{flags} {TEST_XLA_FLAGS}".strip()


def _own_cores(workerinput: dict) -> None:
    """Keeps an xdist worker on its own share of the cores (worker i of n: every n-th core from the
    i-th), before its XLA client starts: XLA CPU sizes its thread pool by the cores a process may
    use, so each worker computes on its cores and none waits on threads the other worker's
    threads preempt (2 workers on 2 cores: about 5 % less time and CPU on the compile- and
    fit-bound modules, docs/results.md 2026-12-07). The tests' subprocesses inherit the share.
    Where the platform cannot pin, or there are fewer cores than workers, nothing changes."""
    if not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    n, worker = int(workerinput["workercount"]), str(workerinput["workerid"])
    if len(cores) >= n > 1 and worker.startswith("gw"):
        os.sched_setaffinity(0, cores[int(worker[2:]) :: n])


#: Modules whose tests are long end-to-end runs (a minute each, subprocesses of several processes
#: or devices): collected first, so the two workers' last tests are short ones. With `worksteal`
#: a worker that runs out takes tests from the end of the other's queue, but not the one it is
#: running: a minute-long test started last leaves the other worker idle that long.
FIRST_MODULES = ("test_sharded.py", "test_handles.py")


def pytest_collection_modifyitems(config, items):
    """The tests of `FIRST_MODULES` first (each module's tests together and in order), then the rest."""
    first = [i for i in items if i.path.name in FIRST_MODULES]
    items[:] = sorted(first, key=lambda i: FIRST_MODULES.index(i.path.name)) + [i for i in items if i not in first]


def pytest_configure(config):
    """XLA flags for the suite (`TEST_XLA_FLAGS`), and one on-disk compilation cache, shared by the xdist workers and the subprocesses that tests
    start (they inherit the environment): a program that two workers, two modules or a test and a
    subprocess compile is compiled once, and a second run of the suite reuses what the first
    compiled. Its key is the program, the jax version and the XLA flags, so a changed program is
    compiled anew; a cache hit still counts in `count_compilations` (the event wraps the lookup).
    A folder above 2 GiB is emptied when a run starts."""
    folder = _cache_folder(config)
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist)
        size = sum(f.stat().st_size for f in folder.glob("*") if f.is_file()) if folder.is_dir() else 0
        if size > _CACHE_LIMIT:
            shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True, exist_ok=True)
        os.environ[_CACHE_ENV] = str(folder)
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        _with_test_flags()
    if hasattr(config, "workerinput"):
        _own_cores(config.workerinput)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs",
                      float(os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")))


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
