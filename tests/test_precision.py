"""No float32 matrix product of default precision in the programs a fit compiles.

A GPU (Ampere and later) runs a float32 `dot_general` of default precision with its operands
rounded to TF32, 10 mantissa bits: a relative error of about 5e-4. In the photo-consistency warp
that is a fraction of a pixel at 400 px and over a pixel at full DTU size, which the term cannot
tell from a depth error. A CPU computes such products in float32 either way, so a CPU run cannot
show the loss; these checks read the StableHLO that JAX dumps (`jax_dump_ir_to`) for every program
lowered while `_dumps.dumped_programs` is open (it first drops the process's compiled programs, so each
is lowered anew; the dump is written before the persistent cache is asked) and ask every float32
product for `Precision.HIGHEST`. The small photo fit (stereo start, the optimizer and its photo-consistency,
the polish, the verdict) is test_consistency's end-to-end fit, checked there with
`assert_full_precision`; here: the JAX splat the GPUs render with, the metrics, the camera import,
and a sentinel that shows the check finds a default-precision product.
"""

import jax
import jax.numpy as jnp

import jaxgenus as jg
from _dumps import assert_full_precision, dumped_programs
from _meshes import torus, torus_trimesh


def test_float32_products_are_full_precision(tmp_path):
    tm = torus_trimesh(1.0, 0.35, 24, 12)
    cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
    m = torus(1.0, 0.35, 24, 12)
    with dumped_programs(tmp_path):
        view, fov = jg.geometry.cameras_to_opengl(cams)
        jg.project(jg.cameras_from_opengl(view, fov[0], height=64, width=64), jnp.zeros((4, 3)))
        jg.render(m, cams, channels=("alpha", "depth", "shaded"), plan=jg.rendering.plan_render(m, cams))
        jg.metrics.chamfer_distance(m, tm)
        jg.metrics.icp_align(m, tm)
        a = jnp.ones((7, 5), jnp.float32)
        jax.jit(lambda x: jnp.einsum("ij,jk->ik", x, x.T))(a)  # the sentinel: a default-precision product
    assert_full_precision(tmp_path, min_products=2, sentinel="7x5xf32")
