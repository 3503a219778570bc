"""Native CPU splat rasterizer (private): `splat_all`, the tier-free twin of `_splat.splat`.

One XLA FFI call (native/kernels/raster.cc) rasterizes every valid face of every
view over the pixels within the blur radius of it, on `std::thread`s over the
views; the hand-written VJP is a second FFI call. Same model and formulas as
`_splat.py` (tapered coverage, depth-softmax blend with a background, depth
channel, envelope-theorem gradients), float32 or float64.

Under `vmap` the FFI calls use `vmap_method="broadcast_all"`: the batch axes
become extra leading view axes of one call.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgenus import _ffi  # noqa: F401  (registers the FFI targets)
from jaxgenus.rendering._splat import SplatConfig, Tier

__all__ = ["splat_all"]

_FORWARD = "jaxgenus_raster_forward"
_BACKWARD = "jaxgenus_raster_backward"


def _attrs(cfg: SplatConfig) -> dict:
    nb = cfg.n_attr + int(cfg.want_depth)
    bg = np.zeros(max(nb, 1), np.float64)
    bg[:nb] = np.asarray(cfg.background, np.float64).reshape(-1)[:nb]
    return dict(
        height=np.int64(cfg.height), width=np.int64(cfg.width), sigma=np.float64(cfg.sigma),
        gamma=np.float64(cfg.gamma), sharpness=np.float64(cfg.sharpness), want_cov=np.int64(bool(cfg.want_cov)),
        n_attr=np.int64(cfg.n_attr), attr_planes=np.int64(bool(cfg.attr_planes)), want_depth=np.int64(bool(cfg.want_depth)), background=bg,
    )


def _check(cfg: SplatConfig, faces: Tier, dconst) -> None:
    """Shapes and dtypes, checked at trace time with messages naming the argument."""
    if cfg.height < 1 or cfg.width < 1:
        raise ValueError(f"splat_all: height and width must be >= 1, got {cfg.height}, {cfg.width}")
    if cfg.n_attr < 0 or len(cfg.background) != cfg.n_attr + int(cfg.want_depth):
        raise ValueError("splat_all: cfg.background must have n_attr + want_depth values")
    v = faces.v
    if v.ndim < 3 or v.shape[-2:] != (3, 2):
        raise ValueError(f"splat_all: faces.v must have shape (N, F, 3, 2), got {v.shape}")
    if v.dtype not in (jnp.float32, jnp.float64):
        raise ValueError(f"splat_all: faces.v must be float32 or float64, got {v.dtype}")
    lead, nf = v.shape[:-3], v.shape[-3]
    want = {
        "plane": (faces.plane, (nf, 3), v.dtype), "qrange": (faces.qrange, (nf, 2), v.dtype),
        "attr": (faces.attr, (nf, cfg.n_attr * (5 if cfg.attr_planes else 1)), v.dtype), "logw": (faces.logw, (nf,), v.dtype),
        "valid": (faces.valid, (nf,), jnp.bool_), "dconst": (dconst, (2,), v.dtype),
    }
    for name, (x, tail, dtype) in want.items():
        shape = lead + tail
        if x is None or tuple(x.shape) != shape:
            got = None if x is None else tuple(x.shape)
            raise ValueError(f"splat_all: {name} must have shape {shape}, got {got}")
        if x.dtype != dtype:
            raise ValueError(f"splat_all: {name} must have dtype {np.dtype(dtype).name}, got {x.dtype}")


def _forward_call(cfg, faces, dconst):
    lead = faces.logw.shape[:-1]
    dt = faces.v.dtype
    h, w, nb = cfg.height, cfg.width, cfg.n_attr + int(cfg.want_depth)
    out = (
        jax.ShapeDtypeStruct(lead + (h, w), dt),
        jax.ShapeDtypeStruct(lead + (h, w, nb), dt),
        jax.ShapeDtypeStruct(lead + (h, w), dt),
    )
    call = jax.ffi.ffi_call(_FORWARD, out, vmap_method="broadcast_all")
    return call(faces.v, faces.plane, faces.qrange, faces.attr, faces.logw, faces.valid, dconst, **_attrs(cfg))


def _backward_call(cfg, faces, dconst, blend, mlw, g_cov, g_blend):
    out = (
        jax.ShapeDtypeStruct(faces.v.shape, faces.v.dtype),
        jax.ShapeDtypeStruct(faces.plane.shape, faces.v.dtype),
        jax.ShapeDtypeStruct(faces.qrange.shape, faces.v.dtype),
        jax.ShapeDtypeStruct(faces.attr.shape, faces.v.dtype),
        jax.ShapeDtypeStruct(faces.logw.shape, faces.v.dtype),
        jax.ShapeDtypeStruct(dconst.shape, faces.v.dtype),
    )
    call = jax.ffi.ffi_call(_BACKWARD, out, vmap_method="broadcast_all")
    return call(
        faces.v, faces.plane, faces.qrange, faces.attr, faces.logw, faces.valid, dconst,
        blend, mlw, g_cov, g_blend, **_attrs(cfg),
    )


def _strip(faces: Tier) -> Tier:
    return faces._replace(origin=None)


def _primal(cfg, faces, dconst):
    cov, blend, _ = _forward_call(cfg, faces, dconst)
    return cov, (blend if cfg.n_attr + int(cfg.want_depth) else None)


def _fwd(cfg, faces, dconst):
    cov, blend, mlw = _forward_call(cfg, faces, dconst)
    nb = cfg.n_attr + int(cfg.want_depth)
    return (cov, blend if nb else None), (faces, dconst, blend, mlw)


def _bwd(cfg, res, g):
    faces, dconst, blend, mlw = res
    g_cov, g_blend = g
    if g_blend is None:
        g_blend = jnp.zeros(blend.shape, blend.dtype)
    gv, gplane, gqrange, gattr, glogw, gdc = _backward_call(cfg, faces, dconst, blend, mlw, g_cov, g_blend)
    return Tier(gv, gplane, gqrange, gattr, glogw, None, None), gdc


_run = jax.custom_vjp(_primal, nondiff_argnums=(0,))
_run.defvjp(_fwd, _bwd)


def splat_all(cfg: SplatConfig, faces: Tier, dconst):
    """Rasterize every face slot of every view: returns `(cov (N, H, W), blend (N, H, W, C) or None)`.

    `faces` is a `Tier` with a leading view axis N holding all face slots (`origin` is
    ignored; faces with `valid == False` are skipped); `dconst` is `(N, 2)`. Only
    `height, width, sigma, gamma, want_cov, n_attr, want_depth, background` (and the
    derived `sharpness`) of `cfg` are used. Equals `_splat.splat(cfg, (faces,), dconst)`
    for a tier whose windows cover every face; differentiable (custom VJP), jit/vmap-able.
    """
    faces = _strip(faces)
    _check(cfg, faces, dconst)
    cfg = cfg._replace(windows=(1,), background=tuple(float(b) for b in cfg.background))
    return _run(cfg, faces, dconst)
