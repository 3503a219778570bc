"""The package's structure: public surface, version, module sizes, imports and dependencies."""

from __future__ import annotations

import ast
import importlib.metadata
import re
import types
from pathlib import Path

import jaxgenus as jg

PACKAGE = Path(jg.__file__).parent
MODULES = sorted(PACKAGE.glob("*.py"))


def test_all_lists_exactly_the_public_names():
    assert len(jg.__all__) == len(set(jg.__all__))
    assert [n for n in jg.__all__ if not hasattr(jg, n)] == []
    public = {n for n in dir(jg) if not n.startswith("_")}
    modules = {n for n in public if isinstance(getattr(jg, n), types.ModuleType) and n != "metrics"}
    assert public - modules == set(jg.__all__)


def test_version_is_the_installed_metadata():
    assert jg.__version__ == importlib.metadata.version("jaxgenus")


def test_no_module_over_450_lines():
    sizes = {p.name: len(p.read_text().splitlines()) for p in MODULES}
    assert {k: v for k, v in sizes.items() if v > 450} == {}


def _imports(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, []


def test_no_private_name_is_imported_across_modules():
    bad = []
    for path in MODULES:
        for module, names in _imports(path):
            if module.startswith("jaxgenus"):
                # a private module (`from jaxgenus import _colmap`) is fine, a private name in one is not
                bad += [f"{path.name}: from {module} import {n}" for n in names
                        if n.startswith("_") and not (module == "jaxgenus" and (PACKAGE / f"{n}.py").exists())
                        and n != "_native"]
    assert bad == []


def test_every_declared_runtime_dependency_is_imported():
    requires = importlib.metadata.requires("jaxgenus") or []
    runtime = [re.split(r"[\s<>=!~;\[]", r, maxsplit=1)[0].lower() for r in requires if "extra ==" not in r]
    # distribution name -> import name; trimesh's ray/spatial backends are used through trimesh
    module_of = {"libigl": "igl", "pillow": "PIL", "rtree": None, "embreex": None}
    imported = {m.split(".")[0] for p in MODULES for m, _ in _imports(p)}
    missing = [d for d in runtime if module_of.get(d, d.replace("-", "_")) not in imported | {None}]
    assert runtime and missing == []
