"""Multi-view photo-consistency through the rendered depth (photo targets).

For a reference view and a neighbour, every reference pixel the mesh covers is
back-projected with the mesh's rendered depth, projected into the neighbour, and
the neighbour's photo is sampled there (bilinear). Where the surface is right,
the sampled image equals the reference photo up to exposure; where it is wrong,
the neighbour's texture lands shifted. The two are compared by zero-mean
normalized cross-correlation (NCC) over small windows, which ignores gain and
offset between the views (exposure, white balance, a light that brightens one
view). The gradient reaches the vertices through the depth (the soft
rasterizer's blended depth) and the sampling positions; pixels that the
neighbour does not see (its own depth render, held constant, is nearer), that
leave its image or its mask, that lie next to an occluding contour inside the
silhouette (a step in the depth), and windows without texture (std below
`MIN_STD`) count for nothing. Textureless parts are left to the silhouette and
shading terms. A window costs `robust_cost` of its residual `1 - NCC`:
the residual while it is small next to the median residual, bounded where it is
not, so the few windows that cannot match even on the true surface do not shake
it (docs/photometric.md). This is the mesh-refinement idea of Vu et al. 2012 and
Delaunoy & Pollefeys 2014, written here for the soft rasterizer.

`view_neighbours` picks, for every view, the views that see much of what it sees
from 5 to 40 degrees away (the baselines NCC works on), the nearest to 20 degrees
first, filled up with the nearest up to 60 degrees where fewer lie there (sparse rings);
a step samples one of them per reference view. `stereo_depth_cost` compares
the rendered depth with depths found by plane-sweep stereo of the photos alone
(`jaxgenus.capture.stereo_depths`), whose basin is as wide as the sweep.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxgenus.geometry import Cameras
from jaxgenus.optim._pyramid import scaled_cameras, window_reduce

_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)

__all__ = ["MIN_STD", "ROBUST_SPREAD", "STEREO_SCALE", "consistency_windows", "photo_consistency", "robust_cost",
           "stereo_depth_cost", "view_neighbours"]

#: Windows whose reference photo varies less than this (std of the grey level in [0, 1]) carry no texture.
MIN_STD = 0.03
_LUMA = (0.299, 0.587, 0.114)
_OCCLUSION = 0.015  # relative depth tolerance of the visibility test
_COVER = 0.99  # pixels whose rendered coverage is below this sit on a contour: their depth is blended
# Inside the silhouette, an occluding contour blends the depths of the near and the far surface: moving
# it sideways changes the blended depth, so NCC there would push limbs sideways, where no silhouette
# holds them. Pixels next to a depth step this large
# (relative) are left out (docs/results.md, "Occluding contours").
_DEPTH_STEP = 0.02
#: The scale of `robust_cost`: this many times the median window residual.
ROBUST_SPREAD = 2.0
_MIN_SCALE = 1e-3
#: The scale of `stereo_depth_cost`: relative depth differences well below it pull as their squares, larger
#: ones are bounded (a wrong stereo match costs little). 0.04 of the depth (about 14 px at 256^2 and a
#: 40 degree field) reaches the floor of a concavity the visual hull spans; 0.02 held the fit off the
#: skull's eye sockets (docs/results.md, "A heavier stereo term").
STEREO_SCALE = 0.04
_OVERLAP_POINTS = 2000  # `view_neighbours` measures overlaps on at most this many points


def view_neighbours(cameras: Cameras, centre=(0.0, 0.0, 0.0), *, points=None, count: int = 4,
                    min_angle: float = 5.0, max_angle: float = 40.0, best_angle: float = 20.0,
                    min_overlap: float = 0.3) -> np.ndarray:
    """`(N, count)` int32: per view, the views that see much of what it sees from `min_angle` to
    `max_angle` degrees away, nearest to `best_angle` first. A view with fewer there (sparse rings:
    24 views of a sphere lie about 40 degrees apart) fills up with its nearest views within 1.5 x
    `max_angle`; rows that still have fewer repeat the best, and a view with none at all holds its
    own index (a pair with itself carries no signal).

    What a view sees is the part of `points` (`(M, 3)`, e.g. the visual hull's vertices; default:
    `centre` alone) in front of it and inside its image; a pair needs `min_overlap` of it inside
    the other view too, and its angle is measured at the centre of that part, with the distances
    to it within 2x. An object cut by the frames (each view sees a part of a building) pairs views
    that share a part, where the object's centre is in few of the images."""
    if not isinstance(cameras, Cameras):
        raise ValueError(f"cameras must be Cameras, got {type(cameras).__name__}")
    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count must be an int >= 1, got {count!r}")
    if not 0.0 <= min_angle < max_angle <= 180.0:
        raise ValueError(f"need 0 <= min_angle < max_angle <= 180, got {min_angle}, {max_angle}")
    if not 0.0 < min_overlap <= 1.0:
        raise ValueError(f"min_overlap must be in (0, 1], got {min_overlap!r}")
    pts = np.asarray(centre if points is None else points, np.float64).reshape(-1, 3)
    if len(pts) == 0 or not np.isfinite(pts).all():
        raise ValueError(f"points: expected finite (M, 3) points, M >= 1, got shape {pts.shape}")
    pts = pts[np.random.default_rng(0).permutation(len(pts))[:_OVERLAP_POINTS]] if len(pts) > _OVERLAP_POINTS else pts
    rot, t = np.asarray(cameras.rotation, np.float64), np.asarray(cameras.translation, np.float64)
    centres = -np.einsum("nji,nj->ni", rot, t)
    pc = np.einsum("nij,mj->nmi", rot, pts) + t[:, None]  # (N, M, 3): the points in each camera
    f, pp = np.asarray(cameras.focal, np.float64), np.asarray(cameras.principal_point, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = f[:, None] * pc[..., :2] / pc[..., 2:3] + pp[:, None]
    sees = ((pc[..., 2] > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= cameras.width) & (uv[..., 1] >= 0)
            & (uv[..., 1] <= cameras.height)).astype(np.float64)  # (N, M)
    seen_count = sees.sum(1)
    overlap = (sees @ sees.T) / np.maximum(seen_count[:, None], 1.0)  # share of what i sees that j sees too
    middle = (sees @ pts) / np.maximum(seen_count[:, None], 1.0)  # the centre of what each view sees
    to_i = centres - middle  # (N, 3)
    to_j = centres[None, :, :] - middle[:, None, :]  # (N, N, 3): view j from view i's centre
    dist_i, dist_j = np.linalg.norm(to_i, axis=1), np.linalg.norm(to_j, axis=2)
    if not np.all(dist_j > 0):
        raise ValueError("cameras: a camera sits at the centre of what a view sees")
    cos = np.einsum("ni,nji->nj", to_i / dist_i[:, None], to_j / dist_j[..., None])
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    ratio = dist_i[:, None] / dist_j
    seen = ((overlap >= min_overlap) & (seen_count[:, None] > 0) & (ratio <= 2.0) & (ratio >= 0.5)
            & (angle >= min_angle))
    ok = seen & (angle <= max_angle)
    wide = seen & (angle <= 1.5 * max_angle)
    np.fill_diagonal(ok, False)
    np.fill_diagonal(wide, False)
    out = np.empty((len(cameras), count), np.int32)
    for i in range(len(cameras)):
        cand = np.flatnonzero(ok[i])
        cand = cand[np.argsort(np.abs(angle[i, cand] - best_angle), kind="stable")][:count]
        if len(cand) < count:  # the nearest of the wider ones after them
            more = np.flatnonzero(wide[i] & ~ok[i])
            cand = np.concatenate([cand, more[np.argsort(angle[i, more], kind="stable")][:count - len(cand)]])
        out[i] = np.resize(cand, count) if len(cand) else i
    return out


def _grey(rgb):
    return rgb[..., 0] * _LUMA[0] + rgb[..., 1] * _LUMA[1] + rgb[..., 2] * _LUMA[2]


def _bilinear(img, u, v):
    """`img (H, W, C)` at continuous pixel coordinates `(u, v)` (pixel centres at +0.5), clamped."""
    h, w = img.shape[:2]
    x, y = u - 0.5, v - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0i = jnp.clip(x0.astype(jnp.int32), 0, w - 1)
    y0i = jnp.clip(y0.astype(jnp.int32), 0, h - 1)
    x1i, y1i = jnp.minimum(x0i + 1, w - 1), jnp.minimum(y0i + 1, h - 1)
    top = img[y0i, x0i] * (1 - fx) + img[y0i, x1i] * fx
    bottom = img[y1i, x0i] * (1 - fx) + img[y1i, x1i] * fx
    return top * (1 - fy) + bottom * fy


def _warp_one(depth, covered, ref_cam, ref_img, nb_cam, nb_img, nb_depth):
    """One pair: the reference image's channels `(H, W, C)`, the neighbour's warped onto the reference
    pixels through `depth`, and where that warp is valid (the images' last channel is the mask)."""
    h, w = depth.shape
    rot, t, f, pp = ref_cam
    v, u = jnp.meshgrid(jnp.arange(h, dtype=depth.dtype) + 0.5, jnp.arange(w, dtype=depth.dtype) + 0.5, indexing="ij")
    ray = jnp.stack([(u - pp[0]) / f[0], (v - pp[1]) / f[1], jnp.ones_like(u)], -1)
    x_cam = ray * depth[..., None]
    x_world = jnp.einsum("ji,hwj->hwi", rot, x_cam - t, precision=_HI)
    nrot, nt, nf, npp = nb_cam
    y = jnp.einsum("ij,hwj->hwi", nrot, x_world, precision=_HI) + nt
    z = y[..., 2]
    safe_z = jnp.where(z > 1e-6, z, 1.0)
    un = nf[0] * y[..., 0] / safe_z + npp[0]
    vn = nf[1] * y[..., 1] / safe_z + npp[1]
    hn, wn = nb_img.shape[:2]
    inside = (z > 1e-6) & (un >= 0.5) & (un <= wn - 0.5) & (vn >= 0.5) & (vn <= hn - 0.5)
    sample = _bilinear(nb_img, un, vn)  # channels, mask
    # visibility: the neighbour's own (constant) depth render, at its resolution
    sd, sv = nb_depth.shape[:2]
    scale_u, scale_v = sv / wn, sd / hn
    dn = _bilinear(nb_depth, jax.lax.stop_gradient(un) * scale_u, jax.lax.stop_gradient(vn) * scale_v)
    zc = jax.lax.stop_gradient(z)
    visible = (dn[..., 1] >= _COVER) & (zc <= dn[..., 0] / jnp.maximum(dn[..., 1], 1e-6) * (1.0 + _OCCLUSION))
    valid = covered & inside & visible & (sample[..., -1] >= 0.9) & (ref_img[..., -1] >= 0.9)
    return ref_img[..., :-1], sample[..., :-1], valid


def _blurred(img):
    """`(K, H, W, C)` blurred by the binomial kernel [1, 4, 6, 4, 1] / 16 along both axes (sigma 1 px,
    edges clamped): sampled texture is band-limited before it is compared and interpolated. Each image
    is blurred in its own pixels, so where two views foreshorten the surface differently they see
    different blurs of its texture, and NCC then prefers a surface that evens them out over the true
    one: a fine texture is compared unblurred (docs/results.md, "No blur for a fine texture")."""
    k = (1.0 / 16, 4.0 / 16, 6.0 / 16, 4.0 / 16, 1.0 / 16)
    for axis in (1, 2):
        n = img.shape[axis]
        pad = [(0, 0)] * img.ndim
        pad[axis] = (2, 2)
        p = jnp.pad(img, pad, mode="edge")
        img = sum(w * jax.lax.slice_in_dim(p, i, i + n, axis=axis) for i, w in enumerate(k))
    return img


def _straight(photos, blur: float, colour: bool):
    """`(K, H, W, C + 1)`: the grey level (C = 1) or R, G, B (`colour`, C = 3) divided by the mask
    (straight, not premultiplied: no background darkens the contour), and the mask; all blurred by
    `_blurred` in the share `blur` (1: blurred, 0: as given)."""
    g = photos if colour else jnp.stack([_grey(photos[..., :3]), photos[..., 3]], -1)
    if blur == 1:
        g = _blurred(g)
    elif blur:
        g = g + blur * (_blurred(g) - g)
    return jnp.concatenate([g[..., :-1] / jnp.maximum(g[..., -1:], 1e-3), g[..., -1:]], -1)


def _window_sums(x, window: int, stride: int):
    # one 2-D reduction: `window_reduce` adds in another order, and a fit carries a change in the last
    # bits far (docs/results.md, "2026-12-07 (session 14:46-17:46 UTC)"); the masks' reductions are exact
    return jax.lax.reduce_window(x, 0.0, jax.lax.add, (1, window, window), (1, stride, stride), "VALID")


def _depth_steps(depth):
    """`(K, H, W)` bool: pixels within one pixel of a step in the depth `(K, H, W)`, where the second
    difference of the inverse depth (affine in the pixel on a plane, however grazing) exceeds
    `_DEPTH_STEP` times the inverse depth (an occluding contour inside the silhouette: a limb in
    front of the body)."""
    inv = 1.0 / jnp.maximum(depth, 1e-6)
    p = jnp.pad(inv, ((0, 0), (1, 1), (1, 1)), mode="edge")
    d2v = jnp.abs(p[:, 2:, 1:-1] - 2 * p[:, 1:-1, 1:-1] + p[:, :-2, 1:-1])
    d2u = jnp.abs(p[:, 1:-1, 2:] - 2 * p[:, 1:-1, 1:-1] + p[:, 1:-1, :-2])
    step = jnp.maximum(d2u, d2v) > _DEPTH_STEP * inv
    return window_reduce(step, False, jax.lax.bitwise_or, 3)


def consistency_windows(depth: Float[Array, "K H W"], alpha: Float[Array, "K H W"], ref_cams: Cameras,
                        ref_photos: Float[Array, "K H W 4"], nb_cams: Cameras, nb_photos: Float[Array, "K h w 4"],
                        nb_depth: Float[Array, "K s t 2"], *, window: int = 7, blur: float = 1.0,
                        colour: bool = False) -> tuple[Array, Array]:
    """Per window of every pair `(ncc, weight)`, `(K, Hw, Ww)` each: the NCC of the reference photo
    and the neighbour's photo warped through `depth` (module doc), and 1 where the window is
    valid (3/4 of its pixels valid and the reference std at least `MIN_STD`), else 0.

    `depth`, `alpha`: the rendered depth and coverage of the reference views; photos are
    premultiplied RGBA; `nb_depth`: the neighbours' rendered (depth, coverage) at any
    resolution (held constant). `blur`: how much of the binomial blur (sigma 1 px, each photo in
    its own pixels) the images get, 1 all, 0 none (`LossWeights.consistency_blur`). `colour`: NCC
    of R, G and B together (each channel's covariance and variances, averaged over the channels,
    make one NCC per window: a colour edge of equal grey still counts) instead of the grey level
    (`LossWeights.consistency_colour`)."""
    if not 0.0 <= blur <= 1.0:
        raise ValueError(f"blur must be in [0, 1], got {blur!r}")
    ref_img, nb_img = _straight(ref_photos, blur, colour), _straight(nb_photos, blur, colour)
    cover = jax.lax.stop_gradient(alpha)
    # away from the contours: there the depth is blended across the rim and the surface grazes the ray
    covered = window_reduce(cover, jnp.inf, jax.lax.min, 5) >= _COVER
    depth = depth / jnp.maximum(cover, _COVER)  # the render composites depth over 0 with its coverage
    covered = covered & ~_depth_steps(jax.lax.stop_gradient(depth))
    cam = lambda c: (c.rotation, c.translation, c.focal, c.principal_point)
    a, b, valid = jax.vmap(_warp_one)(depth, covered, cam(ref_cams), ref_img, cam(nb_cams), nb_img, nb_depth)
    m = valid.astype(depth.dtype)
    a, b = jnp.where(valid[..., None], a, 0.0), jnp.where(valid[..., None], b, 0.0)
    stride = max(window // 2, 1)
    n = _window_sums(m, window, stride)
    nn = jnp.maximum(n, 1.0)
    channels = a.shape[-1]
    var_a = var_b = cov = 0.0
    for ch in range(channels):
        x, y = a[..., ch], b[..., ch]
        sa, sb, saa, sbb, sab = [_window_sums(m * q, window, stride) for q in (x, y, x * x, y * y, x * y)]
        var_a = var_a + jnp.maximum(saa / nn - (sa / nn) ** 2, 0.0) / channels
        var_b = var_b + jnp.maximum(sbb / nn - (sb / nn) ** 2, 0.0) / channels
        cov = cov + (sab / nn - sa * sb / (nn * nn)) / channels
    eps = (0.1 * MIN_STD) ** 2
    ncc = cov / jnp.sqrt((var_a + eps) * (var_b + eps))
    # textured on both sides (a flat warped window gives no usable gradient, only noise)
    weight = ((n >= 0.75 * window * window) & (var_a >= MIN_STD**2) & (var_b >= 0.25 * MIN_STD**2)).astype(depth.dtype)
    return ncc, jax.lax.stop_gradient(weight)


def stereo_depth_cost(depth: Float[Array, "K H W"], alpha: Float[Array, "K H W"], target: Float[Array, "K H W"]
                      ) -> Float[Array, ""]:
    """The rendered depth against depths found by stereo from the photos alone (`target`, NaN or <= 0
    where none): per pixel fully covered, away from contours and steps of the rendered depth, the bounded
    cost `r^2 / (r^2 + c^2)` of the relative difference `r` (`c` = `STEREO_SCALE`), summed and divided by
    the pixels (as the image terms are). Its basin is as wide as the stereo search, where the NCC of
    `photo_consistency` sees a pixel or two."""
    cover = jax.lax.stop_gradient(alpha)
    covered = window_reduce(cover, jnp.inf, jax.lax.min, 5) >= _COVER
    depth = depth / jnp.maximum(cover, _COVER)
    valid = covered & ~_depth_steps(jax.lax.stop_gradient(depth)) & jnp.isfinite(target) & (target > 0)
    t = jnp.where(valid, target, 1.0)
    r = jnp.where(valid, depth / t - 1.0, 0.0)
    cost = r * r / (r * r + STEREO_SCALE**2)
    return jnp.sum(jnp.where(valid, cost, 0.0)) / target.size


def _pooled(x):
    """`(K, H, W, ...)` averaged over 2 x 2 pixel blocks (an odd last row / column padded with 0)."""
    k, h, w = x.shape[:3]
    pad = [(0, 0), (0, h % 2), (0, w % 2)] + [(0, 0)] * (x.ndim - 3)
    x = jnp.pad(x, pad)
    return x.reshape((k, (h + 1) // 2, 2, (w + 1) // 2, 2) + x.shape[3:]).mean(axis=(2, 4))


def robust_cost(residual: Float[Array, "..."], weight: Float[Array, "..."], spread: float = ROBUST_SPREAD
                ) -> Float[Array, "..."]:
    """`c r / (r + c)` of each window's `residual = 1 - NCC` (clipped to [0, 1]), with the scale `c`
    `spread` times the median residual of the windows where `weight > 0` (held constant; 1 where
    there are none). A window that fits pulls as `r` does; one far off (an occlusion the depth test
    missed, a highlight, a grazing window whose texture the two views foreshorten differently)
    pulls ever less, as `(c / (r + c))^2`, and costs at most `c`. The scale follows the fit: wide
    while the surface is pixels off (every window then carries signal), narrow near the surface,
    where those outliers are what is left. `spread <= 0`: the residual itself."""
    r = jnp.clip(residual, 0.0, 1.0)
    if spread <= 0:
        return r
    median = jnp.nanmedian(jnp.where(weight > 0, jax.lax.stop_gradient(r), jnp.nan))
    c = jnp.maximum(spread * jnp.where(jnp.isfinite(median), median, 1.0), _MIN_SCALE)
    return c * r / (r + c)


def photo_consistency(depth, alpha, ref_cams: Cameras, ref_photos, nb_cams: Cameras, nb_photos, nb_depth, *,
                      window: int = 7, scales: int = 2, spread: float = ROBUST_SPREAD,
                      blur: float = 1.0, colour: bool = False) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """`(loss, windows)`: the mean over the valid windows of their `robust_cost` (0 when there are
    none) and how many windows were valid (`consistency_windows` for the arguments), averaged over
    `scales` levels of a 2 x 2 pyramid of the depth, coverage and photos: the coarser levels see
    texture twice as wide, so a surface a few pixels off still finds its way. `blur`, `colour`: as in
    `consistency_windows`."""
    losses, counts = [], []
    for level in range(scales):
        if level:
            depth, alpha = _pooled(depth), _pooled(alpha)
            ref_photos, nb_photos, nb_depth = _pooled(ref_photos), _pooled(nb_photos), _pooled(nb_depth)
            ref_cams, nb_cams = scaled_cameras(ref_cams, 2), scaled_cameras(nb_cams, 2)
        ncc, weight = consistency_windows(depth, alpha, ref_cams, ref_photos, nb_cams, nb_photos, nb_depth,
                                          window=window, blur=blur, colour=colour)
        count = jnp.sum(weight)
        losses.append(jnp.sum(weight * robust_cost(1.0 - ncc, weight, spread)) / jnp.maximum(count, 1.0))
        counts.append(count)
    return sum(losses) / scales, counts[0]
