"""Phong subdivision: every face split in four, the new vertices on a smooth surface through the old.

A fitted mesh's vertices lie on the object's surface, but its flat faces are chords of it: over a
surface of curvature k, edges of length h sag about k h^2 / 8 below it at their midpoints, and
the face interiors with them (the convex parts inside the object, the concave ones outside).
`phong_subdivision` keeps every vertex, adds one on each edge and lifts it off the chord as
Phong tessellation (Boubekeur & Alexa 2008) does: the edge's midpoint `m` is projected onto the
tangent planes of its two end vertices (area-weighted vertex normals), and the new vertex is
`(1 - s) m + s * mean(projections)`. With `s = 1/2` the lift is the sag of a circular arc
through the two vertices with their normals (k h^2 / 8), which is what restores the surface
between them; a plane stays a plane, and a cylinder's or a sphere's chords move onto it to second
order. The connectivity is the standard 1-to-4 split: the genus and manifoldness are kept. Host
side (numpy), on the live part of the mesh.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxgenus.geometry._mesh import Mesh

__all__ = ["Subdivision", "phong_subdivision"]


class Subdivision(NamedTuple):
    """What `phong_subdivision` returns.

    Attributes:
        mesh: the subdivided `Mesh`: the old vertices first (same order), then one per edge; 4x the faces.
        values: the per-vertex `values` given, extended to the new vertices (the mean of each edge's
            two ends), or None.
    """

    mesh: Mesh
    values: np.ndarray | None


def _area_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals; zero where the faces around a vertex have no area."""
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], cross)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)


def phong_subdivision(mesh, *, shape: float = 0.5, values=None) -> Subdivision:
    """`mesh` with each face split in four and each new (edge) vertex lifted toward the smooth surface
    through the old ones (module doc).

    Args:
        mesh: a `Mesh` or `(vertices (V, 3), faces (F, 3))`.
        shape: the Phong shape factor `s` in [0, 1]: 0 puts the new vertices at the edge midpoints
            (a plain 1-to-4 split), 1/2 (default) on the circular arc through the edge's ends.
        values: optional `(V, ...)` per-vertex values (an albedo) to carry over.

    Returns:
        A `Subdivision` (the input is not modified).
    """
    v, f = mesh.to_numpy() if isinstance(mesh, Mesh) else mesh
    dtype = np.asarray(v).dtype if isinstance(mesh, Mesh) else np.float64
    v, f = np.asarray(v, np.float64), np.asarray(f, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"mesh: expected vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    if not np.isfinite(v).all():
        raise ValueError("mesh: vertices must be finite")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"mesh: face indices must lie in [0, {len(v)})")
    if isinstance(shape, bool) or not isinstance(shape, (int, float)) or not 0.0 <= shape <= 1.0:
        raise ValueError(f"shape must be a number in [0, 1], got {shape!r}")
    if values is not None:
        values = np.asarray(values)
        if values.shape[:1] != (len(v),):
            raise ValueError(f"values: expected one row per vertex ({len(v)}), got shape {values.shape}")
    n = _area_normals(v, f)
    sides = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    edges, side_edge = np.unique(sides, axis=0, return_inverse=True)
    a, b = edges[:, 0], edges[:, 1]
    mid = 0.5 * (v[a] + v[b])
    # the midpoint's projections onto the end vertices' tangent planes: m - ((m - p) . n) n
    lift = -0.5 * (np.einsum("ei,ei->e", mid - v[a], n[a])[:, None] * n[a]
                   + np.einsum("ei,ei->e", mid - v[b], n[b])[:, None] * n[b])
    new = mid + shape * lift
    m = len(f)
    e = side_edge.reshape(-1)  # sides in the order (0,1) of every face, then (1,2), then (2,0)
    e01, e12, e20 = (e[k * m:(k + 1) * m] + len(v) for k in range(3))
    faces = np.concatenate([np.stack([f[:, 0], e01, e20], 1), np.stack([f[:, 1], e12, e01], 1),
                            np.stack([f[:, 2], e20, e12], 1), np.stack([e01, e12, e20], 1)])
    carried = None
    if values is not None:
        carried = np.concatenate([values, (0.5 * (values[a] + values[b])).astype(values.dtype)])
    return Subdivision(Mesh.from_numpy(np.concatenate([v, new]).astype(dtype), faces.astype(np.int32)), carried)
