"""`RasterPlan`: static window sizes and face budgets of the JAX splat, from the
geometry (`plan_render`) or from static sizes only (`static_plan`)."""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.rendering._faces import blur_radius, check_inputs, check_scalar, face_setup
from jaxgenus.geometry import Mesh

__all__ = ["RasterPlan", "plan_render", "static_plan"]

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


@functools.partial(jax.jit, static_argnames=("sigma", "znear", "cull"))
def _visible_extents(mesh, cameras, *, sigma, znear, cull):
    fs = face_setup(mesh, cameras, sigma=sigma, znear=znear, cull=cull, attrs=(), light=None, ambient=0.0)
    return fs.valid, fs.extent


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
    check_inputs(mesh, cameras)
    sigma = check_scalar("sigma", sigma)
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


def static_plan(face_capacity: int, height: int, width: int, sigma: float = 0.1) -> RasterPlan:
    """A `RasterPlan` from static information only (face capacity, image size), for
    rendering traced geometry without a plan on the JAX splat path.

    The small window fits a face of the typical size of a mesh of `face_capacity`
    faces whose visible half fills half the image (bounding box about
    `2 sqrt(H W / F)` pixels) plus the blur; every face slot may use it. Larger
    faces go to a window four times as large, with a budget that lets them cover
    the image 8 times over. Faces beyond are truncated or dropped and counted in
    `RenderInfo` (`n_overflow`), never silently.
    """
    f = max(int(face_capacity), 1)
    r = blur_radius(check_scalar("sigma", sigma))
    typical = 2.0 * math.sqrt(height * width / f)
    window = _bucket(int(math.ceil(typical + 2.0 * r + 1.0)))
    big = min(_bucket(4 * window), _bucket(max(height, width) + int(math.ceil(2.0 * r)) + 1))
    if big <= window:
        return RasterPlan(window=window, max_faces=f)
    max_big = int(min(f, math.ceil(8.0 * height * width / big**2)))
    return RasterPlan(window=window, max_faces=f, big_window=big, max_big_faces=max_big)
