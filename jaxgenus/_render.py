"""`render`: differentiable soft rasterizer (silhouette, normal, depth, shaded channels).

The per-face set-up (projection, culling, depth planes, attributes) is plain JAX
and is differentiated by autodiff; the per-pixel work is the face-major splat of
`_splat.py` with its hand-written VJP. See docs/rendering.md.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from jaxgenus._cameras import Cameras
from jaxgenus._mesh import Mesh
from jaxgenus._operators import face_normals
from jaxgenus._splat import CUTOFF_LOG, DC, SplatConfig, Tier, splat

__all__ = ["render", "RenderInfo", "RasterPlan", "plan_render", "CHANNEL_SIZES"]

#: Number of image channels each requested channel contributes, in request order.
CHANNEL_SIZES = {"alpha": 1, "normal": 3, "depth": 1, "shaded": 1}
_BLEND_DEFAULT = {"normal": (0.0, 0.0, 0.0), "depth": (0.0,), "shaded": (0.0,)}
_WINDOW_BUCKETS = (4, 5, 6, 7, 8, 9, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 128, 160, 192, 256)


class RasterPlan(eqx.Module):
    """Static window sizes and face budgets of the splat rasterizer.

    Faces whose blurred bounding box (clipped to the image) fits in
    `window x window` pixels go to the small tier (at most `max_faces` per view);
    larger ones go to the big tier (`big_window`, at most `max_big_faces` per
    view; `max_big_faces = 0` disables it). Faces larger than their tier's window
    are truncated and faces beyond a budget are dropped; both are counted in
    `RenderInfo`. Changing a plan recompiles a jitted caller.
    """

    window: int = eqx.field(static=True)
    max_faces: int = eqx.field(static=True)
    big_window: int = eqx.field(static=True, default=0)
    max_big_faces: int = eqx.field(static=True, default=0)

    def __check_init__(self):
        if self.window < 1 or self.max_faces < 1:
            raise ValueError(f"plan needs window >= 1 and max_faces >= 1, got {self.window}, {self.max_faces}")
        if self.max_big_faces < 0 or (self.max_big_faces and self.big_window <= self.window):
            raise ValueError("plan.big_window must exceed plan.window when max_big_faces > 0")

    def pairs_per_view(self) -> int:
        """Pixel-face pairs evaluated per view."""
        return self.max_faces * self.window**2 + self.max_big_faces * self.big_window**2


class RenderInfo(eqx.Module):
    """Coverage counters of one `render` call (per view, int32 arrays)."""

    n_visible: Int[Array, "N"]
    n_truncated: Int[Array, "N"]
    n_dropped: Int[Array, "N"]

    @property
    def n_overflow(self) -> Array:
        """Total number of faces rendered incompletely (truncated + dropped), all views."""
        return jnp.sum(self.n_truncated) + jnp.sum(self.n_dropped)


class _Faces(NamedTuple):
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


def _facing_log_weight(tri):
    """log sigmoid(cos / FACING_WIDTH) per view and face; `tri (N, F, 3, 3)` in camera space."""
    ncam = jnp.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    to_cam = -jnp.mean(tri, axis=2)
    num = jnp.sum(ncam * to_cam, axis=-1)
    den2 = jnp.sum(ncam * ncam, axis=-1) * jnp.sum(to_cam * to_cam, axis=-1)
    ok = den2 > jnp.finfo(tri.dtype).tiny
    cos = jnp.where(ok, num * jax.lax.rsqrt(jnp.where(ok, den2, 1.0)), 0.0)
    # tapered like the coverage: exactly 0 (log -inf, face dropped) at the cutoff
    w = jnp.minimum((jax.nn.sigmoid(cos / FACING_WIDTH) - DC) / (1.0 - 2.0 * DC), 1.0)  # w(c) + w(-c) = 1
    live = w > 0
    return jnp.where(live, jnp.log(jnp.where(live, w, 1.0)), -jnp.inf)


def _check_scalar(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive float, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite float, got {value!r}")
    return v


def _check_inputs(mesh, cameras):
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a jaxgenus.Mesh, got {type(mesh).__name__}")
    if not isinstance(cameras, Cameras):
        raise ValueError(f"cameras must be a jaxgenus.Cameras, got {type(cameras).__name__}")


def _face_setup(mesh, cameras, *, sigma, znear, cull, attrs, light, ambient) -> _Faces:
    """Per view and face: projection, culling, depth plane and blend attributes."""
    dtype = mesh.vertices.dtype
    rot = cameras.rotation.astype(dtype)
    trans = cameras.translation.astype(dtype)
    focal = cameras.focal.astype(dtype)
    pp = cameras.principal_point.astype(dtype)
    h, w = cameras.height, cameras.width

    xc = jnp.einsum("nij,vj->nvi", rot, mesh.vertices) + trans[:, None, :]
    tri = xc[:, mesh.faces]  # (N, F, 3, 3)
    z = tri[..., 2]
    front_ok = jnp.all(z > znear, axis=-1)
    zs = jnp.where(z > znear, z, 1.0)  # double where: no x/z blow-up
    uv = tri[..., :2] / zs[..., None] * focal[:, None, None, :] + pp[:, None, None, :]

    valid = mesh.face_mask[None, :] & front_ok
    in_front = valid  # depth normalization: every face in front of the camera (continuous)
    if cull:
        logw = _facing_log_weight(tri)
        valid = valid & (logw > -jnp.inf)
    else:
        logw = jnp.zeros(valid.shape, dtype)

    # window: pixel centres within the blur radius of the face's bbox, clipped to the image
    r = blur_radius(sigma)
    big = 4.0 * (h + w)
    lo = jnp.clip(jnp.min(uv, axis=2) - r - 0.5, -big, big)
    hi = jnp.clip(jnp.max(uv, axis=2) + r - 0.5, -big, big)
    size = jnp.array([w, h], dtype)
    first = jnp.clip(jnp.ceil(lo), 0, size)
    last = jnp.clip(jnp.floor(hi), -1, size - 1)
    span = last - first + 1
    valid = valid & jnp.all(span > 0, axis=-1)
    origin = jax.lax.stop_gradient(first).astype(jnp.int32)
    extent = jnp.max(jax.lax.stop_gradient(span), axis=-1).astype(jnp.int32)

    # normalized inverse depth q in [0, 1] over this view's visible vertices
    zmin = jnp.min(jnp.where(in_front[..., None], z, jnp.inf), axis=(1, 2))
    zmax = jnp.max(jnp.where(in_front[..., None], z, -jnp.inf), axis=(1, 2))
    anyv = jnp.any(in_front, axis=1)
    zmin = jnp.where(anyv, zmin, 1.0)
    zmax = jnp.where(anyv, zmax, 1.0)
    scale = jnp.maximum(1.0 / zmin - 1.0 / zmax, 1e-6 / zmin)
    offset = 1.0 / zmax
    q = (1.0 / zs - offset[:, None, None]) / scale[:, None, None]
    q = jnp.where(valid[..., None], q, 0.0)

    e1 = uv[:, :, 1] - uv[:, :, 0]
    e2 = uv[:, :, 2] - uv[:, :, 0]
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    ok = jnp.abs(det) > 1e-12
    idet = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)
    dq1 = q[..., 1] - q[..., 0]
    dq2 = q[..., 2] - q[..., 0]
    gx = (e2[..., 1] * dq1 - e1[..., 1] * dq2) * idet
    gy = (e1[..., 0] * dq2 - e2[..., 0] * dq1) * idet
    c = jnp.where(ok, q[..., 0] - gx * uv[:, :, 0, 0] - gy * uv[:, :, 0, 1], jnp.mean(q, axis=-1))
    plane = jnp.stack([gx, gy, c], axis=-1)
    qrange = jnp.stack([jnp.min(q, axis=-1), jnp.max(q, axis=-1)], axis=-1)

    n_views, n_faces = valid.shape
    parts = []
    if attrs:
        nrm = face_normals(mesh)
        for name in attrs:
            if name == "normal":
                parts.append(jnp.broadcast_to(nrm[None], (n_views, n_faces, 3)))
            else:  # shaded
                if light is None:
                    ldir = -rot[:, 2, :]  # headlight: towards the camera
                else:
                    ldir = jnp.broadcast_to(jnp.asarray(light, dtype), (n_views, 3))
                    ldir = ldir / jnp.linalg.norm(ldir, axis=-1, keepdims=True)
                lam = jnp.maximum(jnp.einsum("fi,ni->nf", nrm, ldir), 0.0)
                parts.append((ambient + (1.0 - ambient) * lam)[..., None])
    attr = jnp.concatenate(parts, axis=-1) if parts else jnp.zeros((n_views, n_faces, 0), dtype)
    dconst = jnp.stack([scale, offset], axis=-1)
    logw = jnp.where(valid, logw, 0.0)
    return _Faces(uv, plane, qrange, attr, logw, valid, origin, extent, dconst)


@functools.partial(jax.jit, static_argnames=("sigma", "znear", "cull"))
def _visible_extents(mesh, cameras, *, sigma, znear, cull):
    fs = _face_setup(mesh, cameras, sigma=sigma, znear=znear, cull=cull, attrs=(), light=None, ambient=0.0)
    return fs.valid, fs.extent


def _compact(mask: Array, k: int):
    """Indices of the first `k` True entries of each row of `mask (N, F)`, and a slot mask."""
    n, f = mask.shape
    pos = jnp.cumsum(mask, axis=1) - 1
    tgt = jnp.where(mask & (pos < k), pos, k)
    rows = jnp.broadcast_to(jnp.arange(n)[:, None], (n, f))
    idx = jnp.zeros((n, k), jnp.int32).at[rows, tgt].set(
        jnp.broadcast_to(jnp.arange(f, dtype=jnp.int32), (n, f)), mode="drop"
    )
    count = jnp.sum(mask, axis=1)
    return idx, jnp.arange(k)[None, :] < count[:, None], count


def _gather(x, idx):
    return jnp.take_along_axis(x, idx.reshape(idx.shape + (1,) * (x.ndim - 2)), axis=1)


def _bucket(n: int) -> int:
    for b in _WINDOW_BUCKETS:
        if b >= n:
            return b
    return int(n)


def plan_render(
    mesh: Mesh,
    cameras: Cameras,
    *,
    sigma: float = 0.1,
    znear: float = 1e-4,
    cull_backfaces: bool = True,
    quantile: float = 0.999,
    face_margin: float = 1.1,
) -> RasterPlan:
    """Choose a `RasterPlan` from the geometry (call outside `jit`, on concrete arrays).

    The small window is the bucket, at most the `quantile` of the visible faces'
    clipped blurred bounding boxes (rounded up to a bucket), that minimizes the
    evaluated pairs; the rest go to a big tier sized for the largest face, so the
    plan truncates nothing for this geometry. Face budgets get a `face_margin`
    headroom so nearby shapes reuse the plan.
    """
    _check_inputs(mesh, cameras)
    sigma = _check_scalar("sigma", sigma)
    if not 0.0 < quantile <= 1.0:
        raise ValueError(f"quantile must be in (0, 1], got {quantile}")
    if face_margin < 1.0:
        raise ValueError(f"face_margin must be >= 1, got {face_margin}")
    valid, ext = (np.asarray(a) for a in _visible_extents(mesh, cameras, sigma=sigma, znear=znear, cull=cull_backfaces))
    n_faces = mesh.face_capacity
    vis = ext[valid]
    if vis.size == 0:
        return RasterPlan(window=_bucket(int(math.ceil(2 * blur_radius(sigma))) + 2), max_faces=min(8, max(n_faces, 1)))
    big_window = _bucket(int(vis.max()))
    top = _bucket(int(np.ceil(np.quantile(vis, quantile, method="higher"))))
    best = None
    for window in [b for b in _WINDOW_BUCKETS if _bucket(int(vis.min())) <= b < top] + [top]:
        small = np.sum(valid & (ext <= window), axis=1).max()
        nbig = np.sum(valid & (ext > window), axis=1).max()
        max_faces = int(min(n_faces, math.ceil(small * face_margin / 8 + 1) * 8))
        max_big = int(min(n_faces, math.ceil(nbig * face_margin / 4 + 1) * 4)) if nbig else 0
        plan = RasterPlan(window=window, max_faces=max_faces, big_window=big_window if nbig else 0, max_big_faces=max_big)
        if best is None or plan.pairs_per_view() < best.pairs_per_view():
            best = plan
    return best


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _default_plan(mesh, cameras, sigma, znear, cull):
    if not (_is_traced(mesh.vertices) or _is_traced(cameras.rotation) or _is_traced(cameras.translation)):
        return plan_render(mesh, cameras, sigma=sigma, znear=znear, cull_backfaces=cull)
    # traced and no plan: every face slot, a window for faces up to ~16 px (documented)
    return RasterPlan(window=_bucket(int(math.ceil(2 * blur_radius(sigma))) + 16), max_faces=mesh.face_capacity)


def render(
    mesh: Mesh,
    cameras: Cameras,
    *,
    channels=("alpha", "normal"),
    sigma: float = 0.1,
    gamma: float = 0.01,
    background=None,
    znear: float = 1e-4,
    cull_backfaces: bool = True,
    light_direction=None,
    ambient: float = 0.3,
    plan: RasterPlan | None = None,
    return_info: bool = False,
):
    """Soft-rasterize `mesh` in every camera: returns images `(N, H, W, C)`.

    Channels (concatenated in the requested order; `CHANNEL_SIZES` gives C):

    * `"alpha"` (1): coverage `min(1, sum_j sigmoid(s_j / sigma))` over the front
      faces, `s_j` the signed distance in pixels from the pixel centre to face j's
      projection (> 0 inside). Neighbours sum to 1 along a shared edge, so the
      inside of a fine mesh is opaque and silhouettes are not shifted.
    * `"normal"` (3): world-space unit face normals blended by a depth softmax
      with temperature `gamma` (on the normalized inverse depth of the view).
    * `"depth"` (1): the camera-space depth blended the same way.
    * `"shaded"` (1): Lambertian `ambient + (1 - ambient) * max(0, n . l)` blended
      the same way; `l` is `light_direction` (world, pointing to the light) or, if
      None, a headlight (towards each camera).

    Args:
        sigma: edge blur in pixels (the sigmoid's scale; 10-90 % over 4.4 sigma).
            gamma: depth softmax temperature.
        background: dict `{"normal": (3,), "depth": float, "shaded": float}` of
            blend background values (default 0); alpha's background is 0.
        znear: faces with a vertex at camera depth <= znear (world units) are skipped.
        cull_backfaces: fade out faces turned away from the camera (closed meshes):
            coverage and blend weight scale by `sigmoid(cos / FACING_WIDTH)`, so the
            image stays continuous in the vertices as a face turns at the contour
            (a hard cut there breaks the silhouette gradient). False: all faces.
        plan: a `RasterPlan` (windows, face budgets). If None it is chosen from the
            geometry when the inputs are concrete, else a generic plan is used;
            inside `jit` pass `plan_render(...)` computed outside.
        return_info: also return a `RenderInfo` with overflow counts.

    Only the requested channels are computed. jit/vmap friendly; float64 under x64.
    """
    _check_inputs(mesh, cameras)
    if isinstance(channels, str):
        channels = (channels,)
    channels = tuple(channels)
    if not channels:
        raise ValueError("channels must name at least one channel")
    for c in channels:
        if c not in CHANNEL_SIZES:
            raise ValueError(f"channels: unknown channel {c!r}; choose from {tuple(CHANNEL_SIZES)}")
    if len(set(channels)) != len(channels):
        raise ValueError(f"channels must not repeat, got {channels}")
    sigma = _check_scalar("sigma", sigma)
    gamma = _check_scalar("gamma", gamma)
    znear = _check_scalar("znear", znear)
    ambient = float(ambient)
    if not 0.0 <= ambient <= 1.0:
        raise ValueError(f"ambient must be in [0, 1], got {ambient}")
    bg = dict(_BLEND_DEFAULT)
    if background is not None:
        if not isinstance(background, dict):
            raise ValueError("background must be a dict {channel: value}")
        for k, val in background.items():
            if k not in bg:
                raise ValueError(f"background: no configurable background for channel {k!r}")
            val = tuple(float(x) for x in np.atleast_1d(np.asarray(val, dtype=float)))
            if len(val) != len(bg[k]):
                raise ValueError(f"background[{k!r}] must have {len(bg[k])} values, got {len(val)}")
            bg[k] = val
    if light_direction is not None:
        ld = np.asarray(light_direction, dtype=float)
        if ld.shape != (3,) or not np.linalg.norm(ld) > 0:
            raise ValueError("light_direction must be a non-zero 3-vector")
    if plan is None:
        plan = _default_plan(mesh, cameras, sigma, znear, cull_backfaces)
    elif not isinstance(plan, RasterPlan):
        raise ValueError(f"plan must be a RasterPlan, got {type(plan).__name__}")

    light = None if light_direction is None else tuple(float(x) for x in np.asarray(light_direction).ravel())
    return _render_jit(
        mesh, cameras, plan, channels=channels, sigma=sigma, gamma=gamma, znear=znear, cull=bool(cull_backfaces),
        light=light, ambient=ambient, bg=tuple(sorted(bg.items())), return_info=bool(return_info),
    )


@functools.partial(
    jax.jit, static_argnames=("channels", "sigma", "gamma", "znear", "cull", "light", "ambient", "bg", "return_info")
)
def _render_jit(mesh, cameras, plan, *, channels, sigma, gamma, znear, cull, light, ambient, bg, return_info):
    bg = dict(bg)
    attrs = tuple(c for c in ("normal", "shaded") if c in channels)
    want_depth = "depth" in channels
    fs = _face_setup(
        mesh, cameras, sigma=sigma, znear=znear, cull=cull, attrs=attrs,
        light=light, ambient=ambient,
    )

    n_faces = mesh.face_capacity
    two = plan.max_big_faces > 0
    small = fs.valid & (fs.extent <= plan.window) if two else fs.valid
    groups = [(small, plan.window, min(plan.max_faces, n_faces))]
    if two:
        groups.append((fs.valid & ~small, plan.big_window, min(plan.max_big_faces, n_faces)))
    tiers, windows = [], []
    dropped = jnp.zeros(fs.valid.shape[0], jnp.int32)
    truncated = jnp.zeros(fs.valid.shape[0], jnp.int32)
    for mask, b, k in groups:
        idx, slot, count = _compact(mask, k)
        dropped = dropped + jnp.maximum(count - k, 0).astype(jnp.int32)
        truncated = truncated + jnp.sum(slot & (_gather(fs.extent, idx) > b), axis=1).astype(jnp.int32)
        tiers.append(
            Tier(
                _gather(fs.v, idx), _gather(fs.plane, idx), _gather(fs.qrange, idx),
                _gather(fs.attr, idx), _gather(fs.logw, idx), slot, _gather(fs.origin, idx),
            )
        )
        windows.append(b)
    background_blend = sum((bg[c] for c in attrs), ()) + (bg["depth"] if want_depth else ())
    cfg = SplatConfig(
        height=cameras.height, width=cameras.width, windows=tuple(windows), sigma=sigma, gamma=gamma,
        want_cov=True, n_attr=sum(CHANNEL_SIZES[c] for c in attrs), want_depth=want_depth,
        background=background_blend,
    )
    cov, blend = splat(cfg, tuple(tiers), fs.dconst)

    offsets, o = {}, 0
    for c in attrs + (("depth",) if want_depth else ()):
        offsets[c] = o
        o += CHANNEL_SIZES[c]
    # blend channels are composited over their background with the coverage, so a
    # face's faint outer tail (which wins the depth softmax against the background)
    # fades in with its coverage instead of switching the pixel at the blur cutoff
    alpha = jnp.minimum(cov, 1.0)[..., None]
    out = []
    for c in channels:
        if c == "alpha":
            out.append(alpha)
        else:
            val = blend[..., offsets[c] : offsets[c] + CHANNEL_SIZES[c]]
            out.append(alpha * val + (1.0 - alpha) * jnp.asarray(bg[c], val.dtype))
    images = jnp.concatenate(out, axis=-1)
    if return_info:
        info = RenderInfo(jnp.sum(fs.valid, axis=1).astype(jnp.int32), truncated, dropped)
        return images, info
    return images


