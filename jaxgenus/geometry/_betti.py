"""Where a result's handles are: Betti numbers of solids on a voxel grid.

A correct genus says nothing about *where* the handles are. Two solids with the
same genus have their handles in the same places when the Betti numbers of
their intersection and their union equal theirs: a handle of the result that
is not the object's own adds a loop to the union (it bridges over the object's
hole, b1 of the union rises) or breaks one in the intersection (b1 falls).

The solids are voxelized on one grid (winding number > 1/2 at the voxel
centres) and each voxel is a closed unit cube. For a union of closed cubes:

- `b0`: components, cubes that share a corner count as touching (26-neighbours);
- `b2`: enclosed cavities, components of the empty space (6-neighbours, which is
  the dual convention) that do not reach the grid's border;
- `b1 = b0 + b2 - chi`, with the Euler characteristic `chi = V - E + F - C`
  counted over the lattice vertices, edges, faces and cubes the solid covers.

A grid resolves a solid when the solid's own voxelization has its Betti numbers
(`b1` = its genus for a closed surface); `handle_placement` reports that as
`object_resolved`, and a placement is only meaningful where it holds.
"""

from __future__ import annotations

from typing import NamedTuple

import igl
import numpy as np
from scipy import ndimage

__all__ = ["Betti", "HandlePlacement", "betti_numbers", "handle_placement", "voxelize"]


class Betti(NamedTuple):
    """Betti numbers of a solid: components `b0`, handles (independent loops) `b1`, cavities `b2`."""

    b0: int
    b1: int
    b2: int


class HandlePlacement(NamedTuple):
    """Betti numbers of an object, a result, their intersection and their union on one grid.

    `placed` is True when all four have the object's `b1` and one component each:
    every handle of the result goes through one of the object's holes.
    """

    object: Betti
    result: Betti
    intersection: Betti
    union: Betti
    resolution: int
    voxel_size: float
    object_resolved: bool

    @property
    def placed(self) -> bool:
        g = self.object.b1
        return all(b.b1 == g and b.b0 == 1 for b in (self.object, self.result, self.intersection, self.union))


def _corner_or(o: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    """OR of `o` over the shifts 0/1 along `axes` (a lattice cell is covered when any cube around it is)."""
    out = None
    for mask in range(1 << len(axes)):
        sl = [slice(None)] * 3
        for bit, ax in enumerate(axes):
            s = (mask >> bit) & 1
            sl[ax] = slice(s, o.shape[ax] - 1 + s)
        part = o[tuple(sl)]
        out = part if out is None else out | part
    return out


def betti_numbers(occupancy) -> Betti:
    """Betti numbers of the union of closed unit cubes at the True entries of a 3D bool array."""
    occ = np.asarray(occupancy)
    if occ.ndim != 3 or occ.dtype != np.bool_:
        raise ValueError(f"occupancy must be a 3D bool array, got {occ.dtype} with shape {occ.shape}")
    o = np.pad(occ, 1)
    cubes = int(o.sum())
    vertices = int(_corner_or(o, (0, 1, 2)).sum())
    edges = sum(int(_corner_or(o, tuple(a for a in range(3) if a != ax)).sum()) for ax in range(3))
    faces = sum(int(_corner_or(o, (ax,)).sum()) for ax in range(3))
    chi = vertices - edges + faces - cubes
    b0 = int(ndimage.label(o, structure=np.ones((3, 3, 3), bool))[1])
    b2 = int(ndimage.label(~o, structure=ndimage.generate_binary_structure(3, 1))[1]) - 1  # the padded outside is one
    return Betti(b0, b0 + b2 - chi, b2)


def _vf(mesh, name: str) -> tuple[np.ndarray, np.ndarray]:
    vf = mesh.to_numpy() if hasattr(mesh, "to_numpy") else mesh
    try:
        v, f = (np.asarray(a) for a in vf)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a Mesh or a (vertices, faces) pair") from None
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"{name} must have (V, 3) vertices and (F, 3) faces, got {v.shape} and {f.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} has non-finite vertices")
    return v.astype(np.float64), f.astype(np.int64)


def voxelize(mesh, lower, voxel_size: float, shape) -> np.ndarray:
    """Bool occupancy of a closed mesh (winding number > 1/2) at the centres of a grid
    of `shape` voxels of `voxel_size` whose first corner is at `lower`."""
    v, f = _vf(mesh, "mesh")
    axes = [np.asarray(lower, np.float64)[i] + voxel_size * (np.arange(n) + 0.5) for i, n in enumerate(shape)]
    q = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    w = igl.fast_winding_number(v, f, q)
    return (w > 0.5).reshape(tuple(shape))


def handle_placement(obj, result, *, resolution: int = 128, genus: int | None = None) -> HandlePlacement:
    """Betti numbers of `obj`, `result`, their intersection and union, voxelized on one cubic grid
    of `resolution` voxels along the longest side of their common bounding box (1 voxel margin).

    `genus` (default: that of `obj`'s surface, from its Euler characteristic) decides
    `object_resolved`: the grid resolves the object when its voxels have one component,
    no cavity and `b1 == genus`.
    """
    if not (isinstance(resolution, int) and resolution >= 8):
        raise ValueError(f"resolution must be an int >= 8, got {resolution!r}")
    a, b = _vf(obj, "obj"), _vf(result, "result")
    if genus is None:
        nv = len(np.unique(a[1]))
        ne = len(np.unique(np.sort(a[1][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0))
        genus = (2 - (nv - ne + len(a[1]))) // 2
    lo = np.minimum(a[0].min(0), b[0].min(0))
    hi = np.maximum(a[0].max(0), b[0].max(0))
    h = float((hi - lo).max()) / resolution
    shape = tuple(int(np.ceil((hi - lo)[i] / h)) + 2 for i in range(3))
    lower = lo - h
    oa, ob = voxelize(a, lower, h, shape), voxelize(b, lower, h, shape)
    sa = betti_numbers(oa)
    return HandlePlacement(
        object=sa, result=betti_numbers(ob), intersection=betti_numbers(oa & ob), union=betti_numbers(oa | ob),
        resolution=resolution, voxel_size=h, object_resolved=sa == Betti(1, int(genus), 0))
