"""Per-face set-up of the soft rasterizer: projection, smooth facing weight, depth planes.

Everything here is plain JAX, differentiated by autodiff; the per-pixel work is in
`_splat.py` (JAX) and `_splat_native.py` (C++). See docs/rendering.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh
from jaxgenus.geometry import face_normals
from jaxgenus.rendering._projection import projected_faces
from jaxgenus.rendering._splat import CUTOFF_LOG, DC

_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)

__all__ = ["FACING_WIDTH", "Faces", "attribute_planes", "blur_radius", "check_inputs", "check_scalar", "face_setup",
           "facing_log_weight"]


class Faces(NamedTuple):
    v: Array  # (N, F, 3, 2) pixel coordinates
    plane: Array  # (N, F, 3)
    qrange: Array  # (N, F, 2)
    attr: Array  # (N, F, A)
    logw: Array  # (N, F) log of the smooth facing weight (0 without culling)
    valid: Array  # (N, F)
    origin: Array  # (N, F, 2) int32
    extent: Array  # (N, F) int32, larger side of the clipped blurred bbox
    dconst: Array  # (N, 2)


def blur_radius(sigma: float) -> float:
    """Distance in pixels beyond which a face's coverage is exactly 0 (D < 1e-4)."""
    return sigma * CUTOFF_LOG


#: Width of the smooth back-face cull in facing cosine: a face's coverage and blend
#: weight are scaled by w = sigmoid(cos / FACING_WIDTH) tapered to reach 0 where
#: sigmoid = 1e-4 (cos = -0.28), cos the cosine between its normal and the
#: direction to the camera.
FACING_WIDTH = 0.03


def facing_log_weight(tw, rot, trans):
    """log w per view and face; `tw (F, 3, 3)` the faces' world vertices.

    `cos` is computed in world space from the face normal `n`, the centroid `c` and
    the camera centre `C` as `n . (C - c) / (|n| |C - c|)`, with matrix products over
    views, so its backward costs little next to a per-view set-up."""
    n = jnp.cross(tw[:, 1] - tw[:, 0], tw[:, 2] - tw[:, 0])  # (F, 3)
    c = jnp.mean(tw, axis=1)
    hi = _HI
    centre = -jnp.einsum("nji,nj->ni", rot, trans, precision=hi)  # (N, 3)
    num = jnp.matmul(centre, n.T, precision=hi) - jnp.sum(n * c, axis=-1)[None, :]
    dist2 = jnp.sum(centre * centre, -1)[:, None] - 2.0 * jnp.matmul(centre, c.T, precision=hi) + jnp.sum(c * c, -1)[None, :]
    den2 = jnp.sum(n * n, axis=-1)[None, :] * jnp.maximum(dist2, 0.0)
    ok = den2 > jnp.finfo(tw.dtype).tiny
    cos = jnp.where(ok, num * jax.lax.rsqrt(jnp.where(ok, den2, 1.0)), 0.0)
    # tapered like the coverage: exactly 0 (log -inf, face dropped) at the cutoff
    w = jnp.minimum((jax.nn.sigmoid(cos / FACING_WIDTH) - DC) / (1.0 - 2.0 * DC), 1.0)  # w(c) + w(-c) = 1
    live = w > 0
    return jnp.where(live, jnp.log(jnp.where(live, w, 1.0)), -jnp.inf)


# Faces whose projection has under this doubled area (pixels^2) get a constant (their corners' mean):
# a plane through a sliver would be steep and its gradient in the vertices unbounded.
_MIN_AREA2 = 1e-3


def attribute_planes(uv, corner_values):
    """`(N, F, 5 A)`: per view, face and channel `(gx, gy, c, lo, hi)`, the affine function of the pixel
    `(u, v)` that takes `corner_values (F, 3, A)` at the projected corners `uv (N, F, 3, 2)` (interpolation
    in the image plane, not perspective-corrected: faces span a few pixels), clamped to the corners'
    range so that the blur margin outside a face does not extrapolate. Constant on slivers."""
    f = corner_values[None].astype(uv.dtype)  # (1, F, 3, A)
    d1, d2 = uv[:, :, 1] - uv[:, :, 0], uv[:, :, 2] - uv[:, :, 0]  # (N, F, 2)
    det = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    ok = jnp.abs(det) > _MIN_AREA2
    inv = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)[..., None]  # (N, F, 1)
    f1, f2 = f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0]  # (1, F, A)
    gx = (f1 * d2[..., 1:2] - f2 * d1[..., 1:2]) * inv
    gy = (f2 * d1[..., 0:1] - f1 * d2[..., 0:1]) * inv
    centre = jnp.mean(uv, axis=2)  # (N, F, 2): the plane through the corners' mean, exact at the corners
    c = jnp.mean(f, axis=2) - gx * centre[..., 0:1] - gy * centre[..., 1:2]
    lo = jnp.broadcast_to(jnp.min(f, axis=2), gx.shape)
    hi = jnp.broadcast_to(jnp.max(f, axis=2), gx.shape)
    planes = jnp.stack([gx, gy, c, lo, hi], axis=-1)  # (N, F, A, 5)
    return planes.reshape(planes.shape[:2] + (-1,))


def _constant_planes(values):
    """`(N, F, A)` face constants as `attribute_planes` (flat, the clamp pinned to the value)."""
    z = jnp.zeros_like(values)
    planes = jnp.stack([z, z, values, values, values], axis=-1)
    return planes.reshape(planes.shape[:2] + (-1,))


def check_scalar(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive float, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite float, got {value!r}")
    return v


def check_inputs(mesh, cameras):
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a jaxgenus.Mesh, got {type(mesh).__name__}")
    if not isinstance(cameras, Cameras):
        raise ValueError(f"cameras must be a jaxgenus.Cameras, got {type(cameras).__name__}")


def face_setup(mesh, cameras, *, sigma, znear, cull, attrs, light, ambient, face_colors=None,
               vertex_colors=None, vertex_values=None) -> Faces:
    """Per view and face: projection, culling, depth plane and blend attributes.

    With `vertex_colors (V, 3)` (for `"color"`, instead of `face_colors`) or `vertex_values (V, 3)`
    (for `"values"`) every attribute is a clamped plane in the pixel (`attribute_planes`; 5 values a
    channel): those are interpolated over each face, the other channels are constant planes."""
    dtype = mesh.vertices.dtype
    rot = cameras.rotation.astype(dtype)
    trans = cameras.translation.astype(dtype)
    focal = cameras.focal.astype(dtype)
    pp = cameras.principal_point.astype(dtype)
    h, w = cameras.height, cameras.width

    # gather the faces once; the per-view geometry has a hand-written VJP (_projection)
    tw = mesh.vertices[mesh.faces]
    pj = projected_faces(tw, rot, trans, focal, pp, mesh.face_mask, znear=znear)
    uv = pj.uv
    valid = mesh.face_mask[None, :] & pj.front
    if cull:
        logw = facing_log_weight(tw, rot, trans)
        valid = valid & (logw > -jnp.inf)
    else:
        logw = jnp.zeros(valid.shape, dtype)

    # window: pixel centres within the blur radius of the face's bbox, clipped to the image
    r = blur_radius(sigma)
    big = 4.0 * (h + w)
    uvc = jax.lax.stop_gradient(uv)
    lo = jnp.clip(jnp.min(uvc, axis=2) - r - 0.5, -big, big)
    hi = jnp.clip(jnp.max(uvc, axis=2) + r - 0.5, -big, big)
    size = jnp.array([w, h], dtype)
    first = jnp.clip(jnp.ceil(lo), 0, size)
    last = jnp.clip(jnp.floor(hi), -1, size - 1)
    span = last - first + 1
    valid = valid & jnp.all(span > 0, axis=-1)
    origin = first.astype(jnp.int32)
    extent = jnp.max(span, axis=-1).astype(jnp.int32)

    # faces dropped after the depth normalization (culled, off-image) get q = 0
    plane = jnp.where(valid[..., None], pj.plane, 0.0)
    qrange = jnp.where(valid[..., None], pj.qrange, 0.0)

    n_views, n_faces = valid.shape
    parts = []
    if attrs:
        nrm = face_normals(mesh)
        for name in attrs:
            if name == "normal":
                parts.append(jnp.broadcast_to(nrm[None], (n_views, n_faces, 3)))
            elif name == "color" and vertex_colors is not None:
                parts.append(vertex_colors)  # planes below
            elif name == "values":
                parts.append(vertex_values)  # planes below
            elif name == "color":
                parts.append(jnp.broadcast_to(face_colors.astype(dtype)[None], (n_views, n_faces, 3)))
            else:  # shaded
                if light is None:
                    ldir = -rot[:, 2, :]  # headlight: towards the camera
                else:
                    ldir = jnp.broadcast_to(jnp.asarray(light, dtype), (n_views, 3))
                    ldir = ldir / jnp.linalg.norm(ldir, axis=-1, keepdims=True)
                lam = jnp.maximum(jnp.einsum("fi,ni->nf", nrm, ldir, precision=_HI), 0.0)
                parts.append((ambient + (1.0 - ambient) * lam)[..., None])
    if vertex_colors is not None or vertex_values is not None:
        parts = [attribute_planes(uv, p.astype(dtype)[mesh.faces]) if p.ndim == 2 else _constant_planes(p)
                 for p in parts]
    attr = jnp.concatenate(parts, axis=-1) if parts else jnp.zeros((n_views, n_faces, 0), dtype)
    dconst = pj.dconst
    logw = jnp.where(valid, logw, 0.0)
    return Faces(uv, plane, qrange, attr, logw, valid, origin, extent, dconst)
