"""Shapes whose holes no silhouette shows, built with manifold3d (exact booleans).

`covered_plate()`: a base, two walls along its long sides and a plate on them,
leaving a low tunnel under the plate (open at both ends, seen through only
within a few degrees of its axis), and three round holes through the plate into
the tunnel. Genus 4 (the tunnel and three holes); every hole is seen only
against the base below it. Centred at the origin, farthest vertex at distance 1.

`mug()`: a closed cylindrical body with a strap handle flat against its side
(a belt loop: a slot 0.043 wide between strap and body, seen through only within
a few degrees of its axis, elsewhere against the body). Genus 1, centred and scaled the same way.
"""

from __future__ import annotations

import numpy as np


def _box(manifold3d, lo, hi):
    lo = np.asarray(lo, float)
    return manifold3d.Manifold.cube(tuple(np.asarray(hi, float) - lo)).translate(tuple(lo))


def covered_plate(hole_radius: float = 0.13, segments: int = 48, holes: bool = True):
    """`(vertices, faces, genus)` of the covered plate (module doc), float64 / int64;
    `holes=False`: the same without the three holes (genus 1), in the same frame."""
    import manifold3d

    solid = _box(manifold3d, (0, 0, 0), (2.0, 1.2, 0.3))
    solid = solid + _box(manifold3d, (0, 0, 0.25), (2.0, 0.22, 0.5))
    solid = solid + _box(manifold3d, (0, 0.98, 0.25), (2.0, 1.2, 0.5))
    solid = solid + _box(manifold3d, (0, 0, 0.45), (2.0, 1.2, 0.62))
    for x in (0.5, 1.0, 1.5) if holes else ():
        c = manifold3d.Manifold.cylinder(0.4, hole_radius, hole_radius, segments).translate((x, 0.6, 0.35))
        solid = solid - c
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    v = v - 0.5 * (v.min(0) + v.max(0))
    return v / np.linalg.norm(v, axis=1).max(), f, int(solid.genus())


def mug():
    """`(vertices, faces, genus)` of the mug with a strap handle (module doc), float64 / int64."""
    import manifold3d

    body = manifold3d.Manifold.cylinder(1.0, 0.45, 0.45, 64).translate((0.0, 0.0, -0.5))
    solid = body + _box(manifold3d, (0.48, -0.25, -0.38), (0.54, 0.25, 0.38))
    for z in (-0.38, 0.30):  # the strap's two feet on the body
        solid = solid + _box(manifold3d, (0.3, -0.25, z), (0.54, 0.25, z + 0.08))
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    v = v - 0.5 * (v.min(0) + v.max(0))
    return v / np.linalg.norm(v, axis=1).max(), f, int(solid.genus())
