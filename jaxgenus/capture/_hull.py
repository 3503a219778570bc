"""The silhouettes' visual hull: its bounds, its mesh, and measurements of it.

Host-side numpy and manifold3d (outside `jit`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh
from jaxgenus.capture._targets import check_targets, unit_float
from jaxgenus.geometry import connected_components

__all__ = ["HullOccupancy", "carved_points", "check_region", "cut_views", "hull_occupancy", "hull_thickness",
           "largest_component", "region_misses", "visual_hull", "visual_hull_bounds"]


def check_region(region) -> tuple[np.ndarray, float] | None:
    """`region` checked: None, or `(centre (3,), radius)` of a sphere (float64 centre, float radius > 0)."""
    if region is None:
        return None
    try:
        centre, radius = region
        centre, radius = np.asarray(centre, np.float64), float(radius)
    except (TypeError, ValueError):
        raise ValueError(f"region: expected (centre (3,), radius) of a sphere, got {region!r}") from None
    if centre.shape != (3,) or not np.isfinite(centre).all() or not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"region: expected a finite centre (3,) and a radius > 0, got {centre.tolist()}, {radius!r}")
    return centre, radius


def region_misses(alpha, cams: Cameras, region, *, step: int = 4) -> np.ndarray:
    """`(N,)`: per view, the share of its silhouette (alpha >= 0.5, every `step`-th pixel each way)
    whose rays miss the sphere `region = (centre, radius)`. An object inside the sphere gives 0;
    a sphere that cuts the object, or one in other units than the cameras, more. Host-side."""
    centre, radius = check_region(region)
    rot, trans, focal, pp = _camera_numpy(cams)
    eyes = -np.einsum("nji,nj->ni", rot, trans)
    out = np.zeros(len(cams))
    for i in range(len(cams)):
        rows, cols = np.nonzero(unit_float(np.asarray(alpha[i])[::step, ::step]) >= 0.5)
        if not len(rows):
            continue
        u, v = cols * step + 0.5, rows * step + 0.5
        d = np.stack([(u - pp[i, 0]) / focal[i, 0], (v - pp[i, 1]) / focal[i, 1], np.ones(len(u))], 1) @ rot[i]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        oc = eyes[i] - centre
        b = d @ oc
        disc = b * b - (oc @ oc - radius * radius)
        hit = (disc >= 0) & (np.sqrt(np.maximum(disc, 0.0)) - b >= 0)  # the far crossing lies ahead
        out[i] = 1.0 - hit.mean()
    return out


def _in_region(points: np.ndarray, region) -> np.ndarray:
    """Soft membership of `points` in the sphere `region` (None: 1 everywhere), as an occupancy: 0.5 on
    the sphere, from 1 to 0 across a shell of 1/64 of its radius."""
    if region is None:
        return np.ones(len(points))
    centre, radius = region
    return np.clip(0.5 + (radius - np.linalg.norm(points - centre, axis=1)) * (64.0 / radius), 0.0, 1.0)


def visual_hull_bounds(alpha, cams: Cameras, *, resolution: int = 48, region=None) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds `(lo, hi)` of the visual hull of silhouettes `alpha (N, H, W)`
    (within the sphere `region`, see `carved_points`).

    The bounding box of `carved_points`, grown by one grid cell. Host-side numpy.
    """
    pts, cell = carved_points(alpha, cams, resolution=resolution, region=region)
    return pts.min(0) - cell, pts.max(0) + cell


def cut_views(alpha) -> np.ndarray:
    """`(N,)` bool: the views whose silhouette (alpha >= 0.5) touches the image border, so the
    object may run out of the frame there: such a view says nothing of what projects outside it."""
    a = np.asarray(alpha) >= 0.5
    return a[:, 0, :].any(1) | a[:, -1, :].any(1) | a[:, :, 0].any(1) | a[:, :, -1].any(1)


def _camera_numpy(cams: Cameras) -> tuple[np.ndarray, ...]:
    """`(rotation, translation, focal, principal_point)` as float64 numpy, read once per pass over the views
    (indexing the cameras' jax arrays view by view costs more than the projection)."""
    return tuple(np.asarray(a, np.float64) for a in (cams.rotation, cams.translation, cams.focal,
                                                     cams.principal_point))


def _pixels(cams: tuple[np.ndarray, ...], i: int, points: np.ndarray):
    """Continuous pixel coordinates `(u, v)` of `points` in view `i` (cameras as `_camera_numpy`) and
    whether they lie in front of it."""
    rot, trans, focal, pp = (a[i] for a in cams)
    xc = points @ rot.T + trans
    front = xc[:, 2] > 1e-9
    z = np.where(front, xc[:, 2], 1.0)
    return xc[:, 0] / z * focal[0] + pp[0], xc[:, 1] / z * focal[1] + pp[1], front


def _axes_centre(cams: Cameras) -> tuple[np.ndarray, float]:
    """The point closest to every optical axis, and the radius of the ball around it every camera sees."""
    rot = np.asarray(cams.rotation, np.float64)
    trans = np.asarray(cams.translation, np.float64)
    centers = -np.einsum("nji,nj->ni", rot, trans)
    axes = rot[:, 2, :]
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]  # sum (I - d d^T) (p - c) = 0
    centre = np.linalg.lstsq(proj.sum(0), np.einsum("nij,nj->i", proj, centers), rcond=None)[0]
    dist = np.linalg.norm(centers - centre, axis=1)
    half_fov = np.arctan(0.5 * min(cams.height, cams.width) / np.asarray(cams.focal).max())
    return centre, float(dist.min() * np.sin(half_fov) * 1.05)


def _enough(n_views: int) -> int:
    """Silhouettes that must cover a point of a hull cut by the frame: a quarter of the views, two at
    least (one of one). Fewer leave it unbounded along the rays of the few views that see a point
    (a 16-view torus cut in every view: hull silhouette IoU 0.88 with two, 0.98 with a quarter;
    with half, the hull stops short of the object)."""
    return max(min(2, n_views), int(np.ceil(0.25 * n_views)))


def _carved(alpha: np.ndarray, cams: Cameras, grid: np.ndarray, cut: np.ndarray, region=None) -> np.ndarray:
    """The grid points inside every view's silhouette (and inside the sphere `region`); a view whose
    silhouette touches its border keeps what projects outside it, and a point must lie inside
    `_enough` silhouettes."""
    inside = _in_region(grid, region) >= 0.5
    seen = np.zeros(len(grid), np.int32)
    h, w = cams.height, cams.width
    arrays = _camera_numpy(cams)
    for i in range(len(cams)):
        u, v, front = _pixels(arrays, i, grid)
        u, v = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        ok = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        hit = np.zeros(len(grid), bool)
        hit[ok] = alpha[i, v[ok], u[ok]] >= 0.5
        seen += hit
        inside &= hit | (~ok & cut[i])
    return inside & (seen >= _enough(len(cams)))


def carved_points(alpha, cams: Cameras, *, resolution: int = 48, region=None) -> tuple[np.ndarray, float]:
    """The points of a `resolution^3` grid inside the visual hull of `alpha (N, H, W)`, and the grid step.

    The grid spans the region every camera sees (around the least-squares intersection of the
    optical axes), grown (up to 1.5^3 times) while the hull reaches its boundary; a point survives
    when it projects inside the silhouette (alpha >= 0.5) of every view (views cut by the frame,
    `cut_views`: of every view it projects into, and of a quarter of the views at least; then
    only the largest connected piece). `region = (centre, radius)`: the object lies inside this
    sphere (IDR/NeuS's unit sphere, `load_region`); the grid spans it and nothing outside it
    survives, so what views cut by the frame leave open ends there. Raises `ValueError` when
    no point survives.
    """
    alpha = np.asarray(alpha, np.float32)
    region = check_region(region)
    centre, radius = _axes_centre(cams) if region is None else region
    cut = cut_views(alpha)
    for _ in range(1 if region is not None else 4):
        ticks = np.linspace(-radius, radius, resolution)
        grid = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), -1).reshape(-1, 3) + centre
        inside = _carved(alpha, cams, grid, cut, region)
        if not inside.any():
            raise ValueError("images: the silhouettes are inconsistent with cams (their visual hull is empty): are the "
                             "images paired with the right cameras, and do the intrinsics match the images' size?")
        if cut.any():  # what few views see can float apart from the object: keep the largest piece
            inside = _largest_piece(inside.reshape((resolution,) * 3)).ravel()
        idx = np.argwhere(inside.reshape(resolution, resolution, resolution))
        if idx.min() > 0 and idx.max() < resolution - 1:
            break
        radius *= 1.5
    return grid[inside], 2.0 * radius / (resolution - 1)


def _largest_piece(occupied: np.ndarray) -> np.ndarray:
    """The largest 26-connected piece of a boolean grid."""
    from scipy import ndimage

    labels, n = ndimage.label(occupied, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return occupied
    return labels == (np.argmax(np.bincount(labels.ravel())[1:]) + 1)


def _hull_occupancy(alpha: np.ndarray, cams: Cameras, points: np.ndarray, region=None) -> np.ndarray:
    """Soft visual-hull occupancy of `points (P, 3)`: the minimum over views of the bilinearly
    interpolated silhouette at their projections (0 outside an image; a view cut by the frame
    says nothing there, and then a point needs a quarter of the views' silhouettes), and of the
    membership of the sphere `region` (`_in_region`)."""
    h, w = cams.height, cams.width
    cut = cut_views(alpha)
    occ = _in_region(points, region)
    seen = np.zeros(len(points), np.int32)
    arrays = _camera_numpy(cams)
    for i in range(len(cams)):
        u, v, front = _pixels(arrays, i, points)
        u, v = u - 0.5, v - 0.5  # pixel centres sit at +0.5: continuous coordinates of the sample grid
        ok = front & (u > -1) & (u < w) & (v > -1) & (v < h)
        u, v = np.clip(u, -1, w), np.clip(v, -1, h)
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - u0, v - v0
        pad = np.pad(alpha[i], 1, mode="edge" if cut[i] else "constant")  # samples -1 and w: background or the edge

        def at(r, c):
            return pad[np.clip(r + 1, 0, h + 1), np.clip(c + 1, 0, w + 1)]

        val = ((1 - fv) * ((1 - fu) * at(v0, u0) + fu * at(v0, u0 + 1))
               + fv * ((1 - fu) * at(v0 + 1, u0) + fu * at(v0 + 1, u0 + 1)))
        seen += ok & (val >= 0.5)
        occ = np.minimum(occ, np.where(ok, val, 1.0 if cut[i] else 0.0))
    if not cut.any():  # every view bounds the object: the minimum alone is the hull
        return occ
    return np.where(seen >= _enough(len(cams)), occ, np.minimum(occ, 0.0))


class HullOccupancy(NamedTuple):
    """The visual hull's soft occupancy on a grid (`hull_occupancy`).

    Attributes:
        values: `(nx, ny, nz)` occupancy in [0, 1] at the grid points.
        lo: `(3,)` the first grid point; cell: the grid step; hi: `(3,)` the upper corner of
            the box the surface is extracted in.
    """

    values: np.ndarray
    lo: np.ndarray
    cell: float
    hi: np.ndarray


def hull_occupancy(images, cams: Cameras, *, resolution: int = 64, bounds=None, region=None) -> HullOccupancy:
    """The soft occupancy of the silhouettes' visual hull (minimum over views of the bilinearly
    sampled silhouette) on a grid of `resolution` cells along the longest side of `bounds`
    (default `visual_hull_bounds`; pass them to reuse them), two cells of margin; within the
    sphere `region` (`carved_points`) when one is given. Host-side."""
    alpha = check_targets(images, cams).alpha
    region = check_region(region)
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 8:
        raise ValueError(f"resolution must be an int >= 8, got {resolution!r}")
    lo, hi = (visual_hull_bounds(alpha, cams, region=region) if bounds is None
              else (np.asarray(b, np.float64) for b in bounds))
    cell = float((hi - lo).max()) / resolution
    lo, hi = lo - 2 * cell, hi + 2 * cell
    shape = np.ceil((hi - lo) / cell).astype(int) + 1
    axes = [lo[d] + cell * np.arange(shape[d]) for d in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return HullOccupancy(_hull_occupancy(alpha, cams, grid, region).reshape(shape), lo, cell, hi)


def _trilinear(phi: np.ndarray, lo: np.ndarray, cell: float, points: np.ndarray) -> np.ndarray:
    """The grid `phi` (samples at `lo + cell * i`) interpolated at `points (P, 3)`, -0.5 past its
    last cells; the arithmetic of `_point_field`, in the same order (the same float64 values)."""
    f = (points - lo) * (1.0 / cell)
    i = np.trunc(f).astype(np.int64)
    n = np.array(phi.shape)
    out = np.any((i < 0) | (i >= n - 1), axis=1)
    i = np.where(out[:, None], 0, i)
    fx, fy, fz = (f - i).T
    flat = phi.ravel()
    sy, sx = n[2], n[1] * n[2]
    b = i[:, 0] * sx + i[:, 1] * sy + i[:, 2]
    c00 = flat[b] * (1 - fz) + flat[b + 1] * fz
    c01 = flat[b + sy] * (1 - fz) + flat[b + sy + 1] * fz
    c10 = flat[b + sx] * (1 - fz) + flat[b + sx + 1] * fz
    c11 = flat[b + sx + sy] * (1 - fz) + flat[b + sx + sy + 1] * fz
    return np.where(out, -0.5, (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx)


def _point_field(phi: np.ndarray, lo: np.ndarray, cell: float):
    """`field(x, y, z)`: the trilinear interpolation of `phi`, one Python call per point."""
    flat = phi.ravel().tolist()
    nx, ny, nz = (int(s) for s in phi.shape)
    sy, sx = nz, ny * nz
    x0, y0, z0 = (float(c) for c in lo)
    inv = 1.0 / cell

    def field(x, y, z):
        fx, fy, fz = (x - x0) * inv, (y - y0) * inv, (z - z0) * inv
        i, j, k = int(fx), int(fy), int(fz)
        if i < 0 or j < 0 or k < 0 or i >= nx - 1 or j >= ny - 1 or k >= nz - 1:
            return -0.5
        fx, fy, fz = fx - i, fy - j, fz - k
        b = i * sx + j * sy + k
        c00 = flat[b] * (1 - fz) + flat[b + 1] * fz
        c01 = flat[b + sy] * (1 - fz) + flat[b + sy + 1] * fz
        c10 = flat[b + sx] * (1 - fz) + flat[b + sx + 1] * fz
        c11 = flat[b + sx + sy] * (1 - fz) + flat[b + sx + sy + 1] * fz
        return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx

    return field


def _lattice_points(lo: np.ndarray, hi: np.ndarray, cell: float) -> np.ndarray:
    """The points manifold3d's level set over the box `[lo, hi]` at edge length `cell` evaluates,
    in the order it asks for them: a body-centred lattice of `floor(extent / cell)` steps a side,
    for each index (row-major) the cube corner half a step below it, then (inside the box) the
    lattice point itself."""
    steps = np.floor((hi - lo) / cell).astype(np.int64)
    step = (hi - lo) / steps
    idx = np.stack(np.meshgrid(*(np.arange(s + 2) for s in steps), indexing="ij"), -1).reshape(-1, 3)
    centre = np.all(idx <= steps, axis=1)
    at = np.arange(len(idx)) + np.cumsum(centre) - centre  # each corner after the points before it
    points = np.empty((len(idx) + int(centre.sum()), 3))
    points[at] = lo + (idx - 0.5) * step
    points[at[centre] + 1] = lo + idx[centre] * step
    return points


def _lattice_field(phi: np.ndarray, lo: np.ndarray, cell: float, hi: np.ndarray):
    """`field(x, y, z)` for manifold3d's level set of the trilinear interpolation of `phi` over
    `[lo, hi]`: the values at every point it will ask for are computed at once (`_lattice_points`,
    `_trilinear`) and handed out in that order, checked against the point asked (a Python
    interpolation per point took most of a small fit's time); a point off that order is
    interpolated as asked, from then on."""
    slow = _point_field(phi, lo, cell)
    if np.any(np.floor((hi - lo) / cell) < 1):  # a box thinner than a cell: no lattice to lay
        return slow
    points = _lattice_points(lo, hi, cell)
    values = _trilinear(phi, lo, cell, points).tolist()
    xs = points[:, 0].tolist()
    state = [0, True]  # the next point's index; still in order

    def field(x, y, z):
        n = state[0]
        if state[1] and n < len(xs) and xs[n] == x:
            state[0] = n + 1
            return values[n]
        state[1] = False
        return slow(x, y, z)

    return field


def visual_hull(images, cams: Cameras, *, resolution: int = 64, closing: int = 0, bounds=None,
                occupancy: HullOccupancy | None = None, region=None):
    """Watertight `Mesh` of the visual hull of the silhouettes in `images`.

    `images` as in `reconstruct` (`(N, H, W, 4)` RGBA or `(N, H, W)` alpha). The soft
    occupancy (`hull_occupancy` at `resolution` within `bounds` and the sphere `region`, or the
    `occupancy` given, which then replaces all three) is closed by `closing > 0` cells (a grey-level morphological
    closing with a ball: fills thin spurious tunnels left by carving, and real holes that
    thin). Its 0.5 level set is extracted with manifold3d's marching tetrahedra, so the mesh
    is a closed manifold; it may have several components, and holes thinner than about a
    grid cell close up. Host-side.
    """
    import manifold3d

    if isinstance(closing, bool) or not isinstance(closing, int) or closing < 0:
        raise ValueError(f"closing must be an int >= 0, got {closing!r}")
    if occupancy is None:
        occupancy = hull_occupancy(images, cams, resolution=resolution, bounds=bounds, region=region)
    occ, lo, cell = np.array(occupancy.values, np.float64), np.asarray(occupancy.lo, np.float64), occupancy.cell
    hi = np.asarray(occupancy.hi, np.float64)
    if closing:
        from scipy import ndimage

        ball = np.linalg.norm(np.mgrid[-closing : closing + 1, -closing : closing + 1, -closing : closing + 1], axis=0)
        occ = ndimage.grey_closing(occ, footprint=ball <= closing + 1e-9)
    occ = occ - 0.5
    occ[0, :, :] = occ[-1, :, :] = occ[:, 0, :] = occ[:, -1, :] = occ[:, :, 0] = occ[:, :, -1] = -0.5
    m = manifold3d.Manifold.level_set(_lattice_field(occ, lo, cell, hi), [*lo, *hi], cell)
    mesh = m.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float32)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int32)
    if len(f) == 0:
        raise ValueError("images: the visual hull is empty at this resolution")
    return Mesh.from_numpy(v, f)


def largest_component(mesh: Mesh) -> Mesh:
    """The connected component of `mesh` with the most faces (the mesh itself when it has one)."""
    n, labels = connected_components(mesh)
    if n == 1:
        return mesh
    v, f = mesh.to_numpy()
    f = f[labels == np.bincount(labels).argmax()]
    used, f = np.unique(f, return_inverse=True)
    return Mesh.from_numpy(v[used], f.reshape(-1, 3))


def hull_thickness(alpha, cams: Cameras, resolution: int, pixel: float, *, hull: Mesh | None = None) -> float:
    """`2 * volume / area` of the largest piece of the visual hull, in units of `pixel` (inf if none).

    A slab's thickness, a tube's radius: how thin the object looks to the cameras. `hull`: that
    largest piece, when it was built already (then `alpha`, `cams` and `resolution` are not read).
    """
    if hull is None:
        try:
            hull = largest_component(visual_hull(alpha, cams, resolution=resolution))
        except ValueError:
            return math.inf
    v, f = hull.to_numpy()
    v = v.astype(np.float64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return float(2.0 * abs(volume) / area / pixel) if area > 0 else math.inf
