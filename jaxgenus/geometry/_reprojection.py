"""Held-out image-based rendering: how well a mesh explains photos it was not fitted to.

`reprojection_psnr` predicts each held-out photo from the training photos through the
mesh: a ray through every held-out pixel finds the surface point it sees, that point
is projected into the training views nearest in viewing direction that see it (inside
their frame, no other part of the mesh hiding it: an object cut by the frames is still
predicted from the nearest views that hold it), and the training colours found there
(bilinear) are blended, nearer directions weighing more. The PSNR of that prediction
against the held-out photo, over the object's pixels, measures the geometry: a wrong
surface sends each view's colours to the wrong place. No texture is fitted and no
renderer of this library is used: rays are cast by trimesh (embree when installed).

The same rays say which of a mesh's vertices the cameras see. `seen_counts` counts, per vertex,
the cameras that hold it in their frame, face it and have no other part of the mesh in between;
`fill_unseen` moves the vertices that no camera sees, though some hold them in frame (a slot behind a
gable, the underside of an object on a table, a bulge the silhouettes left behind a wall), onto the
membrane the seen surface spans around them: each such vertex at the mean of its neighbours (a
harmonic map of the uniform graph Laplacian), the seen ones and those out of every frame fixed. No
image says where that surface is; a cavity no camera looks into or a bulge behind the seen surface
is the guess the images never checked, and a held-out view between the cameras sees the former as a
crack and through the latter misses what the cameras did see.

`fit_outline` moves the outline of a mesh fitted to coarser copies of its masks onto the masks at
their own size: per view, the vertices on the mesh's outer outline (their normal across the view
ray, and a ray a tenth of a pixel outward past them misses the mesh) move across the ray by the
signed distance of their projection to the mask's edge; each vertex takes the mean of the moves its
views ask, in a few damped rounds. Only outline vertices move: a move handed on to neighbours that no
view checks is never taken back, and rounds of them drift.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg
from scipy import ndimage
from scipy.sparse.csgraph import connected_components
import trimesh

from jaxgenus.geometry._cameras import Cameras

__all__ = ["OutlineFit", "Reprojection", "UnseenFill", "fill_unseen", "fit_outline", "reprojection_psnr",
           "seen_counts"]


class Reprojection(NamedTuple):
    """What `reprojection_psnr` measured, per held-out view.

    Attributes:
        psnr: `(M,)` dB over each view's evaluated pixels (colours in [0, 1]).
        coverage: `(M,)` share of those pixels that some training view saw; the rest
            were predicted black (a mesh that misses the object pays for it).
        pixels: `(M,)` evaluated pixels: the held-out mask or the mesh, whichever covers them.
        psnr_inside: `(M,)` dB over the pixels both the held-out mask and the mesh cover (the
            surface's placement alone, without its outline; with no masks, as `psnr`).
    """

    psnr: np.ndarray
    coverage: np.ndarray
    pixels: np.ndarray
    psnr_inside: np.ndarray

    @property
    def mean(self) -> float:
        return float(np.mean(self.psnr))


def as_trimesh(mesh) -> trimesh.Trimesh:
    if isinstance(mesh, trimesh.Trimesh):
        v, f = mesh.vertices, mesh.faces
    elif hasattr(mesh, "to_numpy"):
        v, f = mesh.to_numpy()
    else:
        v, f = mesh
    v, f = np.asarray(v, np.float64), np.asarray(f, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"mesh: expected vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    if not np.isfinite(v).all():
        raise ValueError("mesh: vertices must be finite")
    return trimesh.Trimesh(v, f, process=False)


def ray_intersector(tm: trimesh.Trimesh):
    """An embree ray intersector of `tm`. A loop that moves a mesh keeps one `Trimesh` and sets its
    vertices each round: a `Trimesh` sits in a reference cycle (with its visual), so one dropped each
    round is freed only by Python's cycle collector, which counts objects, not bytes (on 600k faces,
    25 rounds of the outline held 2.3 GB that way)."""
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError:  # pragma: no cover - embreex ships on x86_64
        from trimesh.ray.ray_triangle import RayMeshIntersector
    return RayMeshIntersector(tm)


def photo_array(x, name: str, n: int | None = None, *, as_read: bool = False) -> np.ndarray:
    """The checked RGB of photos `x` as float32 in [0, 1]; `as_read`: 8- and 16-bit photos as they are."""
    x = np.asarray(x)
    if x.ndim != 4 or x.shape[-1] not in (3, 4):
        raise ValueError(f"{name}: expected (N, H, W, 3 or 4) photos, got shape {x.shape}")
    if n is not None and len(x) != n:
        raise ValueError(f"{name}: {len(x)} photos for {n} cameras")
    if x.dtype in (np.uint8, np.uint16):
        if as_read:
            return x[..., :3]
        out = x[..., :3].astype(np.float32)  # uint8 / 255, uint16 / 65535, as image files are read
        out *= np.float32(1.0 / np.iinfo(x.dtype).max)
        return out
    if not all(np.isfinite(view).all() for view in x):  # a view at a time: no full-size mask
        raise ValueError(f"{name}: photos must be finite")
    return np.asarray(x[..., :3], np.float32)  # float32 photos are not copied (and never written to)


def camera_arrays(cams: Cameras):
    r = np.asarray(cams.rotation, np.float64)
    t = np.asarray(cams.translation, np.float64)
    centres = -np.einsum("nji,nj->ni", r, t)
    return r, t, np.asarray(cams.focal, np.float64), np.asarray(cams.principal_point, np.float64), centres


def _blocks(x: np.ndarray, f: int) -> np.ndarray:
    """`(H, W, C)` averaged over `f x f` blocks (the ragged last row/column dropped)."""
    h, w = x.shape[0] // f, x.shape[1] // f
    return x[: h * f, : w * f].reshape(h, f, w, f, -1).mean(axis=(1, 3))


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Colours of `img (H, W, 3)` at pixel positions `(u, v)` (pixel centres at +0.5), edge-clamped."""
    h, w = img.shape[:2]
    x, y = np.clip(u - 0.5, 0, w - 1), np.clip(v - 0.5, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(np.int64), w - 2), np.minimum(np.floor(y).astype(np.int64), h - 2)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - ax) + img[y0, x0 + 1] * ax
    bottom = img[y0 + 1, x0] * (1 - ax) + img[y0 + 1, x0 + 1] * ax
    return top * (1 - ay) + bottom * ay


def reprojection_psnr(mesh, photos, cameras: Cameras, held_photos, held_cameras: Cameras, held_masks=None, *,
                      neighbours: int = 4, downsample: int = 1) -> Reprojection:
    """PSNR of the held-out photos predicted from the training photos through `mesh` (module doc).

    Args:
        mesh: a `Mesh`, a `trimesh.Trimesh` or `(vertices, faces)`, in the cameras' frame.
        photos, cameras: the training photos `(N, H, W, 3|4)` (float in [0, 1], uint8 or uint16)
            and their cameras.
        held_photos, held_cameras: the held-out photos `(M, H', W', 3|4)` and cameras.
        held_masks: `(M, H', W')` object masks of the held-out photos (> 0.5: object), or
            None: the pixels the mesh covers are evaluated.
        neighbours: training views blended per pixel: the nearest in viewing direction (of the
            held-out view) that see its surface point.
        downsample: evaluate at one pixel per `downsample x downsample` block (block means
            of the held-out photo and mask; the training photos are sampled at full size).
    """
    src = photo_array(photos, "photos", len(cameras))
    held = photo_array(held_photos, "held_photos", len(held_cameras))
    if held_masks is not None:
        held_masks = np.asarray(held_masks, np.float32)
        if held_masks.shape != held.shape[:3]:
            raise ValueError(f"held_masks: expected shape {held.shape[:3]}, got {held_masks.shape}")
    if src.shape[1:3] != (cameras.height, cameras.width) or held.shape[1:3] != (held_cameras.height,
                                                                                 held_cameras.width):
        raise ValueError("photos/held_photos: image sizes differ from their cameras' (height, width)")
    if not (isinstance(neighbours, int) and neighbours >= 1) or not (isinstance(downsample, int) and downsample >= 1):
        raise ValueError(f"neighbours and downsample must be ints >= 1, got {neighbours}, {downsample}")
    tm = as_trimesh(mesh)
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))  # embree is float32: trace near the origin
    tm = trimesh.Trimesh(tm.vertices - shift, tm.faces, process=False)
    rays, tol = ray_intersector(tm), 1e-3 * float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
    r_s, t_s, f_s, c_s, centre_s = camera_arrays(cameras)
    r_h, _, f_h, c_h, centre_h = camera_arrays(held_cameras)
    centre_s, centre_h = centre_s - shift, centre_h - shift
    t_s = -np.einsum("nij,nj->ni", r_s, centre_s)  # translations in the shifted frame
    out = []
    for m in range(len(held)):
        target = _blocks(held[m], downsample)
        h, w = target.shape[:2]
        jj, ii = np.meshgrid((np.arange(w) + 0.5) * downsample, (np.arange(h) + 0.5) * downsample)
        pix = np.stack([(jj.ravel() - c_h[m, 0]) / f_h[m, 0], (ii.ravel() - c_h[m, 1]) / f_h[m, 1],
                        np.ones(jj.size)], axis=1)
        d = pix @ r_h[m]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        tri, ray, loc = rays.intersects_id(np.broadcast_to(centre_h[m], d.shape).copy(), d, multiple_hits=False,
                                           return_locations=True)
        hit = np.zeros(len(d), bool)
        hit[ray] = True
        points = np.zeros((len(d), 3))
        points[ray] = loc
        order = np.argsort(np.einsum("ni,i->n", _unit(centre_s), _unit(centre_h[m])))[::-1]
        colour, weight, count = np.zeros((len(d), 3)), np.zeros(len(d)), np.zeros(len(d), np.int64)
        for s in order:  # nearest directions first, each point until `neighbours` views saw it
            idx = np.flatnonzero(hit & (count < neighbours))
            if len(idx) == 0:
                break
            p = points[idx]
            x = p @ r_s[s].T + t_s[s]
            z = np.maximum(x[:, 2], 1e-12)
            u, v = f_s[s, 0] * x[:, 0] / z + c_s[s, 0], f_s[s, 1] * x[:, 1] / z + c_s[s, 1]
            inside = (x[:, 2] > 0) & (u >= 0) & (u < cameras.width) & (v >= 0) & (v < cameras.height)
            to_cam = centre_s[s] - p
            dist = np.linalg.norm(to_cam, axis=1)
            seen = inside.copy()
            seen[inside] = unoccluded(rays, p[inside], to_cam[inside] / dist[inside, None], dist[inside], tol)
            cos = np.einsum("ni,ni->n", to_cam / dist[:, None], _unit(centre_h[m] - p))
            wgt = 1.0 / (np.arccos(np.clip(cos[seen], -1, 1)) + 1e-2)
            colour[idx[seen]] += wgt[:, None] * _bilinear(src[s], u[seen], v[seen])
            weight[idx[seen]] += wgt
            count[idx[seen]] += 1
        seen_any = weight > 0
        pred = np.where(seen_any[:, None], colour / np.maximum(weight, 1e-12)[:, None], 0.0)
        mask = hit if held_masks is None else _blocks(held_masks[m][..., None], downsample).ravel() > 0.5
        region, inside = hit | mask, hit & mask
        sq = np.mean((pred - target.reshape(-1, 3)) ** 2, axis=1)
        out.append((_psnr(sq[region]), float(np.mean(seen_any[region])) if region.any() else 0.0,
                    int(region.sum()), _psnr(sq[inside])))
    psnr, coverage, pixels, psnr_inside = (np.array(c) for c in zip(*out))
    return Reprojection(psnr, coverage, pixels, psnr_inside)


def _psnr(squared_errors: np.ndarray) -> float:
    return -10.0 * np.log10(max(float(np.mean(squared_errors)) if len(squared_errors) else 0.0, 1e-10))


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def unoccluded(rays, points: np.ndarray, directions: np.ndarray, dist: np.ndarray, tol: float) -> np.ndarray:
    """Whether the segment from each point (nudged off its surface) to its camera is free of the mesh."""
    if len(points) == 0:
        return np.zeros(0, bool)
    start = points + directions * tol
    _, ray, loc = rays.intersects_id(start, directions, multiple_hits=False, return_locations=True)
    free = np.ones(len(points), bool)
    blocked = np.linalg.norm(loc - start[ray], axis=1) < dist[ray] - 2 * tol
    free[ray[blocked]] = False
    return free


def facing_cosines(tm: trimesh.Trimesh, rays, tol: float, arrays, size: tuple[int, int], *,
                   margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex of `tm` and camera, the cosine between the vertex's (area-weighted) normal and the
    direction to the camera where the camera sees it (inside its frame by `margin` pixels, in front,
    facing it, the segment to it free of the mesh), else -1; and how many cameras hold it in frame.

    `arrays` is `camera_arrays` of the cameras (their centres in `tm`'s frame), `size` `(H, W)`.
    Returns `(cosines (V, N) float32, in_frame (V,) int)`.
    """
    r, _, focal, centre_px, centres = arrays
    h, w = size
    v, normals = np.asarray(tm.vertices), np.asarray(tm.vertex_normals)
    cosines, in_frame = np.full((len(v), len(r)), -1.0, np.float32), np.zeros(len(v), np.int64)
    for k in range(len(r)):
        x = (v - centres[k]) @ r[k].T
        z = np.maximum(x[:, 2], 1e-12)
        u, y = focal[k, 0] * x[:, 0] / z + centre_px[k, 0], focal[k, 1] * x[:, 1] / z + centre_px[k, 1]
        inside = (x[:, 2] > 0) & (u >= margin) & (u < w - margin) & (y >= margin) & (y < h - margin)
        in_frame += inside
        to_cam = centres[k] - v
        dist = np.linalg.norm(to_cam, axis=1)
        to_cam /= np.maximum(dist, 1e-30)[:, None]
        cos = np.einsum("ni,ni->n", to_cam, normals)
        idx = np.flatnonzero(inside & (cos > 0))
        free = unoccluded(rays, v[idx] + normals[idx] * tol, to_cam[idx], dist[idx], tol)
        cosines[idx[free], k] = cos[idx[free]]
    return cosines, in_frame


def seen_counts(mesh, cameras: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """How many of `cameras` see each vertex of `mesh`, and how many hold it in their frame.

    A camera sees a vertex when the vertex projects inside its frame, in front of it, its
    (area-weighted) normal faces the camera and the segment to the camera, started a hair off the
    surface, meets no other part of the mesh.

    Returns:
        `(seen (V,), in_frame (V,))` int counts over the cameras.
    """
    tm = as_trimesh(mesh)
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))  # embree is float32: trace near the origin
    tm = trimesh.Trimesh(tm.vertices - shift, tm.faces, process=False)
    rays, tol = ray_intersector(tm), 1e-3 * float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
    r, t, focal, centre_px, centres = camera_arrays(cameras)
    cosines, in_frame = facing_cosines(tm, rays, tol, (r, t, focal, centre_px, centres - shift),
                                       (cameras.height, cameras.width))
    return np.sum(cosines > 0, axis=1).astype(np.int64), in_frame


class UnseenFill(NamedTuple):
    """What `fill_unseen` returns.

    Attributes:
        vertices: `(V, 3)` the mesh's vertices with the unseen ones moved (a new array).
        moved: `(V,)` bool, the vertices it moved (seen by no camera, in some camera's frame).
        distance: `(V,)` how far each vertex moved (the mesh's units).
    """

    vertices: np.ndarray
    moved: np.ndarray
    distance: np.ndarray


def fill_unseen(mesh, cameras: Cameras) -> UnseenFill:
    """The vertices of `mesh` that no camera sees (but some holds in frame) moved onto the membrane
    the seen surface spans around them (module doc); the faces and the genus are kept.

    Args:
        mesh: a `Mesh`, a `trimesh.Trimesh` or `(vertices, faces)`, in the cameras' frame.
        cameras: the `Cameras` whose views count as seeing.

    Returns:
        An `UnseenFill`; the input is not modified. A group of unseen vertices with no seen or
        out-of-frame neighbour anywhere around it stays where it is.
    """
    tm = as_trimesh(mesh)
    v, f = np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64)
    seen, in_frame = seen_counts((v, f), cameras)
    moved = (seen == 0) & (in_frame > 0)
    out = v.copy()
    if moved.any() and not moved.all():
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        adj = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(v), len(v))).tocsr()
        adj = ((adj + adj.T) > 0).astype(np.float64)
        lap = sparse.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
        free = np.flatnonzero(moved)
        n_groups, group = connected_components(adj[free][:, free], directed=False)
        bounded = np.zeros(n_groups, bool)
        bounded[group[np.asarray(adj[free][:, np.flatnonzero(~moved)].sum(axis=1)).ravel() > 0]] = True
        moved[free[~bounded[group]]] = False  # an island with nothing seen around it stays put
        free, fixed = np.flatnonzero(moved), np.flatnonzero(~moved)
        if len(free):
            system = lap[free][:, free].tocsc()
            out[free] = sparse_linalg.splu(system).solve(-(lap[free][:, fixed] @ v[fixed]))
        if not np.isfinite(out).all():
            out, moved = v.copy(), np.zeros_like(moved)
    return UnseenFill(out, moved, np.linalg.norm(out - v, axis=1))


class OutlineFit(NamedTuple):
    """What `fit_outline` returns.

    Attributes:
        vertices: `(V, 3)` the mesh's vertices with the outline moved (a new array).
        moved: `(V,)` bool, the vertices some view found on its outline.
        distance: `(V,)` how far each vertex moved (the mesh's units).
        before, after: the mean distance in pixels between the outline vertices' projections and
            the masks' edges, before and after (NaN where no view found an outline).
    """

    vertices: np.ndarray
    moved: np.ndarray
    distance: np.ndarray
    before: float
    after: float


def _signed_edges(masks: np.ndarray) -> list[np.ndarray]:
    """Per mask, the signed distance (px, > 0 outside) of each pixel centre to its edge; the frame's
    border is no edge (an object cut by the frame runs on past it)."""
    out = []
    for m in masks > 0.5:
        padded = np.pad(m, 4, mode="edge")
        d = ndimage.distance_transform_edt(~padded) - ndimage.distance_transform_edt(padded)
        out.append(np.clip(d[4:-4, 4:-4], -8, 8).astype(np.float32))
    return out


def _outline_moves(tm: trimesh.Trimesh, cams_arrays, size, edges, band: float, probe_px: float):
    """One round of `fit_outline` on `tm` as it is now: per vertex, the summed move its views ask of
    it, how many asked, and the sum and count of the outline vertices' |signed distance| (px)."""
    r, _, focal, centre_px, centres = cams_arrays
    h, w = size
    v = np.asarray(tm.vertices)
    normals, rays = np.asarray(tm.vertex_normals), ray_intersector(tm)
    acc, count, offsets = np.zeros_like(v), np.zeros(len(v)), np.zeros(2)
    for k in range(len(r)):
        x = (v - centres[k]) @ r[k].T
        z = np.maximum(x[:, 2], 1e-12)
        u, y = focal[k, 0] * x[:, 0] / z + centre_px[k, 0], focal[k, 1] * x[:, 1] / z + centre_px[k, 1]
        ray = v - centres[k]
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        across = np.einsum("ni,ni->n", normals, ray)
        idx = np.flatnonzero((x[:, 2] > 0) & (u >= 3) & (u < w - 3) & (y >= 3) & (y < h - 3) & (np.abs(across) < 0.3))
        s = ndimage.map_coordinates(edges[k], [y[idx] - 0.5, u[idx] - 0.5], order=1).astype(np.float64)
        near = np.abs(s) < band
        idx, s = idx[near], s[near]
        out = normals[idx] - across[idx, None] * ray[idx]
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
        probe = v[idx] + out * (probe_px * z[idx] / focal[k, 0])[:, None] - centres[k]
        probe /= np.linalg.norm(probe, axis=1, keepdims=True)
        outer = ~rays.intersects_any(np.broadcast_to(centres[k], probe.shape).copy(), probe)
        idx, s, out = idx[outer], s[outer], out[outer]
        acc[idx] += (-s * z[idx] / focal[k, 0])[:, None] * out
        count[idx] += 1
        offsets += (np.abs(s).sum(), len(s))
    return acc, count, offsets


def fit_outline(mesh, cameras: Cameras, masks, *, rounds: int = 24, band: float = 3.0, step: float = 0.7,
                probe_px: float = 0.1, total=None) -> OutlineFit:
    """The outline of `mesh` moved onto `masks` at their own size (module doc).

    Args:
        mesh: a `Mesh`, a `trimesh.Trimesh` or `(vertices, faces)`, in the cameras' frame.
        cameras: the `Cameras` of `masks` (pinhole, their size the masks').
        masks: `(N, H, W)` object masks (> 0.5: object), one per camera.
        rounds: rounds of moves; band: only outline vertices within `band` pixels of a mask's
            edge move (farther ones are no outline the mask shows: a thin part, an occluding
            contour); step: the share of the mean move applied per round; probe_px: how far
            outward (pixels) a ray past a vertex must miss the mesh for the vertex to be on the outline.
        total: where the views are split over processes (each passing the same mesh with its own
            cameras and masks), a function summing an array over the processes
            (`jaxgenus.optim.summed_over_processes`): every process then makes the same moves. None:
            `cameras` are all the views.

    Returns:
        An `OutlineFit`; the input is not modified. The faces (and so the genus) are kept.
    """
    tm = as_trimesh(mesh)
    masks = np.asarray(masks)
    if masks.ndim != 3 or len(masks) != len(cameras) or masks.shape[1:] != (cameras.height, cameras.width):
        raise ValueError(f"masks: expected ({len(cameras)}, {cameras.height}, {cameras.width}) for the cameras, "
                         f"got {masks.shape}")
    masks = np.asarray(masks, np.float32)  # not copied when float32 (never written to)
    if not all(np.isfinite(m).all() for m in masks):
        raise ValueError("masks: must be finite")
    if not (isinstance(rounds, int) and rounds >= 0 and band > 0 and 0 < step <= 1 and probe_px > 0):
        raise ValueError(f"rounds >= 0, band > 0, 0 < step <= 1 and probe_px > 0 needed, got {rounds}, {band}, "
                         f"{step}, {probe_px}")
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))  # embree is float32: trace near the origin
    v0 = np.asarray(tm.vertices, np.float64) - shift
    faces = np.asarray(tm.faces, np.int64)
    r, t, focal, centre_px, centres = camera_arrays(cameras)
    arrays = (r, t, focal, centre_px, centres - shift)
    edges, size = _signed_edges(masks), (cameras.height, cameras.width)
    v, moved, before = v0.copy(), np.zeros(len(v0), bool), float("nan")
    moving = trimesh.Trimesh(v, faces, process=False)  # one mesh, its vertices set each round (`ray_intersector`)
    for k in range(rounds + 1):
        moving.vertices = v
        moves = _outline_moves(moving, arrays, size, edges, band, probe_px)
        acc, count, (total_px, n_px) = moves if total is None else (total(a) for a in moves)
        offset = total_px / n_px if n_px else float("nan")
        before = offset if k == 0 else before
        if k == rounds:
            break
        moved |= count > 0
        v = v + step * acc / np.maximum(count, 1)[:, None]
    if not np.isfinite(v).all():
        v, moved, offset = v0.copy(), np.zeros_like(moved), before
    return OutlineFit(v + shift, moved, np.linalg.norm(v - v0, axis=1), before, offset)
