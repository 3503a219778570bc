"""The package's structure: public surface, version, layers, module and function sizes, imports, dependencies."""

from __future__ import annotations

import ast
import dataclasses
import importlib.metadata
import re
import types
from pathlib import Path

import jaxgenus as jg

PACKAGE = Path(jg.__file__).parent
MODULES = sorted(PACKAGE.rglob("*.py"))
# the layers, each importing only from the ones it names (and from the top-level `_ffi`)
LAYERS = {
    "geometry": set(),
    "rendering": {"geometry"},
    "capture": {"geometry"},
    "optim": {"geometry", "rendering"},
    "pipeline": {"geometry", "rendering", "capture", "optim"},
}
SUBPACKAGES = sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py"))


def _layer(path: Path) -> str | None:
    rel = path.relative_to(PACKAGE).parts
    return rel[0] if len(rel) == 2 else None


def test_all_lists_exactly_the_public_names():
    assert len(jg.__all__) == len(set(jg.__all__))
    assert len(jg.__all__) <= 40 and "metrics" in jg.__all__  # the names a user calls; the rest in subpackages
    assert [n for n in jg.__all__ if not hasattr(jg, n)] == []
    public = {n for n in dir(jg) if not n.startswith("_")}
    modules = {n for n in public if isinstance(getattr(jg, n), types.ModuleType)}
    assert modules == set(SUBPACKAGES) | {"metrics"}
    assert public - modules == set(jg.__all__) - {"metrics"}
    # plumbing stays in its room
    assert not {"RECORD_KEYS", "CHANNEL_SIZES", "capacity_bucket", "LIGHTING_SHAPE"} & set(jg.__all__)


def test_every_subpackage_lists_what_it_exports():
    for name in SUBPACKAGES:
        sub = getattr(jg, name)
        assert sorted(sub.__all__) == sorted(n for n in dir(sub) if not n.startswith("_")
                                             and not isinstance(getattr(sub, n), types.ModuleType)), name


def test_version_is_the_installed_metadata():
    assert jg.__version__ == importlib.metadata.version("jaxgenus")


def test_layers_and_sizes():
    assert set(SUBPACKAGES) == set(LAYERS)
    top = [p.name for p in PACKAGE.glob("*.py")]
    assert len(top) <= 6, top
    for name in SUBPACKAGES:
        modules = [p for p in (PACKAGE / name).glob("*.py") if p.name != "__init__.py"]
        assert len(modules) <= 12, (name, len(modules))
    sizes = {str(p.relative_to(PACKAGE)): len(p.read_text().splitlines()) for p in MODULES}
    assert {k: v for k, v in sizes.items() if v > 450} == {}


def _code_lines(path: Path, node) -> int:
    """Lines of a function's body that hold code (docstring, blank lines and comments excluded)."""
    body = node.body
    if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
        body = body[1:]
    if not body:
        return 0
    lines = path.read_text().splitlines()[body[0].lineno - 1: node.end_lineno]
    return sum(1 for line in lines if line.strip() and not line.strip().startswith("#"))


def test_no_function_over_80_lines():
    long = []
    for path in MODULES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = _code_lines(path, node)
                if n > 80:
                    long.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name} ({n} lines)")
    assert long == []


def _imports(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, []


def test_no_private_name_crosses_a_module_and_layers_point_down():
    bad = []
    for path in MODULES:
        me = _layer(path)
        for module, names in _imports(path):
            if not module.startswith("jaxgenus"):
                continue
            parts = module.split(".")
            if me is not None and len(parts) > 1 and parts[1] in LAYERS and parts[1] != me:
                if parts[1] not in LAYERS[me]:
                    bad.append(f"{path.name} ({me}) imports the layer above it: {module}")
                if len(parts) > 2:  # another room's private module
                    bad.append(f"{path.name} ({me}) reaches into {module}")
            # a sibling private module (`from jaxgenus.capture import _colmap`) is fine, a private name is not
            siblings = {p.stem for p in (PACKAGE / Path(*parts[1:])).glob("_*.py")} if len(parts) <= 2 else set()
            bad += [f"{path.name}: from {module} import {n}" for n in names
                    if n.startswith("_") and n not in siblings and n not in ("_native", "_ffi")]
    assert bad == []


def test_reconstruct_options_take_their_parts_names_and_defaults():
    """A setting of `ReconstructOptions` that a part (`OptimizeOptions`, ...) holds has the part's name and
    default (one default per setting), and the part `reconstruct` runs carries it."""
    from jaxgenus.pipeline import ENTRIES

    o = jg.ReconstructOptions()
    mine = {f.name for f in dataclasses.fields(o)} | set(ENTRIES)
    parts = {jg.OptimizeOptions: o.optimize, jg.LossWeights: o.optimize.weights, jg.RenderSettings: o.render,
             jg.RemeshOptions: o.remesh_options}
    shared = 0
    for part, derived in parts.items():
        for name in mine & {f.name for f in dataclasses.fields(part)} - {"max_faces"}:  # the budget: none in remesh()
            assert getattr(o, name) == getattr(part(), name) == getattr(derived, name), (part.__name__, name)
            shared += 1
    assert shared >= 20 and o.remesh_options.max_faces == o.max_faces


def test_every_declared_runtime_dependency_is_imported():
    requires = importlib.metadata.requires("jaxgenus") or []
    runtime = [re.split(r"[\s<>=!~;\[]", r, maxsplit=1)[0].lower() for r in requires if "extra ==" not in r]
    # distribution name -> import name; trimesh's ray/spatial backends are used through trimesh
    module_of = {"libigl": "igl", "pillow": "PIL", "rtree": None, "embreex": None}
    imported = {m.split(".")[0] for p in MODULES for m, _ in _imports(p)}
    missing = [d for d in runtime if module_of.get(d, d.replace("-", "_")) not in imported | {None}]
    assert runtime and missing == []
