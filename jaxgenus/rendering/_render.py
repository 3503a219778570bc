"""`render`: differentiable soft rasterizer (silhouette, normal, depth, shaded channels).

The per-face set-up (projection, culling, depth planes, attributes) is plain JAX
and is differentiated by autodiff; the per-pixel work is the face-major splat of
`_splat.py` with its hand-written VJP. See docs/rendering.md.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh, settings_repr
from jaxgenus.rendering._faces import Faces, check_inputs, check_scalar, face_setup
from jaxgenus.rendering._sharded import per_device, view_sharding
from jaxgenus.rendering._plan import RasterPlan, plan_render, static_plan
from jaxgenus.rendering._splat import SplatConfig, Tier, splat
from jaxgenus.rendering._splat_native import splat_all

__all__ = ["render", "RenderInfo", "RenderSettings", "CHANNEL_SIZES", "SHADINGS"]

#: Number of image channels each requested channel contributes, in request order.
CHANNEL_SIZES = {"alpha": 1, "normal": 3, "depth": 1, "shaded": 1, "color": 3, "values": 3}
#: The shadings of a photo render: colours constant per face, or per vertex and interpolated (`render_photo`).
SHADINGS = ("flat", "smooth")
_BLEND_DEFAULT = {"normal": (0.0, 0.0, 0.0), "depth": (0.0,), "shaded": (0.0,), "color": (0.0, 0.0, 0.0),
                  "values": (0.0, 0.0, 0.0)}


@dataclasses.dataclass(frozen=True, repr=False)
class RenderSettings:
    """The renderer's settings an optimizer or a verdict passes to `render` (immutable, hashable).

    Attributes:
        sigma: edge blur in pixels (see `render`).
        gamma: depth softmax temperature.
        plan: the JAX splat's `RasterPlan` (None: the native kernel on CPU, else planned per call).
        shading: photos: `"flat"` (a colour per face) or `"smooth"` (per vertex, interpolated
            over the faces); `jaxgenus.render_photo`. Not a keyword of `render` (`kwargs`).
    """

    def __repr__(self) -> str:
        return settings_repr(self)


    sigma: float = 0.1
    gamma: float = 0.01
    plan: RasterPlan | None = None
    shading: str = "flat"

    def __post_init__(self):
        for name in ("sigma", "gamma"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"render settings: {name} must be a positive number, got {v!r}")
        if self.shading not in SHADINGS:
            raise ValueError(f"render settings: shading must be one of {SHADINGS}, got {self.shading!r}")
        if self.plan is not None and not isinstance(self.plan, RasterPlan):
            raise ValueError(f"render settings: plan must be a RasterPlan or None, got {type(self.plan).__name__}")

    def kwargs(self) -> dict:
        """Keyword arguments of `render`."""
        return {"sigma": self.sigma, "gamma": self.gamma, "plan": self.plan}


class RenderInfo(eqx.Module):
    """Coverage counters of one `render` call (per view, int32 arrays)."""

    n_visible: Int[Array, "N"]
    n_truncated: Int[Array, "N"]
    n_dropped: Int[Array, "N"]

    @property
    def n_overflow(self) -> Array:
        """Total number of faces rendered incompletely (truncated + dropped), all views."""
        return jnp.sum(self.n_truncated) + jnp.sum(self.n_dropped)


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


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _default_plan(mesh, cameras, sigma, znear, cull):
    if not (_is_traced(mesh.vertices) or _is_traced(cameras.rotation) or _is_traced(cameras.translation)):
        return plan_render(mesh, cameras, sigma=sigma, znear=znear, cull_backfaces=cull)
    return static_plan(mesh.face_capacity, cameras.height, cameras.width, sigma)


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
    face_colors=None,
    vertex_colors=None,
    vertex_values=None,
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
    * `"color"` (3): the per-face RGB `face_colors`, or the per-vertex RGB `vertex_colors`
      interpolated over each face (affine in the pixel, clamped to the corners' range),
      blended the same way (a photo's shading, see `jaxgenus.render_photo`).
    * `"values"` (3): the per-vertex `vertex_values` interpolated over each face as
      `vertex_colors` are, beside `"color"` in the same pass (one rasterization for both;
      such as the irradiance of a photo's shading next to its colour).

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
        face_colors: `(face capacity, 3)` RGB per face for `"color"` (differentiable).
        vertex_colors: `(vertex capacity, 3)` RGB per vertex for `"color"`, instead of
            `face_colors` (differentiable in the colours and the vertices).
        vertex_values: `(vertex capacity, 3)` per-vertex values for `"values"`.
        plan: None (default): on CPU the native kernel (`_splat_native`, C++ behind
            the XLA FFI) renders every face exactly, with no windows or budgets, under
            `jit` or not; on other platforms the JAX splat runs with a plan from the
            geometry (concrete inputs) or from static sizes (`static_plan`, traced),
            its overflow counted in `RenderInfo`. A given `RasterPlan` always runs
            the JAX splat with it.
        return_info: also return a `RenderInfo` with overflow counts.

    Only the requested channels are computed. jit/vmap friendly; float64 under x64.
    Cameras whose arrays are sharded over devices along the view axis (a `NamedSharding`
    of their leading axis; traced ones under explicit sharding) are rendered per device,
    each device its own views, and the images come back sharded the same way.
    """
    check_inputs(mesh, cameras)
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
    sigma = check_scalar("sigma", sigma)
    gamma = check_scalar("gamma", gamma)
    znear = check_scalar("znear", znear)
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
    if face_colors is not None and vertex_colors is not None:
        raise ValueError("give face_colors or vertex_colors, not both")
    if ("color" in channels) != (face_colors is not None or vertex_colors is not None):
        raise ValueError("face_colors or vertex_colors must be given exactly when channels has 'color'")
    if face_colors is not None:
        face_colors = jnp.asarray(face_colors)
        if face_colors.shape != (mesh.face_capacity, 3):
            raise ValueError(f"face_colors must have shape (face capacity {mesh.face_capacity}, 3), got {face_colors.shape}")
    if vertex_colors is not None:
        vertex_colors = jnp.asarray(vertex_colors)
        if vertex_colors.shape != (mesh.vertex_capacity, 3):
            raise ValueError(f"vertex_colors must have shape (vertex capacity {mesh.vertex_capacity}, 3), "
                             f"got {vertex_colors.shape}")
        face_colors = vertex_colors  # one traced argument; `smooth` tells them apart
    if ("values" in channels) != (vertex_values is not None):
        raise ValueError("vertex_values must be given exactly when channels has 'values'")
    if vertex_values is not None:
        vertex_values = jnp.asarray(vertex_values)
        if vertex_values.shape != (mesh.vertex_capacity, 3):
            raise ValueError(f"vertex_values must have shape (vertex capacity {mesh.vertex_capacity}, 3), "
                             f"got {vertex_values.shape}")
    native = plan is None
    if plan is None:
        # the plan of the JAX splat, used only where the native kernel is not (GPU):
        # from the geometry when it is concrete, else from static sizes
        if jax.default_backend() == "cpu":
            plan = static_plan(mesh.face_capacity, cameras.height, cameras.width, sigma)
        else:
            plan = _default_plan(mesh, cameras, sigma, znear, cull_backfaces)
    elif not isinstance(plan, RasterPlan):
        raise ValueError(f"plan must be a RasterPlan, got {type(plan).__name__}")

    light = None if light_direction is None else tuple(float(x) for x in np.asarray(light_direction).ravel())
    static = dict(channels=channels, sigma=sigma, gamma=gamma, znear=znear, cull=bool(cull_backfaces), light=light,
                  ambient=ambient, bg=tuple(sorted(bg.items())), return_info=bool(return_info), native=native,
                  smooth=vertex_colors is not None)
    colors = (face_colors, vertex_values)
    where = view_sharding(cameras.rotation)
    if where is not None:  # views split over devices: each renders its own (module `_sharded`)
        return per_device(lambda m, fc, c: _render_jit(m, c, plan, fc, **static), where, len(cameras),
                          replicated=(mesh, colors), split=(cameras,), out_split=True)
    return _render_jit(mesh, cameras, plan, colors, **static)


def _splat_windows(fs: Faces, plan: RasterPlan, n_faces: int, cfg: SplatConfig):
    """The JAX splat over the plan's tiers: `(cov, blend, truncated, dropped)`."""
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
    cov, blend = splat(cfg._replace(windows=tuple(windows)), tuple(tiers), fs.dconst)
    return cov, blend, truncated, dropped


def _splat_native(fs: Faces, cfg: SplatConfig):
    """The native CPU kernel over every face (no windows, nothing truncated or dropped)."""
    faces = Tier(fs.v, fs.plane, fs.qrange, fs.attr, fs.logw, fs.valid, None)
    cov, blend = splat_all(cfg, faces, fs.dconst)
    zero = jnp.zeros(fs.valid.shape[0], jnp.int32)
    return cov, blend, zero, zero


@functools.partial(
    jax.jit,
    static_argnames=("channels", "sigma", "gamma", "znear", "cull", "light", "ambient", "bg", "return_info", "native",
                     "smooth"),
)
def _render_jit(mesh, cameras, plan, colors, *, channels, sigma, gamma, znear, cull, light, ambient, bg, return_info,
                native, smooth):
    bg = dict(bg)
    attrs = tuple(c for c in ("normal", "shaded", "color", "values") if c in channels)
    want_depth = "depth" in channels
    colors, values = colors
    fs = face_setup(
        mesh, cameras, sigma=sigma, znear=znear, cull=cull, attrs=attrs,
        light=light, ambient=ambient, face_colors=None if smooth else colors, vertex_colors=colors if smooth else None,
        vertex_values=values,
    )
    cfg = SplatConfig(
        height=cameras.height, width=cameras.width, windows=(), sigma=sigma, gamma=gamma,
        want_cov=True, n_attr=sum(CHANNEL_SIZES[c] for c in attrs), want_depth=want_depth,
        background=sum((bg[c] for c in attrs), ()) + (bg["depth"] if want_depth else ()),
        attr_planes=smooth or values is not None,
    )
    windows = lambda f: _splat_windows(f, plan, mesh.face_capacity, cfg)
    if native:  # no plan given: the native kernel on CPU, the JAX splat with `plan` elsewhere
        cov, blend, truncated, dropped = jax.lax.platform_dependent(
            fs, cpu=lambda f: _splat_native(f, cfg), default=windows
        )
    else:
        cov, blend, truncated, dropped = windows(fs)

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


