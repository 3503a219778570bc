"""The surface moved along its normals to where the photos at their own size agree (a plane sweep).

A fit made at a fraction of the photos' size places the surface to within about a pixel of that
size, several pixels of the photos'. `fit_photo_depth` refines it at the photos' own size, vertex by
vertex: each vertex a camera sees is given a reference camera (the one that faces it most squarely)
and up to `neighbours` more that see it from 5-35 degrees away (a vertex with fewer than two there,
on a sparse ring of views or in a concavity few views see into, takes the views nearest the
reference up to 1.5 times as far). A square of reference pixels around the vertex's projection is cast
onto surfaces through the vertex, tangent to the mesh and bent with its mean curvature (a flat square
on a curved surface would place the vertex a fraction of a pixel inside a convex one), moved along the
normal in steps of a fraction of a reference pixel; each sends the square into the neighbours, and the
zero-mean normalized cross-correlation (NCC) of the colours there (each channel zero-mean over the
square, one norm over the three) against the reference square scores it (an exposure offset per
channel and a gain common to the channels do not count). The best offset of the neighbours' mean
score (a parabola through the best three) becomes a target, weighed by how far the best score stands
above the mean one, where at least `min_views` neighbours have their own best within a step of it (one
pair alone is fooled by an occluder or a repeated pattern); vertices with too little texture (colour
deviation under `min_contrast`), a best score under `min_ncc` or a best offset at the end of the range
get none, and a best offset nearer than `hold_px` holds the vertex where it is. The offsets of all
vertices then solve `min sum_i w_i (d_i - t_i)^2 + anchor sum_i d_i^2 + smoothing sum_edges (d_i - d_j)^2`
(a sparse solve), so unmeasured vertices follow their neighbours; `fixed` vertices and their neighbours
stay (the outline a mask placed: a move along the normal there moves the silhouette). Photos with a
4th channel (a mask, as RGBA) count in a view only where the whole square lies on the mask: a square
that reaches past the object's edge compares the background, not the surface. A few rounds, the
normals and who sees what recomputed each time.

The NCC of many windows is computed in JAX (one compiled kernel for chunks of vertices); visibility is
cast with trimesh rays (embree when installed), as for `reprojection_psnr`.
"""

from __future__ import annotations

from typing import NamedTuple

import igl
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg
import trimesh
from scipy import ndimage

from jaxgenus.geometry._cameras import Cameras
from jaxgenus.geometry._reprojection import as_trimesh, camera_arrays, facing_cosines, photo_array, ray_intersector

__all__ = ["PhotoDepthFit", "fit_photo_depth"]

_CHUNK = 128  # vertices a sweep call: its temporaries ~90 MiB at 49 views x 17 planes x 81 samples x 8 partners
_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)
_LEAST = 2  # partners a vertex should have; fewer within max_angle: look up to 1.5x as far
_LEVEL = 1.0 / 65535.0  # the colours' 16-bit step; 8-bit photos' levels are 257 of them (exactly)


class PhotoDepthFit(NamedTuple):
    """What `fit_photo_depth` returns.

    Attributes:
        vertices: `(V, 3)` the mesh's vertices moved along their normals (a new array).
        measured: `(V,)` bool, the vertices free to move whose sweep found a confident best offset
            (last round).
        distance: `(V,)` how far each vertex moved in all (the mesh's units).
        offset_px: the mean |best offset| of the measured vertices in reference pixels, per round.
        ncc_before, ncc_after: the measured vertices' mean NCC at their place and at their best
            offset, per round (the first round's `ncc_before` is the input's).
    """

    vertices: np.ndarray
    measured: np.ndarray
    distance: np.ndarray
    offset_px: tuple[float, ...]
    ncc_before: tuple[float, ...]
    ncc_after: tuple[float, ...]


def _sample(colour, cam, u, v):
    """Bilinear colours `(..., 3)` of views `cam` at pixel positions `(u, v)` (centres at +0.5), edge-clamped."""
    _, h, w, _ = colour.shape
    x, y = jnp.clip(u - 0.5, 0.0, w - 1.001), jnp.clip(v - 0.5, 0.0, h - 1.001)
    x0, y0 = jnp.floor(x).astype(jnp.int32), jnp.floor(y).astype(jnp.int32)
    ax, ay = (x - x0)[..., None], (y - y0)[..., None]
    flat = colour.reshape(-1, 3)
    b = cam * (h * w) + y0 * w + x0
    as16 = (lambda c: c.astype(jnp.uint16) * jnp.uint16(257)) if colour.dtype == jnp.uint8 else (lambda c: c)  # noqa: E731
    at = lambda i: as16(flat[i]).astype(jnp.float32) * _LEVEL  # noqa: E731
    return (at(b) * (1 - ax) + at(b + 1) * ax) * (1 - ay) + (at(b + w) * (1 - ax) + at(b + w + 1) * ax) * ay


@jax.jit(donate_argnums=0)
def _with_view(levels, k, view):
    """`levels` with view `k` replaced by `view`, in place (the buffer is donated)."""
    return jax.lax.dynamic_update_index_in_dim(levels, view, k, 0)


def _device_colours(src: np.ndarray):
    """The photos' colours `(N, H, W, 3)` on the device: 8- and 16-bit photos as they are, others as 16-bit
    levels `_LEVEL` apart (half the memory of float32), converted and written a view at a time into one
    device buffer: neither a float copy nor a host copy of all the photos is made (a whole-stack
    transfer held two)."""
    dtype = np.uint8 if src.dtype == np.uint8 else np.uint16
    levels = jnp.zeros(src.shape[:3] + (3,), dtype)
    for k in range(len(src)):
        as_read = src.dtype in (np.uint8, np.uint16)
        view = src[k] if as_read else np.rint(np.clip(src[k], 0.0, 1.0) * np.float32(65535.0)).astype(dtype)
        levels = _with_view(levels, k, np.ascontiguousarray(view))
    return levels


def _reference_pixels(rot, focal, centre_px, centres, offsets, v, ref):
    """Each vertex's position in its reference camera's frame `(C, 3)` and its square of pixels `(C, P)` x2."""
    x = jnp.einsum("cij,cj->ci", rot[ref], v - centres[ref], precision=_HI)
    pu = (focal[ref, 0] * x[:, 0] / x[:, 2] + centre_px[ref, 0])[:, None] + offsets[None, :, 0]
    pv = (focal[ref, 1] * x[:, 1] / x[:, 2] + centre_px[ref, 1])[:, None] + offsets[None, :, 1]
    return x, pu, pv


def _reference_squares(colour, rot, focal, centre_px, centres, offsets, v, ref, slot=None):
    """Each vertex's square of reference pixels: its camera-frame position `(C, 3)`, the pixels
    `(C, P)` x2, their colours `(C, P, 3)` (each channel zero-mean) and the colour deviation `(C,)`.
    `slot`: where each reference view's photo sits in `colour` (default: at `ref`)."""
    x, pu, pv = _reference_pixels(rot, focal, centre_px, centres, offsets, v, ref)
    a = _sample(colour, (ref if slot is None else slot)[:, None], pu, pv)
    a = a - a.mean(1, keepdims=True)
    return x, pu, pv, a, jnp.sqrt((a * a).mean((1, 2)) + 1e-12)


@jax.jit
def _square_spreads(colour, rot, focal, centre_px, centres, offsets, v, ref, slot):
    """The colour deviation `(C,)` of each vertex's reference square (`_reference_squares`)."""
    return _reference_squares(colour, rot, focal, centre_px, centres, offsets, v, ref, slot)[-1]


@jax.jit
def _square_colours(colour, rot, focal, centre_px, centres, offsets, v, ref, slot):
    """Each vertex's reference square (`_reference_squares`): its zero-mean colours and their deviation
    as a row `(C, 3 P + 1)`."""
    a, sa = _reference_squares(colour, rot, focal, centre_px, centres, offsets, v, ref, slot)[3:]
    return jnp.concatenate([a.reshape(a.shape[0], -1), sa[:, None]], axis=1)


def _partner_ncc(colour, rot, focal, centre_px, centres, steps, v, n, sag, ref, nbr, nbr_ok, x, pu, pv, a, sa, slots):
    """NCC `(C, K, D)` of each vertex's reference square (camera-frame position `x`, pixels `pu, pv`,
    zero-mean colours `a`, deviation `sa`) against its `K` neighbours on `D` surfaces along its normal
    (NaN: no such neighbour or out of its frame); `slots[:, j]`: where neighbour j's photo sits in `colour`.
    Each surface is the tangent plane bent by `sag` `(C,)`: `sag r^2` along the normal at distance `r`
    from the vertex (the mesh's mean curvature: a flat square on a curved surface would place the
    vertex a fraction of a pixel inside a convex one)."""
    _, h, w, _ = colour.shape
    rays = jnp.stack([(pu - centre_px[ref, 0, None]) / focal[ref, 0, None],
                      (pv - centre_px[ref, 1, None]) / focal[ref, 1, None], jnp.ones_like(pu)], -1)
    rays = jnp.einsum("cji,cpj->cpi", rot[ref], rays, precision=_HI)  # (C, P, 3) world directions
    planes = v[:, None, :] + (steps[None, :] * x[:, 2:3] / focal[ref, 0:1])[..., None] * n[:, None, :]
    t = (jnp.einsum("cdi,ci->cd", planes - centres[ref][:, None], n, precision=_HI)[:, :, None]
         / jnp.einsum("cpi,ci->cp", rays, n, precision=_HI)[:, None, :])
    points = centres[ref][:, None, None] + t[..., None] * rays[:, None]  # (C, D, P, 3) on the planes
    bend = sag[:, None, None] * jnp.sum((points - planes[:, :, None]) ** 2, -1)  # (C, D, P) along the normal
    along = bend / jnp.einsum("cpi,ci->cp", rays, n, precision=_HI)[:, None]  # (C, D, P): the ray's length to it
    points = points + along[..., None] * rays[:, None]
    out = []
    for j in range(nbr.shape[1]):
        cam = nbr[:, j]
        y = jnp.einsum("cij,cdpj->cdpi", rot[cam], points - centres[cam][:, None, None], precision=_HI)
        z = jnp.maximum(y[..., 2], 1e-9)
        u = focal[cam, 0, None, None] * y[..., 0] / z + centre_px[cam, 0, None, None]
        q = focal[cam, 1, None, None] * y[..., 1] / z + centre_px[cam, 1, None, None]
        b = _sample(colour, slots[:, j, None, None], u, q)  # (C, D, P, 3)
        b = b - b.mean(2, keepdims=True)
        ncc = (a[:, None] * b).mean((2, 3)) / (sa[:, None] * jnp.sqrt((b * b).mean((2, 3)) + 1e-12))
        inside = ((u > 1) & (u < w - 1) & (q > 1) & (q < h - 1) & (y[..., 2] > 0)).all(2)
        out.append(jnp.where(inside & nbr_ok[:, j, None], ncc, jnp.nan))
    return jnp.stack(out, 1)


@jax.jit
def _sweep_scores(colour, rot, focal, centre_px, centres, offsets, steps, v, n, sag, ref, nbr, nbr_ok):
    """NCC `(C, K, D)` of each vertex's reference square against its `K` neighbours on `D` planes
    along its normal (`_partner_ncc`), every view's photo in `colour`."""
    x, pu, pv, a, sa = _reference_squares(colour, rot, focal, centre_px, centres, offsets, v, ref)
    return _partner_ncc(colour, rot, focal, centre_px, centres, steps, v, n, sag, ref, nbr, nbr_ok, x, pu, pv, a, sa, nbr)


@jax.jit
def _held_scores(colour, rot, focal, centre_px, centres, offsets, steps, v, n, sag, ref, nbr, nbr_ok, a, sa, slots):
    """`_sweep_scores` where `colour` holds only some views (`slots`: where each neighbour's photo sits,
    0 where it is not held: `nbr_ok` is False there) and the reference squares' colours come in."""
    x, pu, pv = _reference_pixels(rot, focal, centre_px, centres, offsets, v, ref)
    return _partner_ncc(colour, rot, focal, centre_px, centres, steps, v, n, sag, ref, nbr, nbr_ok, x, pu, pv, a, sa,
                        slots)


def _squares_on_mask(photos, reach: float):
    """Per view of RGBA `photos`, where a square reaching `reach` pixels around a pixel lies on the
    mask (`(N, H, W)` bool); None for RGB photos."""
    if np.shape(photos)[-1] != 4:
        return None
    alpha = np.asarray(photos)[..., 3]
    half = np.iinfo(alpha.dtype).max / 2 if alpha.dtype in (np.uint8, np.uint16) else 0.5  # no float copy
    return np.stack([ndimage.distance_transform_edt(np.pad(a > half, 1, mode="edge"))[1:-1, 1:-1] > reach for a in alpha])


def _on(on_mask, v, arrays):
    """`(V, N)` whether each vertex projects where `on_mask` holds in each view."""
    r, _, focal, centre_px, centres = arrays
    _, h, w = on_mask.shape
    out = np.zeros((len(v), len(r)), bool)
    for k in range(len(r)):
        x = (v - centres[k]) @ r[k].T
        z = np.maximum(x[:, 2], 1e-12)
        u = np.clip(np.floor(focal[k, 0] * x[:, 0] / z + centre_px[k, 0]), 0, w - 1).astype(np.int64)
        y = np.clip(np.floor(focal[k, 1] * x[:, 1] / z + centre_px[k, 1]), 0, h - 1).astype(np.int64)
        out[:, k] = on_mask[k, y, u] & (x[:, 2] > 0)
    return out


def _partners(v, cosines, centres, neighbours: int, max_angle: float, least: int = _LEAST):
    """Per vertex: the reference camera (facing it most squarely), up to `neighbours` others that
    see it 5 to `max_angle` degrees away from the reference's direction (those facing it most
    squarely first), and which of those exist. A vertex with fewer than `least` there (sparse rings,
    a concavity few views see into) takes the views nearest its reference up to 1.5 `max_angle` too."""
    ref = np.argmax(cosines, axis=1)
    usable = cosines[np.arange(len(v)), ref] > 0.3
    dirs = centres[None] - v[:, None]
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    cos_ref = np.einsum("vni,vi->vn", dirs, dirs[np.arange(len(v)), ref])
    seen = (cosines > 0.1) & (cos_ref <= np.cos(np.radians(5.0)))
    good = seen & (cos_ref >= np.cos(np.radians(max_angle)))
    wide = seen & (cos_ref >= np.cos(np.radians(min(1.5 * max_angle, 89.0)))) & (good.sum(1) < least)[:, None]
    rank = np.where(good, 2.0 + cosines, np.where(wide, cos_ref, -9.0))  # in range first, then the nearest
    order = np.argsort(-rank, axis=1)[:, :neighbours]
    return ref, order, np.take_along_axis(good | wide, order, 1) & usable[:, None]


def _sags(v, faces, normals):
    """Per vertex, `-(k1 + k2) / 4` from the mesh's mean curvature (cotangent Laplacian over the
    Voronoi areas): the height `sag r^2` along the normal of a paraboloid with the surface's mean
    curvature (isotropic); 0 where it is not finite."""
    lap = igl.cotmatrix(v, faces)
    area = igl.massmatrix(v, faces, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    curv = np.einsum("vi,vi->v", (lap @ v) / np.maximum(area, 1e-30)[:, None], normals) / 4.0
    return np.where(np.isfinite(curv), curv, 0.0)


def _chunked(kernel, v, *per_vertex):
    """`kernel(v, *per_vertex)` over the vertices in fixed-size chunks (one compilation), as numpy."""
    out = []
    for s in range(0, len(v), _CHUNK):
        idx = np.minimum(np.arange(s, s + _CHUNK), len(v) - 1)
        out.append(np.asarray(kernel(jnp.asarray(v[idx], jnp.float32), *(jnp.asarray(a[idx]) for a in per_vertex)))
                   [: min(_CHUNK, len(v) - s)])
    return np.concatenate(out)


def _spreads(colour, arrays, offsets, v, ref, slot):
    """The colour deviation of each vertex's reference square `(V,)` (its photo at `slot` in `colour`)."""
    r, _, focal, centre_px, centres = (jnp.asarray(a, jnp.float32) for a in arrays)
    return _chunked(lambda *a: _square_spreads(colour, r, focal, centre_px, centres, offsets, *a), v, ref, slot)


def _held_ncc(colour, arrays, offsets, steps, v, normals, sag, ref, nbr, nbr_ok, slot, total):
    """`(V, K, D)` NCC of each vertex's reference square against its neighbours where the views are
    split over processes (`slot`: where each view's photo sits in this process's `colour`, -1 where
    another holds it): the holder of a vertex's reference view samples its square, the squares are
    summed over the processes (`total`), and the holder of each neighbour scores it against that one."""
    r, _, focal, centre_px, centres = (jnp.asarray(a, jnp.float32) for a in arrays)
    mine = slot[ref] >= 0
    squares = np.zeros((len(v), offsets.shape[0] * 3 + 1), np.float32)
    if mine.any():
        squares[mine] = _chunked(lambda *a: _square_colours(colour, r, focal, centre_px, centres, offsets, *a),
                                 v[mine], ref[mine], slot[ref[mine]])
    squares = total(squares)
    a, sa = squares[:, :-1].reshape(len(v), -1, 3), squares[:, -1]
    pv, pk = np.nonzero(nbr_ok & (slot[nbr] >= 0))  # the (vertex, neighbour) pairs whose neighbour is held here
    ncc = np.full(nbr.shape + (len(steps),), np.nan, np.float32)
    size = _CHUNK * nbr.shape[1]  # pairs a call: the temporaries of a chunk of vertices
    for s in range(0, len(pv), size):
        i = np.minimum(np.arange(s, s + size), len(pv) - 1)
        cam = nbr[pv[i], pk[i]][:, None]
        out = _held_scores(colour, r, focal, centre_px, centres, offsets, steps, *(jnp.asarray(x) for x in (
            v[pv[i]].astype(np.float32), normals[pv[i]].astype(np.float32), sag[pv[i]].astype(np.float32), ref[pv[i]],
            cam, np.ones_like(cam, bool),
            a[pv[i]], sa[pv[i]], slot[cam])))
        n = min(size, len(pv) - s)
        ncc[pv[s:s + n], pk[s:s + n]] = np.asarray(out)[:n, 0]
    finite = np.isfinite(ncc)  # each (vertex, neighbour) scored by the one process that holds the neighbour
    counted = total(finite.astype(np.uint8))
    return np.where(counted > 0, total(np.where(finite, ncc, 0.0).astype(np.float32)), np.nan)


def _scores(colour, arrays, offsets, steps, v, normals, sag, ref, nbr, nbr_ok, held=None):
    """The mean NCC over each vertex's neighbours per plane `(V, D)` and how many neighbours have their
    own best within a plane of that mean's best (`_sweep_scores`; `held`: `(slot, total)` of `_held_ncc`
    where the views are split over processes)."""
    if held is None:
        r, _, focal, centre_px, centres = (jnp.asarray(a, jnp.float32) for a in arrays)
        ncc = _chunked(lambda *a: _sweep_scores(colour, r, focal, centre_px, centres, offsets, steps, *a),
                       v, normals.astype(np.float32), sag.astype(np.float32), ref, nbr, nbr_ok)
    else:
        ncc = _held_ncc(colour, arrays, offsets, steps, v, normals, sag, ref, nbr, nbr_ok, *held)
    ok = np.isfinite(ncc[:, :, len(steps) // 2])
    score = np.where(ok[:, :, None] & np.isfinite(ncc), ncc, 0.0).sum(1) / np.maximum(ok.sum(1), 1)[:, None]
    own = np.argmax(np.where(np.isfinite(ncc), ncc, -9.0), axis=2)  # each neighbour's own best plane
    agree = ok & (np.abs(own - np.argmax(score, axis=1)[:, None]) <= 1)
    return score, agree.sum(1)


def _targets(score, count, spread, min_ncc: float, min_contrast: float, min_views: int):
    """Best offset (in steps, parabola-refined), weight and the NCC at 0 and at the best, per vertex."""
    n_steps = score.shape[1]
    half = n_steps // 2
    best = np.argmax(score, axis=1)
    mid = np.clip(best, 1, n_steps - 2)
    rows = np.arange(len(score))
    s0, s1, s2 = score[rows, mid - 1], score[rows, mid], score[rows, mid + 1]
    curve = s0 - 2 * s1 + s2
    frac = np.where(curve < -1e-9, 0.5 * (s0 - s2) / np.where(curve < -1e-9, curve, -1.0), 0.0)
    offset = mid + np.clip(frac, -0.5, 0.5) - half
    top = score[rows, best]
    ok = (count >= min_views) & (spread > min_contrast) & (top > min_ncc) & (best > 0) & (best < n_steps - 1)
    weight = np.where(ok, np.clip((top - score.mean(axis=1)) / 0.2, 0.0, 1.0), 0.0)
    return offset, weight, ok, score[rows, half], top


def _check_settings(*, max_angle: float, step_px: float, search_px: float, hold_px: float, **named) -> None:
    """A `ValueError` naming the first of `fit_photo_depth`'s settings out of its range."""
    bad = [f"{k}: expected an int >= {0 if k == 'rounds' else 1}, got {v!r}" for k, v in named.items()
           if k in ("rounds", "neighbours", "patch", "min_views") and not (isinstance(v, int) and v >= (k != "rounds"))]
    bad += [f"{k}: expected > 0, got {v!r}" for k, v in named.items()
            if k in ("spacing", "smoothing", "anchor") and not v > 0]
    bad += [f"max_angle: expected 5 < max_angle < 90 (degrees), got {max_angle!r}"] if not 5.0 < max_angle < 90.0 else []
    bad += [f"step_px, search_px: expected 0 < step_px < search_px, got {step_px!r}, {search_px!r}"
            ] if not 0 < step_px < search_px else []
    bad += [f"hold_px: expected >= 0, got {hold_px!r}"] if not hold_px >= 0 else []
    if bad:
        raise ValueError(bad[0])


def fit_photo_depth(mesh, cameras: Cameras, photos, *, fixed=None, rounds: int = 2, neighbours: int = 8,
                    max_angle: float = 35.0, patch: int = 4, spacing: float = 1.5, search_px: float = 12.0,
                    step_px: float = 1.5, smoothing: float = 0.1, min_ncc: float = 0.3,
                    min_contrast: float = 0.0115, min_views: int = 2, hold_px: float = 0.0, anchor: float = 1e-6,
                    held=None, total=None) -> PhotoDepthFit:
    """`mesh`'s vertices moved along their normals to where `photos` agree (module doc).

    Args:
        mesh: a `Mesh`, a `trimesh.Trimesh` or `(vertices, faces)`, in the cameras' frame.
        cameras: the `Cameras` of `photos` (pinhole, their size the photos').
        photos: `(N, H, W, 3|4)` photos (float in [0, 1], uint8 or uint16); a 4th channel is the object's
            mask (> 0.5: object): a view counts for a vertex only where its square lies on it.
        fixed: optional `(V,)` bool, vertices that stay (with their one-ring), such as an outline.
        rounds: sweeps, each from the last one's surface; neighbours: views compared with the
            reference per vertex; max_angle: how far (degrees) from the reference they may look.
        patch, spacing: the reference square is `2 patch + 1` samples a side, `spacing` pixels apart.
        search_px, step_px: the first round's planes span +-`search_px` reference pixels along the
            normal in steps of `step_px`; each later round halves both.
        smoothing: the weight of the edge term of the solve; min_ncc, min_contrast: the least best
            score and the reference square's colour deviation (RMS over its samples and the three
            channels, in [0, 1] levels) a vertex needs to count; min_views: the neighbours that must
            agree on its best offset.
        hold_px: a vertex whose best offset is nearer than this (reference pixels) stays where it is
            (a measured offset of 0); anchor: the solve's pull of every vertex to where it is.
        held, total: where the views are split over processes (each passing the same mesh, every
            camera, and the photos of its own views, `held`: their indices into `cameras`), a
            function summing an array over the processes (`jaxgenus.optim.summed_over_processes`):
            each process sees with its own views, samples the squares of the vertices whose
            reference view it holds and scores them against the neighbours it holds; the sums make
            every process move the vertices alike. None: `photos` are every view's.

    Returns:
        A `PhotoDepthFit`; the input is not modified. The faces (and so the genus) are kept.
    """
    tm = as_trimesh(mesh)
    n_all = len(cameras)
    held = np.arange(n_all) if held is None else np.asarray(held, np.int64)
    split = total is not None
    if held.ndim != 1 or not len(held) or held.min() < 0 or held.max() >= n_all or np.any(np.diff(held) <= 0):
        raise ValueError(f"held: expected increasing indices into the {n_all} cameras, got {held.tolist()[:10]}")
    if not split and len(held) != n_all:
        raise ValueError("held: views split over processes need `total`, the sum over them")
    slot = np.full(n_all, -1, np.int64)
    slot[held] = np.arange(len(held))
    total = total if split else (lambda x: x)
    src = photo_array(photos, "photos", len(held), as_read=True)
    on_mask = _squares_on_mask(photos, patch * spacing * np.sqrt(2.0) + 1.0)
    if src.shape[1:3] != (cameras.height, cameras.width):
        raise ValueError(f"photos: size {src.shape[1:3]} differs from the cameras' {(cameras.height, cameras.width)}")
    faces = np.asarray(tm.faces, np.int64)
    keep = np.zeros(len(tm.vertices), bool) if fixed is None else np.asarray(fixed)
    if keep.shape != (len(tm.vertices),) or keep.dtype != bool:
        raise ValueError(f"fixed: expected a ({len(tm.vertices)},) bool array, got {keep.dtype} {keep.shape}")
    _check_settings(rounds=rounds, neighbours=neighbours, patch=patch, min_views=min_views, max_angle=max_angle,
                    spacing=spacing, search_px=search_px, step_px=step_px, smoothing=smoothing, anchor=anchor,
                    hold_px=hold_px)
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))  # embree is float32: trace near the origin
    v0 = np.asarray(tm.vertices, np.float64) - shift
    r, t, focal, centre_px, centres = camera_arrays(cameras)
    arrays = (r, t, focal, centre_px, centres - shift)
    mine = tuple(a[held] for a in arrays)  # the cameras of the views held here
    colour = _device_colours(src)
    g = np.arange(-patch, patch + 1, dtype=np.float32) * spacing
    offsets = jnp.asarray(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2))
    n_half = int(np.floor(search_px / step_px))
    planes = np.arange(-n_half, n_half + 1, dtype=np.float32)  # in steps; a round's step is step_px / 2^round
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adj = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(v0), len(v0))).tocsr()
    adj = ((adj + adj.T) > 0).astype(np.float64)
    keep = keep | (adj @ keep.astype(np.float64) > 0)
    lap = ((sparse.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj) * smoothing).tocsr()
    v, measured, stats = v0.copy(), np.zeros(len(v0), bool), ([], [], [])
    cur = trimesh.Trimesh(v, faces, process=False)  # one mesh, its vertices set each sweep (`ray_intersector`)
    for k in range(rounds):
        step = step_px / 2**k
        steps = jnp.asarray(planes * step)
        cur.vertices = v
        normals = np.asarray(cur.vertex_normals)
        sag = _sags(v, faces, normals)
        tol = 1e-3 * float(np.linalg.norm(np.ptp(v, axis=0)))
        cosines = np.zeros((len(v), n_all), np.float32)  # each view's column from the process holding it
        cosines[:, held] = facing_cosines(cur, ray_intersector(cur), tol, mine, (cameras.height, cameras.width),
                                          margin=patch * spacing + 2)[0]
        if on_mask is not None:
            cosines[:, held] = np.where(_on(on_mask, v, mine), cosines[:, held], -1.0)
        cosines = total(cosines)
        ref, nbr, nbr_ok = _partners(v, cosines, arrays[4], neighbours, max_angle)
        score, count, spread = np.zeros((len(v), len(steps))), np.zeros(len(v), np.int64), np.zeros(len(v))
        # only the vertices free to move that some pair of views can measure, and of those the textured ones
        act = np.flatnonzero(nbr_ok.any(axis=1) & ~keep)
        if len(act):
            here = act[slot[ref[act]] >= 0]  # the vertices whose reference view this process holds
            if len(here):
                spread[here] = _spreads(colour, arrays, offsets, v[here], ref[here], slot[ref[here]])
            spread = total(spread)
            act = act[spread[act] > min_contrast]
        if len(act):
            score[act], count[act] = _scores(colour, arrays, offsets, steps, v[act], normals[act], sag[act], ref[act],
                                             nbr[act], nbr_ok[act], (slot, total) if split else None)
        offset, weight, measured, at_zero, top = _targets(score, count, spread, min_ncc, min_contrast, min_views)
        offset = np.where(np.abs(offset) * step >= hold_px, offset, 0.0)  # nearer than hold_px: stay
        pixel = np.einsum("vi,vi->v", v - arrays[4][ref], r[ref, 2]) / focal[ref, 0]
        free = np.flatnonzero(~keep)  # the kept vertices' offsets are 0 exactly
        d = np.zeros(len(v))
        if len(free):
            system = (sparse.diags(weight[free] + anchor) + lap[free][:, free]).tocsc()
            d[free] = sparse_linalg.spsolve(system, weight[free] * offset[free] * step * pixel[free])
        d = np.clip(d, -n_half * step * pixel, n_half * step * pixel)
        if not np.isfinite(d).all():
            break
        v = v + d[:, None] * normals
        for acc, value in zip(stats, (np.abs(offset[measured]) * step, at_zero[measured], top[measured])):
            acc.append(float(np.mean(value)) if measured.any() else float("nan"))
    return PhotoDepthFit(v + shift, measured, np.linalg.norm(v - v0, axis=1), *(tuple(s) for s in stats))
