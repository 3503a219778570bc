"""No float32 matrix product of default precision in the programs a fit compiles.

A GPU (Ampere and later) runs a float32 `dot_general` of default precision with its operands
rounded to TF32, 10 mantissa bits: a relative error of about 5e-4. In the photo-consistency warp
that is a fraction of a pixel at 400 px and over a pixel at full DTU size, which the term cannot
tell from a depth error. A CPU computes such products in float32 either way, so a CPU run cannot
show the loss; this test reads the StableHLO that JAX dumps (`JAX_DUMP_IR_TO`) for every program
a small photo fit compiles (stereo start, the optimizer and its photo-consistency, the polish, the
verdict, the JAX splat the GPUs render with, the metrics) and asks every float32 product for
`Precision.HIGHEST`.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

_RUN = """
import numpy as np, jax, jax.numpy as jnp
import jaxgenus as jg
from _meshes import torus, torus_trimesh
from _raycast import cell_albedo, raycast_lambert
# the scene and options of test_consistency's photo fit: its programs come from the shared cache
tm = torus_trimesh(1.0, 0.35, 64, 32)
cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
view, fov = jg.geometry.cameras_to_opengl(cams)
jg.project(jg.cameras_from_opengl(view, fov[0], height=64, width=64), jnp.zeros((4, 3)))
light = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])
photos = np.asarray(raycast_lambert(cams, tm, light_direction=light, ambient=0.25, albedo=cell_albedo(0.1)),
                    np.float32)
opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=15, consistency=1.0, polish_cycles=2)
rec = jg.reconstruct(photos, cams, 1, targets="photo", options=opts, key=jax.random.key(0))
m = torus(1.0, 0.35, 24, 12)
jg.render(m, cams, channels=("alpha", "depth", "shaded"), plan=jg.rendering.plan_render(m, cams))
jg.metrics.chamfer_distance(rec.mesh, tm)
jg.metrics.icp_align(rec.mesh, tm)
a = jnp.ones((7, 5), jnp.float32)
jax.jit(lambda x: jnp.einsum("ij,jk->ik", x, x.T))(a)  # the sentinel: a default-precision product
"""

_TYPES = re.compile(r": \((tensor<[^>]*>), (tensor<[^>]*>)\)")


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


@pytest.mark.slow
def test_float32_products_are_full_precision(tmp_path):
    env = dict(os.environ, JAX_DUMP_IR_TO=str(tmp_path), JAX_INCLUDE_DEBUG_INFO_IN_DUMPS="1")
    here = Path(__file__).parent
    subprocess.run([sys.executable, "-c", _RUN], env=env, cwd=here, check=True, capture_output=True)
    default, full = [], 0
    for f in sorted(tmp_path.glob("*.mlir")):
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
    assert full > 10, "the fit's programs were not dumped"
    sentinel = [d for d in default if "7x5xf32" in d or "5x7xf32" in d]
    assert sentinel, "the check did not find the sentinel's default-precision product"
    rest = [d for d in default if d not in sentinel]
    assert not rest, f"float32 products of default precision (TF32 on GPUs): {sorted(set(rest))}"
