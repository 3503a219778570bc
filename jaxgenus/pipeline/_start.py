"""The start of a reconstruction: a closed mesh of the requested genus placed in the object's bounds.

`start_mesh` takes, for `options.start == "auto"`, the silhouettes' visual hull
when its largest component has the requested genus (a few grids and closings are
tried) or fewer handles (the missing ones are drilled as small tunnels just under
its surface, `drill_tunnels`), else `genus_primitive(genus)` fitted into the
hull's bounds (its longest axis along the hull's longest axis, its thinnest
along the thinnest); `"primitive"` always takes the primitive and `"sphere"` a
genus-0 one. Host-side (numpy, manifold3d, the numpy remesher).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.capture import hull_occupancy, largest_component, visual_hull
from jaxgenus.geometry import Mesh, capacity_bucket, piece_count
from jaxgenus.pipeline._history import GenusEstimate, GenusEvidence, HandleRecord
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.geometry import genus_primitive
from jaxgenus.geometry import RemeshOptions, remesh
from jaxgenus.geometry import connected_components, euler_characteristic, genus as mesh_genus

__all__ = ["CLOSINGS", "HullTable", "Start", "drill_tunnels", "estimate_genus", "persistent_genus", "remeshed_start",
           "start_mesh"]


@dataclasses.dataclass(frozen=True)
class Start:
    """A start mesh and where it came from.

    Attributes:
        mesh: closed manifold `Mesh` in the capacity bucket of `options.face_budget`.
        kind: `"visual_hull"`, `"visual_hull+tunnels"`, `"primitive"`, `"sphere"`, or
            `"fit+images"` (`+tunnels`) when hidden handles were opened from the images;
            `+refit` per refit.
        hull_grid: `(resolution, closing)` of the visual hull used, or None.
        tunnels: handles drilled because no image showed them.
        handles: per handle, where it came from (`HandleRecord`; empty until the start
            stage fills it in).
    """

    mesh: Mesh
    kind: str
    hull_grid: tuple[int, int] | None
    tunnels: int
    handles: tuple[HandleRecord, ...] = ()


class HullTable:
    """The largest component of the visual hull and its genus per `(resolution, closing)`, built on
    first use within `bounds` (the hull's bounds, computed once) and the sphere `region` (None: no
    bound). One table serves one run (the
    genus estimate, the thin-structure test and the start share its hulls); the occupancy grid of
    a resolution is sampled once and closed as each closing asks."""

    def __init__(self, alpha, cams: Cameras, bounds, carve=None, region=None):
        self._alpha, self._cams, self._bounds, self._built, self._grids = alpha, cams, bounds, {}, {}
        self._region = region
        self._carve = carve  # None, or a map of a `HullOccupancy` to the one the fit starts from

    def occupancy(self, resolution: int):
        """The occupancy grid of `resolution` (carved when the table was given `carve`)."""
        if resolution not in self._grids:
            grid = hull_occupancy(self._alpha, self._cams, resolution=resolution, bounds=self._bounds,
                                  region=self._region)
            self._grids[resolution] = grid if self._carve is None else self._carve(grid)
        return self._grids[resolution]

    def get(self, resolution: int, closing: int) -> tuple[Mesh | None, int]:
        """`(hull, genus)`, or `(None, -1)` when there is no hull at that grid."""
        key = (resolution, closing)
        if key not in self._built:
            try:
                hull = largest_component(visual_hull(self._alpha, self._cams, closing=closing,
                                                     occupancy=self.occupancy(resolution)))
                self._built[key] = (hull, mesh_genus(hull))
            except ValueError:
                self._built[key] = (None, -1)
        return self._built[key]


CLOSINGS = (0, 1, 2, 3)


def persistent_genus(values) -> int:
    """The genus a grid's hulls keep longest as the closing grows: `values[c]` is the genus of the
    hull closed by `c` cells (-1: none); the value of the longest run of consecutive closings
    (ties: the lower genus; -1 when there is no hull). Carving leaves thin spurious tunnels that
    a closing of a cell or two fills; a hole the object has stays open over several closings."""
    best, best_len, run, prev = -1, 0, 0, None
    for g in values:
        run = run + 1 if (g == prev and g >= 0) else (1 if g >= 0 else 0)
        prev = g
        if g >= 0 and (run > best_len or (run == best_len and g < best)):
            best, best_len = g, run
    return best


def estimate_genus(hulls: HullTable, resolutions: tuple[int, ...]) -> GenusEstimate:
    """The object's genus as the silhouettes show it (a `GenusEstimate`).

    On each grid of `resolutions`, the genus of the visual hull's largest component after
    closings of 0 to 3 cells; the grid's genus is the one that persists over the most
    consecutive closings (`persistent_genus`). The estimate is the most frequent of the grids'
    (ties: the lower), `agreement` the share of grids that have it, and `plausible` every
    genus some grid has. Holes that no silhouette shows are not counted. `evidence` has a
    `GenusEvidence` for every hull (genus -1: no hull).
    """
    evidence = tuple(GenusEvidence(r, c, hulls.get(r, c)[1]) for r in resolutions for c in CLOSINGS)
    per_grid = [persistent_genus([e.genus for e in evidence if e.resolution == r]) for r in resolutions]
    found = [g for g in per_grid if g >= 0]
    if not found:
        raise ValueError("images: no visual hull could be built from the silhouettes to estimate the genus")
    values, counts = np.unique(found, return_counts=True)
    best = int(np.argmax(counts))
    return GenusEstimate(int(values[best]), float(counts[best] / len(found)), evidence,
                         tuple(int(v) for v in values))


def start_mesh(hulls: HullTable, genus: int, bounds, edge_length: float, options: ReconstructOptions) -> Start:
    """The start of a run (see the module doc).

    Args:
        hulls: the run's `HullTable` (its silhouettes and cameras).
        genus: the requested genus.
        bounds: `(lo, hi)` of the visual hull (world units).
        edge_length: target edge length of the hull start (world units).
        options: `ReconstructOptions` (`start`, `hull_resolutions`, `max_faces`, `initial_faces`).
    """
    if options.start == "auto":
        mesh, grid, tunnels = _hull_start(hulls, genus, edge_length, options)
        if mesh is not None:
            return Start(mesh, "visual_hull+tunnels" if tunnels else "visual_hull", grid, tunnels)
    lo, hi = bounds
    kind = "sphere" if options.start == "sphere" else "primitive"
    return Start(_primitive_start(genus, lo, hi, options), kind, None, 0)


def _axis_fit(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Map vertices into the box [lo, hi], matching axes by extent (longest to longest).

    The axis permutation is completed by a mirror when it is odd, so the map is
    orientation-preserving (outward normals stay outward).
    """
    vlo, vhi = v.min(0), v.max(0)
    src = np.argsort(vhi - vlo)
    dst = np.argsort(hi - lo)
    perm = np.empty(3, int)
    perm[dst] = src  # output axis d takes input axis perm[d]
    odd = np.linalg.det(np.eye(3)[perm]) < 0
    out = np.empty_like(v)
    for d in range(3):
        s = perm[d]
        t = (v[:, s] - vlo[s]) / max(vhi[s] - vlo[s], 1e-12)
        if odd and d == dst[0]:
            t = 1.0 - t  # mirror the thinnest axis
        out[:, d] = lo[d] + t * (hi[d] - lo[d])
    return out


def drill_tunnels(hull: Mesh, count: int, size: float) -> Mesh | None:
    """`hull` with `count` small handles: U-shaped tunnels just under its surface.

    The silhouettes cannot show handles whose holes no view sees through (eyelets,
    hooks, holes in a concave region), so the visual hull can have a lower genus
    than the object. Each missing handle is added where it changes the shape the
    least: a thin half-ring tunnel (ring radius `size`, tube radius `0.3 size`)
    that dives under the surface and comes back up `2 size` further on, cut by
    subtracting a torus centred on the surface, with manifold3d's exact booleans.
    The sites are spread over the surface by farthest-point sampling of surface
    samples; a cut is kept only when it raises the genus by exactly one and
    leaves one piece. Returns
    `None` when fewer than `count` fit. Host-side, deterministic.
    """
    import manifold3d
    import trimesh

    v, f = hull.to_numpy()
    tm = trimesh.Trimesh(v.astype(np.float64), f, process=False)
    pts, fid = trimesh.sample.sample_surface_even(tm, 2000, seed=0)
    normals = tm.face_normals[fid]
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v.astype(np.float32), tri_verts=f.astype(np.uint32)))
    ring = manifold3d.Manifold.revolve(manifold3d.CrossSection.circle(0.3 * size, 12).translate([size, 0.0]), 16)
    dist = np.linalg.norm(pts - pts.mean(0), axis=1)  # farthest-point order, from the extreme sample
    added = 0
    for _ in range(min(len(pts), 8 * count)):
        if added == count:
            break
        i = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(pts - pts[i], axis=1))
        n = normals[i]
        t = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        t /= np.linalg.norm(t)
        # ring plane spanned by the tangent t (local x) and the normal n (local y)
        cut = solid - ring.transform(np.column_stack([t, n, np.cross(t, n), pts[i]]))
        if cut.genus() == solid.genus() + 1 and piece_count(cut) == 1:
            solid = cut
            added += 1
    if added < count:
        return None
    out = solid.to_mesh()
    return Mesh.from_numpy(np.asarray(out.vert_properties, np.float32)[:, :3], np.asarray(out.tri_verts, np.int32))


def _hull_start(hulls: HullTable, genus: int, target: float, options: ReconstructOptions):
    """The visual hull as a start mesh, with the requested genus.

    Tries the grid sizes `options.hull_resolutions` with a grey-level closing of
    0 to 3 cells (closing fills the spurious thin tunnels carving leaves; it stops
    once no grid reaches the genus: closing only removes handles). When no hull
    has the genus but one has fewer handles, the missing ones are drilled as thin
    small tunnels (`drill_tunnels`, size `target`) into the one with the most.
    Returns `(mesh, (resolution, closing), tunnels)` or `(None, None, 0)`. The
    start is remeshed to edge length `target` (world units) within the face budget.
    """

    def remeshed(hull):
        return remeshed_start(hull, genus, target, options)

    below = []  # (genus, order, hull, grid) of hulls with fewer handles than requested
    for closing in (0, 1, 2, 3):
        highest = -1
        for res in options.hull_resolutions:
            hull, g = hulls.get(res, closing)
            if hull is None:
                continue
            highest = max(highest, g)
            if g < genus:
                below.append((-g, len(below), hull, (res, closing)))
            if g != genus:
                continue
            m = remeshed(hull)
            if m is not None:
                return m, (res, closing), 0
        if highest < genus:
            break
    for neg_g, _, hull, grid in sorted(below, key=lambda b: b[:2]):
        drilled = drill_tunnels(hull, genus + neg_g, target)
        m = None if drilled is None else remeshed(drilled)
        if m is not None:
            return m, grid, genus + neg_g
    return None, None, 0


def _sliver_share(v: np.ndarray, f: np.ndarray, degrees: float = 5.0) -> float:
    """The share of the faces whose smallest angle is below `degrees`."""
    p = v[f].astype(np.float64)
    cos_max = np.full(len(f), -1.0)
    for k in range(3):
        e1, e2 = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        cos = np.einsum("ij,ij->i", e1, e2) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) + 1e-30)
        cos_max = np.maximum(cos_max, cos)
    return float(np.mean(cos_max > np.cos(np.radians(degrees))))


def remeshed_start(mesh: Mesh, genus: int, target: float, options: ReconstructOptions) -> Mesh | None:
    """`mesh` remeshed to edge length `target` within `options.face_budget`, padded to its
    capacity bucket; None unless the result is one closed piece of genus `genus`.

    A mesh with sharp creases or large flat walls (a boolean cut) can need several times the
    budget at `target`; the remesher, capped part way through a split pass, then leaves long
    edges that block the collapses and a start full of slivers. So when the capped remesh has
    more than 1 % of its faces under 5 degrees or reaches the budget, the mesh is remeshed
    without a cap at the edge length at which its area holds 4/5 of the budget (not shorter
    than `target`), longer by the square root of any excess, or by 1.25x while slivers remain;
    up to three more times. The best shaped valid remesh below the budget is returned (one at
    the budget only when none is below it). The edge lengths tried after the first depend on the
    mesh and the budget alone: where the budget, not `target`, limits the detail, images of two
    sizes give the same start."""
    budget, best = options.face_budget, None

    def scored(m):
        nonlocal best
        v, f = m.to_numpy()
        if len(f) > budget or euler_characteristic(m) != 2 - 2 * genus or connected_components(m)[0] != 1:
            return None
        rank = (len(f) >= 0.98 * budget, _sliver_share(v, f))
        if best is None or rank < best[0]:
            best = (rank, v, f)
        return rank

    rank = scored(remesh(mesh, RemeshOptions(target_edge_length=target, iterations=5, max_faces=budget))[0])
    if rank is None or rank[0] or rank[1] > 0.01:
        v, f = mesh.to_numpy()
        area = 0.5 * float(np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())
        edge = max(target, float(np.sqrt(4.0 * area / (np.sqrt(3.0) * 0.8 * budget))))
        for _ in range(3):
            m, _ = remesh(mesh, RemeshOptions(target_edge_length=edge, iterations=10, max_faces=None))
            faces = int(m.to_numpy()[1].shape[0])
            if faces > budget:
                edge *= float(np.sqrt(faces / (0.8 * budget)))
                continue
            rank = scored(m)
            if rank is not None and rank[1] <= 0.01:
                break
            edge *= 1.25
    if best is None:
        return None
    return Mesh.from_numpy(best[1].astype(np.float32), best[2], capacity=capacity_bucket(budget))


def _primitive_start(genus: int, lo, hi, options: ReconstructOptions) -> Mesh:
    g = 0 if options.start == "sphere" else genus
    prim = genus_primitive(g, n_faces=options.initial_faces)
    v, f = prim.to_numpy()
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    # shrink slightly inside the hull: the silhouettes then pull the surface outwards
    v = _axis_fit(v, centre - 0.9 * half, centre + 0.9 * half)
    return Mesh.from_numpy(v.astype(np.float32), f, capacity=capacity_bucket(max(options.face_budget, len(f))))
