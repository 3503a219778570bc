"""Depth from the photos alone (a plane sweep), and the free space it shows.

The visual hull keeps every concavity no silhouette shows: a courtyard, the space between the
wings of a building. A textured photo shows more. `stereo_depths` sweeps, for every view, depth
planes through the object's bounds: at each plane its neighbours' photos are warped onto its
pixels and compared with it by zero-mean normalized cross-correlation over small windows (gain
and offset between views do not matter). A pixel takes the depth where the mean of its best two
neighbours' NCC peaks (one neighbour may not see the point), refined by a parabola; it is kept
when that peak is high and the window has texture. `consistent_depths` then keeps only the depths
another view confirms (its own depth at the projection agrees). `carved_occupancy` removes from
the visual hull's occupancy grid the cells that lie in front of confirmed depths, by a margin,
in at least two views: space the photos show to be empty. The fit then starts from a surface
that has the concavities and refines it; the photo-consistency term of the fit only sees a pixel
or two around the surface, far less than a courtyard is deep.

Wide-baseline matching, as in the plane-sweep stereo of multi-view stereo pipelines (Collins
1996; the photo-consistency filtering of COLMAP and OpenMVS), written here for the start.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgenus.capture._hull import HullOccupancy
from jaxgenus.geometry import Cameras

_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)

__all__ = ["StereoDepths", "carved_occupancy", "consistent_depths", "stereo_depths"]

#: A pixel's depth is kept when the mean NCC of its best two neighbours peaks at least this high.
MIN_NCC = 0.6
_MIN_STD = 0.03  # windows whose grey level varies less carry no texture
_LUMA = np.array([0.299, 0.587, 0.114])


class StereoDepths(NamedTuple):
    """Per view `(N, H, W)`: `depth` along the optical axis (NaN where none was found or kept) and
    `score`, the NCC at that depth (mean of the best two neighbours)."""

    depth: np.ndarray
    score: np.ndarray


def _box(x, r: int):
    """Sums of `x (..., H, W)` over `(2r+1)^2` windows (zero outside): separable sums of shifted
    slices (on a CPU 4x faster than running sums, and without their float32 cancellation)."""
    h, w = x.shape[-2:]
    lead = [(0, 0)] * (x.ndim - 2)
    p = jnp.pad(x, lead + [(0, 0), (r, r)])
    rows = sum(p[..., i:i + w] for i in range(2 * r + 1))
    p = jnp.pad(rows, lead + [(r, r), (0, 0)])
    return sum(p[..., i:i + h, :] for i in range(2 * r + 1))


def _best_two_mean(scores):
    """The mean of the two highest of `scores (K, H, W)` along K (the highest alone for K = 1): a max
    and a masked max, on a CPU 17x faster than sorting K."""
    top = scores.max(0)
    if len(scores) == 1:
        return top
    first = jnp.argmax(scores, 0)
    second = jnp.where(jnp.arange(len(scores))[:, None, None] == first[None], -jnp.inf, scores).max(0)
    return 0.5 * (top + second)


def _sample(img, u, v):
    """Bilinear samples of `img (h, w)` at continuous pixel positions (centres at +0.5); 0 outside."""
    h, w = img.shape
    x, y = u - 0.5, v - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(jnp.int32), y0.astype(jnp.int32)

    def at(r, c):
        ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        return jnp.where(ok, img[jnp.clip(r, 0, h - 1), jnp.clip(c, 0, w - 1)], 0.0)

    return ((1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1))
            + fy * ((1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)))


def _ncc(a, b, m, r: int):
    """Windowed zero-mean NCC of `a` and `b` over the pixels `m` (1/0); -1 where a window has under
    3/4 of its pixels or no texture in either image."""
    n = _box(m, r)
    sa, sb = _box(m * a, r), _box(m * b, r)
    safe = jnp.maximum(n, 1.0)
    va = _box(m * a * a, r) - sa * sa / safe
    vb = _box(m * b * b, r) - sb * sb / safe
    cov = _box(m * a * b, r) - sa * sb / safe
    ok = (n >= 0.75 * (2 * r + 1) ** 2) & (va >= safe * _MIN_STD**2) & (vb >= safe * (0.5 * _MIN_STD) ** 2)
    return jnp.where(ok, cov / jnp.sqrt(jnp.maximum(va * vb, 1e-12)), -1.0)


@jax.jit
def _sweep(ref, ref_mask, nbs, nb_masks, rays, to_nb, inv_depths, r_win=3):
    """Scores `(D, H, W)` of one view: per inverse depth of `inv_depths (D,)`, the mean NCC of the
    best two neighbours. `rays (H, W, 3)`: pixel rays in the view's camera (z = 1); `to_nb`:
    `(K, 3, 4)` maps from the view's camera coordinates to each neighbour's pixels (homogeneous)."""

    def plane(inv_d):
        x = jnp.concatenate([rays / inv_d, jnp.ones_like(rays[..., :1])], -1)  # (H, W, 4)
        p = jnp.einsum("kij,hwj->khwi", to_nb, x, precision=_HI)
        z = p[..., 2]
        front = z > 1e-9
        u, v = p[..., 0] / jnp.where(front, z, 1.0), p[..., 1] / jnp.where(front, z, 1.0)
        warped = jax.vmap(_sample)(nbs, u, v)
        seen = jax.vmap(_sample)(nb_masks, u, v)
        m = ref_mask[None] * (front & (seen > 0.5))
        return _best_two_mean(jax.vmap(lambda b, mm: _ncc(ref, b, mm, r_win))(warped, m))  # of (K, H, W)

    return jax.lax.map(plane, inv_depths)


def _grey(photos) -> np.ndarray:
    """Straight (not premultiplied) grey levels and masks of RGBA photos `(N, H, W, 4)`."""
    p = np.asarray(photos, np.float32)
    a = p[..., 3]
    return (p[..., :3] @ _LUMA.astype(np.float32)) / np.maximum(a, 1e-3), (a >= 0.5).astype(np.float32)


def stereo_depths(photos, cams: Cameras, neighbours, bounds, *, planes: int = 64) -> StereoDepths:
    """Plane-sweep depths of every view (module doc).

    Args:
        photos: `(N, H, W, 4)` RGBA, premultiplied by the mask (as `check_targets` returns them).
        cams: their cameras (any frame).
        neighbours: `(N, K)` view indices to compare each view with (`view_neighbours`; a view's
            own index is skipped).
        bounds: `(lo, hi)` a box holding the object: each view sweeps the depths it spans.
        planes: depth planes per view, evenly spaced in inverse depth.
    """
    grey, mask = _grey(photos)
    n, h, w = grey.shape
    table = np.asarray(neighbours)
    if table.ndim != 2 or len(table) != n:
        raise ValueError(f"neighbours: expected ({n}, K) view indices, got shape {table.shape}")
    rot, t = np.asarray(cams.rotation, np.float64), np.asarray(cams.translation, np.float64)
    f, pp = np.asarray(cams.focal, np.float64), np.asarray(cams.principal_point, np.float64)
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, 3)
    vv, uu = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    depth, score = np.full((n, h, w), np.nan, np.float32), np.full((n, h, w), -1.0, np.float32)
    for i in range(n):
        nb = np.array([j for j in dict.fromkeys(table[i].tolist()) if j != i])
        z = corners @ rot[i, 2] + t[i, 2]
        if len(nb) == 0 or z.max() <= 0 or mask[i].sum() == 0:
            continue
        near, far = max(z.min(), 1e-3 * z.max()), z.max()
        inv = np.linspace(1.0 / near, 1.0 / far, planes)
        rays = np.stack([(uu - pp[i, 0]) / f[i, 0], (vv - pp[i, 1]) / f[i, 1], np.ones_like(uu)], -1)
        world = np.concatenate([rot[i].T, (-rot[i].T @ t[i])[:, None]], 1)  # camera i -> world, (3, 4)
        world = np.concatenate([world, [[0, 0, 0, 1]]], 0)
        intr = np.zeros((len(nb), 3, 3))
        intr[:, 0, 0], intr[:, 1, 1], intr[:, :2, 2], intr[:, 2, 2] = f[nb, 0], f[nb, 1], pp[nb], 1.0
        to_nb = intr @ np.concatenate([rot[nb], t[nb, :, None]], 2) @ world  # (K, 3, 4)
        s = np.asarray(_sweep(jnp.asarray(grey[i]), jnp.asarray(mask[i]), jnp.asarray(grey[nb]), jnp.asarray(mask[nb]),
                              jnp.asarray(rays, jnp.float32), jnp.asarray(to_nb, jnp.float32),
                              jnp.asarray(inv, jnp.float32)))
        k = np.argmax(s, 0)
        best = np.take_along_axis(s, k[None], 0)[0]
        a = np.take_along_axis(s, np.clip(k - 1, 0, planes - 1)[None], 0)[0]
        b = np.take_along_axis(s, np.clip(k + 1, 0, planes - 1)[None], 0)[0]
        curve = a - 2 * best + b
        shift = np.where((k > 0) & (k < planes - 1) & (curve < 0), np.clip(0.5 * (a - b) / np.where(curve < 0, curve, -1), -0.5, 0.5), 0.0)
        inv_k = np.interp(k + shift, np.arange(planes), inv)
        keep = (best >= MIN_NCC) & (mask[i] > 0) & (k > 0) & (k < planes - 1)
        depth[i] = np.where(keep, 1.0 / inv_k, np.nan)
        score[i] = best
    return StereoDepths(depth, score)


def _project(rot, t, f, pp, x):
    """Pixels `(u, v)` and depths of world points `x (P, 3)` in one camera."""
    y = x @ rot.T + t
    z = np.where(y[:, 2] > 1e-9, y[:, 2], np.nan)
    return f[0] * y[:, 0] / z + pp[0], f[1] * y[:, 1] / z + pp[1], z


def _points(depth, rot, t, f, pp):
    """World points of a depth map's pixels `(H*W, 3)` (NaN where the depth is)."""
    h, w = depth.shape
    vv, uu = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    cam = np.stack([(uu - pp[0]) / f[0], (vv - pp[1]) / f[1], np.ones_like(uu)], -1) * depth[..., None]
    return (cam.reshape(-1, 3) - t) @ rot


def consistent_depths(sd: StereoDepths, cams: Cameras, neighbours, *, tolerance: float = 0.01) -> StereoDepths:
    """`sd` with the depths no other view confirms set to NaN: a depth is kept when, in one of the
    view's `neighbours` at least, the point projects onto a depth within `tolerance` (relative)."""
    rot, t = np.asarray(cams.rotation, np.float64), np.asarray(cams.translation, np.float64)
    f, pp = np.asarray(cams.focal, np.float64), np.asarray(cams.principal_point, np.float64)
    n, h, w = sd.depth.shape
    out = np.full_like(sd.depth, np.nan)
    for i in range(n):
        x = _points(sd.depth[i].astype(np.float64), rot[i], t[i], f[i], pp[i])
        ok = np.zeros(len(x), bool)
        for j in dict.fromkeys(np.asarray(neighbours)[i].tolist()):
            if j == i:
                continue
            u, v, z = _project(rot[j], t[j], f[j], pp[j], x)
            inside = np.isfinite(z) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            d = np.full(len(x), np.nan)
            d[inside] = sd.depth[j][v[inside].astype(int), u[inside].astype(int)]
            with np.errstate(invalid="ignore"):
                ok |= np.abs(d - z) <= tolerance * z
        out[i] = np.where(ok.reshape(h, w), sd.depth[i], np.nan)
    return StereoDepths(out, sd.score)


def carved_occupancy(occupancy: HullOccupancy, sd: StereoDepths, cams: Cameras, *, margin: float,
                     votes: int = 2) -> tuple[HullOccupancy, float]:
    """The occupancy with the cells emptied that lie in front of a depth of `sd` by more than
    `margin` (world units along the ray) in at least `votes` views; and the share of the occupied
    cells (occupancy >= 0.5) it emptied."""
    vals = np.array(occupancy.values, np.float64)
    shape = vals.shape
    axes = [occupancy.lo[d] + occupancy.cell * np.arange(shape[d]) for d in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = vals.ravel() >= 0.5
    pts = grid[inside]
    rot, t = np.asarray(cams.rotation, np.float64), np.asarray(cams.translation, np.float64)
    f, pp = np.asarray(cams.focal, np.float64), np.asarray(cams.principal_point, np.float64)
    n, h, w = sd.depth.shape
    count = np.zeros(len(pts), np.int32)
    for i in range(n):
        u, v, z = _project(rot[i], t[i], f[i], pp[i], pts)
        ok = np.isfinite(z) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        d = np.full(len(pts), np.nan)
        d[ok] = sd.depth[i][v[ok].astype(int), u[ok].astype(int)]
        with np.errstate(invalid="ignore"):
            count += z < d - margin
    empty = np.zeros(vals.size, bool)
    empty[np.flatnonzero(inside)[count >= votes]] = True
    vals = np.where(empty.reshape(shape), 0.0, vals)
    return occupancy._replace(values=vals), float(empty.sum() / max(inside.sum(), 1))
