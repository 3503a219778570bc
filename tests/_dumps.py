"""Reading the StableHLO that JAX dumps: every float32 matrix product at full precision (test_precision)."""

import contextlib
import re
from pathlib import Path

import jax

_TYPES = re.compile(r": \((tensor<[^>]*>), (tensor<[^>]*>)\)")


@contextlib.contextmanager
def dumped_programs(folder: Path):
    """Every program lowered inside the block is dumped to `folder` as StableHLO with source lines."""
    jax.clear_caches()
    names = ("jax_dump_ir_to", "jax_include_debug_info_in_dumps")
    before = [jax.config.read(name) for name in names]
    jax.config.update("jax_dump_ir_to", str(folder))
    jax.config.update("jax_include_debug_info_in_dumps", True)
    try:
        yield folder
    finally:
        for name, value in zip(names, before):
            jax.config.update(name, value)


def _where(text: str, loc: str) -> str:
    """The first source file:line a `#locN` of a dumped module leads to."""
    defs = dict(re.findall(r"^(#loc\d+) = (.*)$", text, flags=re.M))
    seen = set()
    while loc in defs and loc not in seen:
        seen.add(loc)
        m = re.search(r'"([^"]+\.py)":(\d+)', defs[loc])
        if m:
            return f"{Path(m.group(1)).name}:{m.group(2)}"
        m = re.search(r"(#loc\d+)", defs[loc])
        loc = m.group(1) if m else ""
    return "?"


def default_precision_products(folder: Path) -> tuple[list[str], int]:
    """`(float32 products of default precision as "types at file:line", how many are HIGHEST)` in the
    modules dumped to `folder`."""
    default, full = [], 0
    for f in sorted(folder.glob("*.mlir")):
        text = f.read_text()
        for line in text.splitlines():
            types = _TYPES.search(line) if "stablehlo.dot_general" in line else None
            if types is None or "xf32>" not in types.group(1) + types.group(2):
                continue
            if "precision = [HIGHEST, HIGHEST]" in line:
                full += 1
            else:
                loc = re.search(r"loc\((#loc\d+)\)\s*$", line)
                default.append(f"{types.group(1)} x {types.group(2)} at {_where(text, loc.group(1) if loc else '')}")
    return default, full


def assert_full_precision(folder: Path, min_products: int = 10, sentinel: str | None = None):
    """Every float32 product dumped to `folder` asks for HIGHEST precision (apart from `sentinel`'s
    operand type, which must be found), and at least `min_products` were dumped."""
    default, full = default_precision_products(folder)
    assert full >= min_products, f"the programs were not dumped ({full} full-precision products)"
    if sentinel is not None:
        assert any(sentinel in d for d in default), "the check did not find the sentinel's default-precision product"
    rest = [d for d in default if sentinel is None or sentinel not in d]
    assert not rest, f"float32 products of default precision (TF32 on GPUs): {sorted(set(rest))}"
