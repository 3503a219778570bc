"""`genus_primitive`: smooth closed surfaces of any genus with well-shaped triangles.

* genus 0: a sphere, the convex hull of a spherical Fibonacci point set;
* genus 1: a torus, a staggered (triangular-lattice) grid on the torus;
* genus g >= 2: a flat plate with rounded rim and g round through-holes in a 2-D
  grid, extracted from its signed distance function with manifold3d's marching
  tetrahedra (`Manifold.level_set`).

Every mesh then goes through a few rounds of tangential relaxation (each vertex
slides towards the area-weighted centroid of its one-ring, then is projected
back onto the implicit surface along the SDF gradient), which lifts the small
angles left by marching tetrahedra. The shapes are built centred on the origin
and finally scaled to touch the sphere of radius `extent` from inside.

The signed distance functions below use only Python arithmetic operators and
`abs`, so the same function serves both manifold3d's scalar callback and the
vectorized numpy projection.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from jaxgenus.geometry._mesh import Mesh
from jaxgenus.geometry._topology import connected_components, euler_characteristic, is_closed_manifold

__all__ = ["genus_primitive"]

_MIN_FACES = 100
_MIN_FACES_PER_HOLE = 40
# Plate layout in plate units: hole radius, centre spacing, margin from the
# outermost hole edges to the rim, half-thickness (equal to the rim radius, so
# the rim is a half-circle in cross-section).
_HOLE_R = 1.0
_HOLE_SPACING = 3.2
_MARGIN = 1.2
_HALF_T = 0.45
_RELAX_ITERS = 8
_SAFE_EDGE = 0.3


def _smin(a, b):
    return 0.5 * (a + b - abs(a - b))


def _smax(a, b):
    return 0.5 * (a + b + abs(a - b))


def _sphere_sdf(x, y, z):
    return (x * x + y * y + z * z) ** 0.5 - 1.0


def _torus_sdf(major, minor):
    def sdf(x, y, z):
        q = (x * x + y * y) ** 0.5 - major
        return (q * q + z * z) ** 0.5 - minor

    return sdf


def _clamp(a, lo, hi):
    return _smin(_smax(a, lo), hi)


def _hole_grid(genus: int) -> tuple[int, int, int]:
    """`(rows, cols, holes in the last row)`: `floor(sqrt(genus))` rows, filled row by row."""
    rows = max(1, math.isqrt(genus))
    cols = -(-genus // rows)
    return rows, cols, genus - (rows - 1) * cols


def _plate_sdf(genus: int):
    """Signed distance (negative inside) of a rounded plate with `genus` round holes.

    Hole centres lie on a square grid of spacing `_HOLE_SPACING`, each row
    centred on x = 0 (the last row may hold fewer holes). Returns the SDF and
    the half-sizes of a box around the plate.
    """
    rows, cols, n_last = _hole_grid(genus)
    half_x = 0.5 * (cols - 1) * _HOLE_SPACING + _HOLE_R + _MARGIN
    half_y = 0.5 * (rows - 1) * _HOLE_SPACING + _HOLE_R + _MARGIN
    corner = _HOLE_R + _MARGIN
    inv = 1.0 / _HOLE_SPACING

    def sdf(x, y, z):
        # 2-D rounded rectangle, exact distance.
        qx = abs(x) - (half_x - corner)
        qy = abs(y) - (half_y - corner)
        ox, oy = _smax(qx, 0.0), _smax(qy, 0.0)
        d2 = (ox * ox + oy * oy) ** 0.5 + _smin(_smax(qx, qy), 0.0) - corner
        # Nearest hole: nearest row, then nearest hole within that row (`// 1`
        # is floor for floats and arrays alike). Holes of other rows are at
        # least _HOLE_SPACING / 2 away, too far to shape the surface.
        r = _clamp((y * inv + 0.5 * rows) // 1, 0.0, rows - 1.0)
        n = cols - (cols - n_last) * _clamp(r - (rows - 2.0), 0.0, 1.0)
        c = _clamp((x * inv + 0.5 * n) // 1, 0.0, n - 1.0)
        dx = x - (c - 0.5 * (n - 1.0)) * _HOLE_SPACING
        dy = y - (r - 0.5 * (rows - 1.0)) * _HOLE_SPACING
        d2 = _smax(d2, _HOLE_R - (dx * dx + dy * dy) ** 0.5)
        # The plate is the _HALF_T offset of the flat sheet {d2 <= -_HALF_T, z = 0},
        # so its rim is a half-circle in cross-section.
        w = _smax(d2 + _HALF_T, 0.0)
        return (w * w + z * z) ** 0.5 - _HALF_T

    return sdf, (half_x + 0.5, half_y + 0.5, _HALF_T + 0.5)


def _sphere(n_faces: int):
    """Convex hull of `n_faces / 2 + 2` spherical Fibonacci points (exactly `2N - 4` faces)."""
    from scipy.spatial import ConvexHull

    n = n_faces // 2 + 2
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    rho = np.sqrt(1.0 - z * z)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    v = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    f = ConvexHull(v).simplices.astype(np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    f[inward] = f[inward][:, ::-1]
    return v, f, _sphere_sdf


def _torus(n_faces: int, minor: float = 0.4):
    """Torus (major radius 1) on a staggered grid: every other ring is shifted by half a step."""
    n_v = max(4, 2 * round(0.5 * math.sqrt(n_faces * minor / math.sqrt(3.0))))
    n_u = max(3, round(n_faces / (2 * n_v)))
    j, i = np.meshgrid(np.arange(n_v), np.arange(n_u), indexing="ij")
    u = (i + 0.5 * (j % 2)) * (2.0 * math.pi / n_u)
    w = j * (2.0 * math.pi / n_v)
    rad = 1.0 + minor * np.cos(w)
    v = np.stack([rad * np.cos(u), rad * np.sin(u), minor * np.sin(w)], axis=-1).reshape(-1, 3)
    idx = lambda jj, ii: (jj % n_v) * n_u + (ii % n_u)  # noqa: E731
    j, i = j.ravel(), i.ravel()
    s = j % 2  # row j is shifted by half a step when s == 1
    t1 = np.stack([idx(j, i), idx(j, i + 1), idx(j + 1, i + s)], axis=1)
    t2 = np.stack([idx(j, i + 1 - s), idx(j + 1, i + 1), idx(j + 1, i)], axis=1)
    f = np.concatenate([t1, t2])
    return v, f, _torus_sdf(1.0, minor)


def _plate(genus: int, n_faces: int):
    """The plate with `genus` holes: marching tetrahedra, then decimation if too fine.

    The level-set edge length is capped at `_SAFE_EDGE` (a third of the plate
    thickness) so that marching tetrahedra resolves every hole; the face count
    is tuned through the edge length when that gives too few faces, and by
    topology-preserving edge collapses (`igl.decimate`) when it gives too many.
    """
    import igl
    import manifold3d

    sdf, bound = _plate_sdf(genus)
    box = [-bound[0], -bound[1], -bound[2], bound[0], bound[1], bound[2]]
    inside = lambda x, y, z: -sdf(x, y, z)  # noqa: E731  (manifold3d: positive inside)
    # First guess from the area of the plate's two faces (rims ignored).
    area = 8.0 * (bound[0] - 0.5) * (bound[1] - 0.5)
    h = min(_SAFE_EDGE, math.sqrt(4.0 * area / (math.sqrt(3.0) * n_faces)))
    good = None
    for _ in range(6):
        m = manifold3d.Manifold.level_set(inside, box, h)
        if m.genus() != genus or len(m.decompose()) != 1:
            h *= 0.8
            continue
        good = m
        ratio = m.num_tri() / n_faces
        if ratio > 0.92:
            break
        h *= math.sqrt(ratio)
    if good is None:  # pragma: no cover
        raise RuntimeError(f"marching tetrahedra failed for genus {genus}")
    mesh = good.to_mesh()
    v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    if len(f) > 1.08 * n_faces:
        v, f = igl.decimate(v, f, n_faces)[:2]
    return v, f, sdf


def _unit_normals(v, sdf, eps=1e-6):
    """`(V, 3)` unit SDF gradients at `v` (central differences)."""
    grad = np.empty_like(v)
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        grad[:, k] = (sdf(*(v + d).T) - sdf(*(v - d).T)) / (2.0 * eps)
    return grad / np.maximum(np.linalg.norm(grad, axis=1), 1e-12)[:, None]


def _project(v, sdf, steps: int = 2):
    """Move `v` onto the zero set of `sdf` by Newton steps along the SDF gradient."""
    for _ in range(steps):
        v = v - sdf(*v.T)[:, None] * _unit_normals(v, sdf)
    return v


def _min_angles(v, f):
    """`(F,)` smallest interior angle (radians) of every face."""
    p = v[f]
    best = np.full(len(f), np.pi)
    for k in range(3):
        e1 = p[:, (k + 1) % 3] - p[:, k]
        e2 = p[:, (k + 2) % 3] - p[:, k]
        ang = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.einsum("ij,ij->i", e1, e2))
        best = np.minimum(best, ang)
    return best


def _worst_angle_at_vertices(v, f):
    """`(V,)` smallest face angle among the faces around each vertex."""
    worst = np.full(len(v), np.pi)
    np.minimum.at(worst, f.ravel(), np.repeat(_min_angles(v, f), 3))
    return worst


def _relax(v, f, sdf, iters: int):
    """Tangential area-weighted relaxation with projection back onto the surface `sdf = 0`.

    Each vertex moves towards the area-weighted centroid of its one-ring faces,
    within the tangent plane given by the SDF gradient, and is then projected
    onto the zero set. A vertex whose move would shrink the smallest angle of
    its one-ring stays put, so the pass never makes the worst triangles worse.
    """
    nv = len(v)
    flat = f.ravel()
    for _ in range(iters):
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        cen = (a + b + c) / 3.0
        w = np.repeat(area, 3)
        wsum = np.bincount(flat, weights=w, minlength=nv)
        target = np.stack(
            [np.bincount(flat, weights=w * np.repeat(cen[:, k], 3), minlength=nv) for k in range(3)],
            axis=1,
        ) / wsum[:, None]
        normal = _unit_normals(v, sdf)
        d = target - v
        d -= np.einsum("ij,ij->i", d, normal)[:, None] * normal
        moved = _project(v + d, sdf)
        before = _worst_angle_at_vertices(v, f)
        for _retry in range(3):
            worse = _worst_angle_at_vertices(moved, f) < before
            if not worse.any():
                break
            moved[worse] = v[worse]
        v = moved
    return v


def _signed_volume(v, f) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c))) / 6.0


def _min_faces(genus: int) -> int:
    """Smallest `n_faces` that `genus_primitive` accepts for this genus."""
    return max(_MIN_FACES, _MIN_FACES_PER_HOLE * int(genus))


def _check_args(genus, n_faces, extent) -> None:
    if isinstance(genus, bool) or not isinstance(genus, numbers.Integral):
        raise ValueError(f"genus must be a non-negative integer, got {genus!r}")
    if genus < 0:
        raise ValueError(f"genus must be a non-negative integer, got {genus}")
    if isinstance(n_faces, bool) or not isinstance(n_faces, numbers.Integral):
        raise ValueError(f"n_faces must be an integer, got {n_faces!r}")
    if n_faces < _min_faces(genus):
        raise ValueError(
            f"n_faces must be >= max({_MIN_FACES}, {_MIN_FACES_PER_HOLE} * genus) = {_min_faces(genus)}"
            f" for genus {genus}, got {n_faces}"
        )
    if isinstance(extent, bool) or not isinstance(extent, numbers.Real) or not (0.0 < extent < math.inf):
        raise ValueError(f"extent must be a finite number > 0, got {extent!r}")


def genus_primitive(genus: int, *, n_faces: int = 5000, extent: float = 1.0) -> Mesh:
    """A smooth closed surface of the given genus, for initializing reconstructions.

    Args:
        genus: number of handles, an integer >= 0. 0 gives a sphere, 1 a torus,
            g >= 2 a rounded plate with g through-holes in a 2-D grid.
        n_faces: approximate face count (within about 10%; the torus rounds
            to its grid), at least `max(100, 40 * genus)`.
        extent: the mesh is centred at the origin and scaled to touch the
            sphere of this radius from inside.

    Returns:
        A watertight, single-component, outward-oriented `Mesh` without padding,
        with Euler characteristic `2 - 2 * genus`. The construction is
        deterministic.
    """
    _check_args(genus, n_faces, extent)
    genus, n_faces = int(genus), int(n_faces)
    if genus == 0:
        v, f, sdf = _sphere(n_faces)
    elif genus == 1:
        v, f, sdf = _torus(n_faces)
    else:
        v, f, sdf = _plate(genus, n_faces)
    v = _relax(v, f, sdf, _RELAX_ITERS)
    if _signed_volume(v, f) < 0:
        f = f[:, ::-1]
    # All three shapes are built centred on the origin; scale to touch the ball.
    v *= float(extent) / np.linalg.norm(v, axis=1).max()
    mesh = Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32))
    if not (
        is_closed_manifold(mesh)
        and euler_characteristic(mesh) == 2 - 2 * genus
        and connected_components(mesh)[0] == 1
    ):  # pragma: no cover  (a construction bug, never a user error)
        raise RuntimeError(f"genus_primitive built a bad mesh for genus {genus}")
    return mesh
