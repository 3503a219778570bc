"""Shapes whose holes no silhouette shows, built with manifold3d (exact booleans).

`covered_plate()`: a base, two walls along its long sides and a plate on them,
leaving a low tunnel under the plate (open at both ends, seen through only
within a few degrees of its axis), and three round holes through the plate into
the tunnel. Genus 4 (the tunnel and three holes); every hole is seen only
against the base below it. Centred at the origin, farthest vertex at distance 1.

`long_tunnel_plate()`: the same with a tunnel that no camera of
`sphere_cameras(24)` sees through (visual hull genus 0): its four handles are
all hidden.

`perforated_plate()`: the covered plate with seven holes in two rows (genus 8, visual hull
genus 0).

`wheel()`: a rim, a hub and ten spokes, and a narrow axle hole through the hub (genus 11,
visual hull genus 10).

`mug()`: a closed cylindrical body with a strap handle flat against its side
(a belt loop: a slot 0.043 wide between strap and body, seen through only within
a few degrees of its axis, elsewhere against the body). Genus 1, centred and scaled the same way.
"""

from __future__ import annotations

import numpy as np


def _box(manifold3d, lo, hi):
    lo = np.asarray(lo, float)
    return manifold3d.Manifold.cube(tuple(np.asarray(hi, float) - lo)).translate(tuple(lo))


def covered_plate(hole_radius: float = 0.13, segments: int = 48, holes: bool = True, length: float = 2.0,
                  tunnel: float = 0.15, filled: bool = False, sites=None):
    """`(vertices, faces, genus)` of the covered plate (module doc), float64 / int64;
    `holes=False`: the same without the three holes (genus 1), in the same frame;
    `filled=True`: also without the tunnel (a block, genus 0).
    `length`: the plate's (and tunnel's) length, `tunnel`: the tunnel's height, both
    before scaling (plate width 1.2); `sites`: the holes' `(x, y)` before scaling (default
    three along the middle)."""
    import manifold3d

    top = 0.3 + tunnel
    solid = _box(manifold3d, (0, 0, 0), (length, 1.2, 0.3))
    solid = solid + _box(manifold3d, (0, 0, 0.25), (length, 0.22, top + 0.05))
    solid = solid + _box(manifold3d, (0, 0.98, 0.25), (length, 1.2, top + 0.05))
    solid = solid + _box(manifold3d, (0, 0, top), (length, 1.2, top + 0.17))
    if filled:
        solid = solid + _box(manifold3d, (0, 0, 0), (length, 1.2, top + 0.17))
    if sites is None:
        sites = [(0.25 * length, 0.6), (0.5 * length, 0.6), (0.75 * length, 0.6)]
    for x, y in sites if holes else ():
        c = manifold3d.Manifold.cylinder(top + 0.05, hole_radius, hole_radius, segments).translate(
            (x, y, 0.35))
        solid = solid - c
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    v = v - 0.5 * (v.min(0) + v.max(0))
    return v / np.linalg.norm(v, axis=1).max(), f, int(solid.genus())


def long_tunnel_plate(holes: bool = True, filled: bool = False):
    """The covered plate with a taller tunnel (0.21 of the object's radius high, 1.65 long)
    and smaller holes (radius 0.08), turned 30 degrees about the plate's normal so that
    no camera of `sphere_cameras(24)` sees through the tunnel (the nearest is 18 degrees
    off its axis; it is seen through within 7): its visual hull has genus 0. `holes`,
    `filled` as for `covered_plate`."""
    v, f, genus = covered_plate(hole_radius=0.1, length=2.0, tunnel=0.25, holes=holes, filled=filled)
    a = np.radians(30.0)
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return v @ turn.T, f, genus


def perforated_plate():
    """`(vertices, faces, genus)`: the covered plate 2.4 long with seven holes of radius 0.09 in
    two staggered rows, turned 20 degrees about the plate's normal. Genus 8: the tunnel and the
    seven holes, none of which a silhouette of `sphere_cameras(24)` shows."""
    sites = [(x, 0.42) for x in np.linspace(0.3, 2.1, 4)] + [(x, 0.78) for x in np.linspace(0.55, 1.85, 3)]
    v, f, genus = covered_plate(hole_radius=0.09, segments=40, length=2.4, sites=sites)
    a = np.radians(20.0)
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return v @ turn.T, f, genus


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


def wheel(spokes: int = 10, axle: float = 0.05, tilt_deg: float = 20.0):
    """`(vertices, faces, genus)` of a spoked wheel: a rim, a hub and `spokes` spokes, and an
    axle hole of radius `axle` through the hub (seen through only within about 14 degrees of
    its axis; `axle=0`: none), tilted `tilt_deg` about x. Genus `spokes + 1`: the openings
    between the spokes show in silhouettes, the axle hole in few or none."""
    import manifold3d

    rim = manifold3d.Manifold.cylinder(0.25, 1.0, 1.0, 96) - manifold3d.Manifold.cylinder(0.25, 0.84, 0.84, 96)
    solid = rim.translate((0.0, 0.0, -0.125))
    solid = solid + manifold3d.Manifold.cylinder(0.4, 0.22, 0.22, 48).translate((0.0, 0.0, -0.2))
    for k in range(spokes):
        spoke = _box(manifold3d, (0.15, -0.04, -0.06), (0.9, 0.04, 0.06))
        solid = solid + spoke.rotate((0.0, 0.0, 360.0 * k / spokes))
    if axle > 0:
        solid = solid - manifold3d.Manifold.cylinder(0.6, axle, axle, 32).translate((0.0, 0.0, -0.3))
    solid = solid.rotate((tilt_deg, 0.0, 0.0))
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    v = v - 0.5 * (v.min(0) + v.max(0))
    return v / np.linalg.norm(v, axis=1).max(), f, int(solid.genus())
