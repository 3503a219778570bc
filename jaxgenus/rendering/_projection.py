"""Projected face geometry of the soft rasterizer, with a hand-written VJP.

`projected_faces` maps the faces' world vertices and the cameras to what the
splat needs per view and face: pixel coordinates of the corners, the plane of
the normalized inverse depth `q` over the triangle, its range, and the view's
depth normalization. It is one elementwise pass over views x faces, laid out
with the face axis last; autodiff of the same formulas cost 5-10x the forward
on XLA CPU (many small unfused passes over (N, F, 3, 2) arrays), the hand VJP
below is a few fused passes. Formulas: docs/rendering.md ("Per-face set-up").
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

__all__ = ["Projected", "projected_faces"]

_DET_EPS = 1e-12  # |det| below this: a degenerate projection, plane (0, 0, mean q)
_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)


class Projected(NamedTuple):
    uv: Array  # (N, F, 3, 2) pixel coordinates of the corners
    plane: Array  # (N, F, 3): q = gx u + gy v + c over the triangle
    qrange: Array  # (N, F, 2) min and max of q over the corners
    dconst: Array  # (N, 2) depth normalization (scale, offset): q = (1/z - offset) / scale
    front: Array  # (N, F) bool: every corner in front of the near plane


class _Fwd(NamedTuple):
    tw: Array  # (3 coord, 3 corner, F)
    x: Array  # (N, 3 corner, F) camera-space coordinates
    y: Array
    zok: Array
    iz: Array  # 1 / z (1 where z <= znear)
    u: Array  # (N, 3, F) pixel coordinates
    w: Array
    keep: Array  # (N, F) live and in front: the faces whose q is used
    q: Array  # (N, 3, F)
    zsel: Array  # (N, 3, F) z where kept, else nan
    zmin: Array  # (N,)
    zmax: Array
    anyv: Array
    a: Array  # (N,) 1/zmin - 1/zmax
    scale: Array
    offset: Array
    ok: Array  # (N, F) non-degenerate projection
    idet: Array
    gx: Array
    gy: Array
    c: Array


def _forward(tw_fc, rot, trans, focal, pp, live, znear):
    tw = jnp.transpose(tw_fc, (2, 1, 0))  # (3 coord, 3 corner, F)
    tri = jnp.einsum("nij,jkf->nikf", rot, tw, precision=_HI) + trans[:, :, None, None]
    x, y, z = tri[:, 0], tri[:, 1], tri[:, 2]
    zok = z > znear
    iz = 1.0 / jnp.where(zok, z, 1.0)
    u = x * iz * focal[:, 0, None, None] + pp[:, 0, None, None]
    w = y * iz * focal[:, 1, None, None] + pp[:, 1, None, None]
    keep = live[None, :] & jnp.all(zok, axis=1)
    zsel = jnp.where(keep[:, None, :], z, jnp.nan)
    anyv = jnp.any(keep, axis=1)
    zmin = jnp.where(anyv, jnp.min(jnp.where(keep[:, None, :], z, jnp.inf), axis=(1, 2)), 1.0)
    zmax = jnp.where(anyv, jnp.max(jnp.where(keep[:, None, :], z, -jnp.inf), axis=(1, 2)), 1.0)
    a = 1.0 / zmin - 1.0 / zmax
    scale = jnp.maximum(a, 1e-6 / zmin)
    offset = 1.0 / zmax
    q = jnp.where(keep[:, None, :], (iz - offset[:, None, None]) / scale[:, None, None], 0.0)
    e1x, e1y = u[:, 1] - u[:, 0], w[:, 1] - w[:, 0]
    e2x, e2y = u[:, 2] - u[:, 0], w[:, 2] - w[:, 0]
    det = e1x * e2y - e1y * e2x
    ok = jnp.abs(det) > _DET_EPS
    idet = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)
    dq1, dq2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    gx = (e2y * dq1 - e1y * dq2) * idet
    gy = (e1x * dq2 - e2x * dq1) * idet
    c = jnp.where(ok, q[:, 0] - gx * u[:, 0] - gy * w[:, 0], jnp.mean(q, axis=1))
    return _Fwd(tw, x, y, zok, iz, u, w, keep, q, zsel, zmin, zmax, anyv, a, scale, offset, ok, idet, gx, gy, c)


def _outputs(s: _Fwd) -> Projected:
    uv = jnp.transpose(jnp.stack([s.u, s.w], axis=-1), (0, 2, 1, 3))
    plane = jnp.stack([s.gx, s.gy, s.c], axis=-1)
    qrange = jnp.stack([jnp.min(s.q, axis=1), jnp.max(s.q, axis=1)], axis=-1)
    dconst = jnp.stack([s.scale, s.offset], axis=-1)
    return Projected(uv, plane, qrange, dconst, jnp.all(s.zok, axis=1))


@functools.partial(jax.custom_vjp, nondiff_argnums=(6,))
def _projected(tw, rot, trans, focal, pp, live, znear):
    return _outputs(_forward(tw, rot, trans, focal, pp, live, znear))


def _projected_fwd(tw, rot, trans, focal, pp, live, znear):
    return _projected(tw, rot, trans, focal, pp, live, znear), (tw, rot, trans, focal, pp, live)


def _first_extreme(q, which):
    """One-hot over the corner axis of the first corner where `q (N, 3, F)` is extreme."""
    k = jnp.argmin(q, axis=1) if which == "min" else jnp.argmax(q, axis=1)
    return k[:, None, :] == jnp.arange(3)[None, :, None]


def _projected_bwd(znear, res, g: Projected):
    tw_fc, rot, trans, focal, pp, live = res
    s = _forward(tw_fc, rot, trans, focal, pp, live, znear)
    dt = s.u.dtype
    gu = jnp.transpose(g.uv[..., 0], (0, 2, 1))  # (N, 3, F)
    gw = jnp.transpose(g.uv[..., 1], (0, 2, 1))
    gpx, gpy, gpc = g.plane[..., 0], g.plane[..., 1], g.plane[..., 2]

    # plane = M^-1 q with rows M_k = (u_k, w_k, 1): dL/dq = M^-T g, dL/dM_k = -dL/dq_k (gx, gy, c)
    e1x, e1y = s.u[:, 1] - s.u[:, 0], s.w[:, 1] - s.w[:, 0]
    e2x, e2y = s.u[:, 2] - s.u[:, 0], s.w[:, 2] - s.w[:, 0]
    dx = jnp.stack([e1y - e2y, e2y, -e1y], axis=1) * s.idet[:, None, :]  # d gx / d q_k
    dy = jnp.stack([e2x - e1x, -e2x, e1x], axis=1) * s.idet[:, None, :]  # d gy / d q_k
    ga = (gpx - gpc * s.u[:, 0])[:, None, :]
    gb = (gpy - gpc * s.w[:, 0])[:, None, :]
    first = (jnp.arange(3) == 0)[None, :, None]
    gq_ok = ga * dx + gb * dy + jnp.where(first, gpc[:, None, :], 0.0)
    ok = s.ok[:, None, :]
    gq = jnp.where(ok, gq_ok, gpc[:, None, :] / 3.0)
    gu = gu - jnp.where(ok, gq_ok * s.gx[:, None, :], 0.0)
    gw = gw - jnp.where(ok, gq_ok * s.gy[:, None, :], 0.0)
    gq = gq + jnp.where(_first_extreme(s.q, "min"), g.qrange[..., 0][:, None, :], 0.0)
    gq = gq + jnp.where(_first_extreme(s.q, "max"), g.qrange[..., 1][:, None, :], 0.0)
    gq = jnp.where(s.keep[:, None, :], gq, 0.0)

    # q = (1/z - offset) / scale
    inv_scale = (1.0 / s.scale)[:, None, None]
    giz = gq * inv_scale
    g_offset = -jnp.sum(giz, axis=(1, 2)) + g.dconst[:, 1]
    g_scale = -jnp.sum(gq * s.q, axis=(1, 2)) / s.scale + g.dconst[:, 0]
    # scale = max(1/zmin - 1/zmax, 1e-6/zmin), offset = 1/zmax (constants when no face is kept)
    big = s.a >= 1e-6 / s.zmin
    g_zmin = jnp.where(big, -g_scale, -1e-6 * g_scale) / (s.zmin * s.zmin)
    g_zmax = (jnp.where(big, g_scale, 0.0) - g_offset) / (s.zmax * s.zmax)
    g_zmin = jnp.where(s.anyv, g_zmin, 0.0)
    g_zmax = jnp.where(s.anyv, g_zmax, 0.0)
    at_min = s.zsel == s.zmin[:, None, None]
    at_max = s.zsel == s.zmax[:, None, None]
    n_min = jnp.maximum(jnp.sum(at_min, axis=(1, 2)), 1).astype(dt)
    n_max = jnp.maximum(jnp.sum(at_max, axis=(1, 2)), 1).astype(dt)

    # pixel coordinates u = f x / z + p
    fx, fy = focal[:, 0, None, None], focal[:, 1, None, None]
    giz = giz + gu * fx * s.x + gw * fy * s.y
    gx_cam = gu * fx * s.iz
    gy_cam = gw * fy * s.iz
    gz_cam = jnp.where(s.zok, -giz * s.iz * s.iz, 0.0)
    gz_cam = gz_cam + jnp.where(at_min, (g_zmin / n_min)[:, None, None], 0.0)
    gz_cam = gz_cam + jnp.where(at_max, (g_zmax / n_max)[:, None, None], 0.0)
    g_focal = jnp.stack([jnp.sum(gu * s.x * s.iz, axis=(1, 2)), jnp.sum(gw * s.y * s.iz, axis=(1, 2))], axis=-1)
    g_pp = jnp.stack([jnp.sum(gu, axis=(1, 2)), jnp.sum(gw, axis=(1, 2))], axis=-1)

    # camera-space coordinates R x + t, as two plain matrix products over the
    # gradients stacked camera-axis-major, (3 N, 3 corner x F). Stacking them as
    # (N, 3, 3, F) made XLA CPU write the whole chain above in one transposing,
    # unvectorized fusion, and reductions over the view axis ran at ~5 ms each.
    n = rot.shape[0]
    g_all = jnp.concatenate([gx_cam, gy_cam, gz_cam], axis=0).reshape(3 * n, -1)  # rows (i, n)
    r_all = jnp.transpose(rot, (1, 0, 2)).reshape(3 * n, 3)  # rows (i, n): R[n, i, :]
    g_tw = jnp.matmul(r_all.T, g_all, precision=_HI).reshape(3, 3, -1)  # (coord j, corner k, F)
    g_rot = jnp.transpose(jnp.matmul(g_all, s.tw.reshape(3, -1).T, precision=_HI).reshape(3, n, 3), (1, 0, 2))
    g_trans = jnp.transpose(jnp.sum(g_all, axis=1).reshape(3, n))
    return jnp.transpose(g_tw, (2, 1, 0)), g_rot, g_trans, g_focal, g_pp, None


_projected.defvjp(_projected_fwd, _projected_bwd)


def projected_faces(tw, rot, trans, focal, pp, live, *, znear: float) -> Projected:
    """Per view and face: corner pixels, inverse-depth plane and range, depth normalization.

    `tw (F, 3, 3)` the faces' world corners; `rot (N, 3, 3)`, `trans (N, 3)`,
    `focal (N, 2)`, `pp (N, 2)` the cameras (world to camera `R x + t`, pixels
    `f x / z + p`); `live (F,)` the faces in use. A face is kept when it is live
    and every corner lies beyond `znear`; `q = (1/z - offset) / scale` maps the
    kept corners' inverse depths of a view onto [0, 1]; faces not kept get
    q = 0. Differentiable in every float argument (hand-written VJP, reverse mode only).
    """
    return _projected(tw, rot, trans, focal, pp, live, float(znear))
