"""The native splat (`_splat_native.splat_all`) against the JAX splat (`_splat.splat`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgenus as jg
from jaxgenus.rendering import _faces
from jaxgenus.rendering._splat import SplatConfig, Tier, splat
from jaxgenus.rendering._splat_native import splat_all
from _meshes import icosphere


# the native kernels are CPU targets called directly here: pin the CPU device (conftest.py)
pytestmark = pytest.mark.usefixtures("cpu_device")

RES = 24
# (attrs, want_depth): cov only; cov + normal; cov + normal + shaded + depth; a colour interpolated
# over the faces (per-vertex colours: every attribute a clamped plane) + normal + depth
CHANNELS = [((), False), (("normal",), False), (("normal", "shaded"), True), (("normal", "color"), True)]


def _scene(dtype, attrs, want_depth, sigma=0.7, gamma=0.02):
    mesh = icosphere(2, noise=0.1, seed=0, dtype=dtype)
    mesh = jg.Mesh(mesh.vertices.astype(dtype), mesh.faces, mesh.n_vertices, mesh.n_faces)
    # close cameras: the sphere overflows the 24 x 24 image, so faces are partly off-image
    cams = jg.sphere_cameras(3, radius=2.6, fov_deg=45.0, resolution=RES)
    smooth = "color" in attrs
    colors = jnp.asarray(np.random.default_rng(5).uniform(0.1, 0.9, (mesh.vertex_capacity, 3)), dtype)
    fs = _faces.face_setup(
        mesh, cams, sigma=sigma, znear=1e-4, cull=True, attrs=attrs, light=None, ambient=0.3,
        vertex_colors=colors if smooth else None,
    )
    n_attr = sum(jg.rendering.CHANNEL_SIZES[a] for a in attrs)
    bg = tuple(0.1 * (i + 1) for i in range(n_attr + int(want_depth)))
    cfg = SplatConfig(
        height=RES, width=RES, windows=(RES,), sigma=sigma, gamma=gamma, want_cov=True,
        n_attr=n_attr, want_depth=want_depth, background=bg, attr_planes=smooth,
    )
    assert fs.attr.shape[-1] == n_attr * (5 if smooth else 1)
    tier = Tier(fs.v, fs.plane, fs.qrange, fs.attr, fs.logw, fs.valid, jnp.zeros(fs.origin.shape, jnp.int32))
    return cfg, tier, fs.dconst


def _as_fn(impl, cfg, tier):
    """Splat as a function of the float face arrays and dconst (valid/origin closed over)."""

    def f(v, plane, qrange, attr, logw, dconst):
        t = Tier(v, plane, qrange, attr, logw, tier.valid, tier.origin)
        if impl == "jax":
            return splat(cfg, (t,), dconst)
        return splat_all(cfg, t, dconst)

    return f


def _args(tier, dconst):
    return (tier.v, tier.plane, tier.qrange, tier.attr, tier.logw, dconst)


def _rel(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b), initial=0.0) / max(np.max(np.abs(b), initial=0.0), 1e-30))


def _compare(cfg, tier, dconst, tol):
    args = _args(tier, dconst)
    out_j, vjp_j = jax.vjp(_as_fn("jax", cfg, tier), *args)
    out_n, vjp_n = jax.jit(lambda *a: jax.vjp(_as_fn("native", cfg, tier), *a))(*args)
    assert (out_n[1] is None) == (out_j[1] is None)
    assert float(jnp.max(out_j[0])) > 0.5  # the scene is visible
    for a, b in zip(out_n, out_j):
        if b is not None:
            assert a.shape == b.shape and a.dtype == b.dtype
            assert _rel(a, b) < tol
    rng = np.random.default_rng(3)
    cot = jax.tree.map(lambda x: jnp.asarray(rng.standard_normal(x.shape), x.dtype), out_j)
    g_j = vjp_j(cot)
    g_n = jax.jit(vjp_n)(cot)
    names = ("v", "plane", "qrange", "attr", "logw", "dconst")
    for name, a, b in zip(names, g_n, g_j):
        assert a.shape == b.shape and a.dtype == b.dtype, name
        if b.size:
            assert _rel(a, b) < tol, (name, _rel(a, b))


@pytest.mark.parametrize("attrs,want_depth", CHANNELS)
def test_matches_jax_splat_float64(attrs, want_depth):
    with jax.enable_x64(True):
        cfg, tier, dconst = _scene(np.float64, attrs, want_depth)
        assert bool(jnp.any(tier.valid & jnp.any(tier.v < 0, axis=(-1, -2))))  # partly off-image
        _compare(cfg, tier, dconst, 1e-9)


@pytest.mark.parametrize("attrs,want_depth", CHANNELS)
def test_matches_jax_splat_float32(attrs, want_depth):
    cfg, tier, dconst = _scene(np.float32, attrs, want_depth)
    _compare(cfg, tier, dconst, 2e-4)  # float32 rounding: 1.4e-4 on the gradient with XLA CPU's loop emitters


def test_vmap_and_grad():
    with jax.enable_x64(True):
        cfg, tier, dconst = _scene(np.float64, ("normal",), True)
        shifts = jnp.asarray([0.0, 0.7])

        def loss(shift, v):
            t = tier._replace(v=v + shift)
            cov, blend = splat_all(cfg, t, dconst)
            return jnp.sum(cov**2) + jnp.sum(blend**2)

        batched = jax.jit(jax.vmap(jax.value_and_grad(loss, argnums=1), in_axes=(0, None)))(shifts, tier.v)
        for i, s in enumerate(shifts):
            val, g = jax.value_and_grad(loss, argnums=1)(s, tier.v)
            assert abs(float(batched[0][i]) - float(val)) <= 1e-12 * abs(float(val))
            assert _rel(batched[1][i], g) < 1e-12


def test_bad_shapes_raise_clear_errors():
    cfg, tier, dconst = _scene(np.float32, ("normal",), False)
    with pytest.raises(ValueError, match="plane"):
        splat_all(cfg, tier._replace(plane=tier.plane[..., :2]), dconst)
    with pytest.raises(ValueError, match="attr"):
        splat_all(cfg._replace(n_attr=2, background=(0.0, 0.0)), tier, dconst)
    with pytest.raises(ValueError, match="dconst"):
        splat_all(cfg, tier, dconst[:, :1])
    with pytest.raises(ValueError, match="logw"):
        splat_all(cfg, tier._replace(logw=tier.logw.astype(jnp.int32)), dconst)
    # the FFI adapter checks too (a direct call bypassing the Python checks)
    out = (jax.ShapeDtypeStruct((3, RES, RES), jnp.float32), jax.ShapeDtypeStruct((3, RES, RES, 3), jnp.float32),
           jax.ShapeDtypeStruct((3, RES, RES), jnp.float32))
    call = jax.ffi.ffi_call("jaxgenus_raster_forward", out)
    attrs = dict(height=np.int64(RES), width=np.int64(RES), sigma=np.float64(0.5), gamma=np.float64(0.01),
                 sharpness=np.float64(1.0), want_cov=np.int64(1), n_attr=np.int64(3), attr_planes=np.int64(0),
                 want_depth=np.int64(0),
                 background=np.zeros(3))
    with pytest.raises(Exception, match="qrange"):
        jax.block_until_ready(call(tier.v, tier.plane, tier.plane, tier.attr, tier.logw, tier.valid, dconst, **attrs))
    with pytest.raises(Exception, match="background"):
        attrs["background"] = np.zeros(1)
        jax.block_until_ready(call(tier.v, tier.plane, tier.qrange, tier.attr, tier.logw, tier.valid, dconst, **attrs))
