"""Tests for `genus_primitive`: topology, orientation, size and triangle quality.

Every property is checked against an independent reference: trimesh for the
topology, volume and angles, a plain numpy edge count for the Euler
characteristic, and ray casting for the visibility of the holes.
"""

import math

import numpy as np
import pytest
import trimesh
from scipy import ndimage

import jaxgenus
from jaxgenus.geometry import _primitives

SWEEP_FACES = 2000


def _euler_numpy(v, f):
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    unique = np.unique(np.sort(edges, axis=1), axis=0)
    return len(v) - len(unique) + len(f)


def _check_surface(mesh, genus, n_faces, extent):
    v, f = mesh.to_numpy()
    assert v.dtype == np.float32 and f.dtype == np.int32
    assert mesh.vertex_capacity == len(v) and mesh.face_capacity == len(f)  # no padding
    tm = trimesh.Trimesh(vertices=v.astype(np.float64), faces=f, process=False)
    assert tm.euler_number == 2 - 2 * genus
    assert _euler_numpy(v, f) == 2 - 2 * genus
    assert tm.is_watertight
    assert tm.is_winding_consistent
    assert tm.body_count == 1
    assert tm.volume > 0  # outward orientation
    assert len(np.unique(f)) == len(v)  # no unreferenced vertices
    norms = np.linalg.norm(v.astype(np.float64), axis=1)
    assert norms.max() <= extent * (1 + 1e-6)
    assert norms.max() >= extent * (1 - 1e-5)  # scaled to fill the ball
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    assert np.linalg.norm(centre) < 0.01 * extent
    assert 0.75 * n_faces <= len(f) <= 1.25 * n_faces
    min_angle = np.degrees(tm.face_angles.min(axis=1))
    assert np.percentile(min_angle, 1) >= 20.0
    return tm


@pytest.mark.parametrize("genus", range(31))
def test_sweep_topology_and_quality(genus):
    _check_surface(jaxgenus.genus_primitive(genus, n_faces=SWEEP_FACES), genus, SWEEP_FACES, 1.0)


@pytest.mark.parametrize("genus", [0, 1, 2, 7, 30])
def test_default_face_count(genus):
    tm = _check_surface(jaxgenus.genus_primitive(genus, extent=2.5), genus, 5000, 2.5)
    if genus <= 7:
        # Smooth: no crease between neighbouring faces at this resolution.
        assert np.degrees(tm.face_adjacency_angles.max()) < 60.0


def test_sphere_and_torus_are_round():
    v, _ = jaxgenus.genus_primitive(0, n_faces=1000).to_numpy()
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    v, _ = jaxgenus.genus_primitive(1, n_faces=1000, extent=1.4).to_numpy()
    # Torus of major radius 1 and minor radius 0.4 (outer radius 1.4).
    tube = np.hypot(np.hypot(v[:, 0], v[:, 1]) - 1.0, v[:, 2])
    np.testing.assert_allclose(tube, 0.4, atol=1e-4)


def _through_holes(tm, direction, n=240):
    """Count the enclosed regions of rays along `direction` that miss the mesh."""
    direction = np.asarray(direction, np.float64)
    direction /= np.linalg.norm(direction)
    a = np.cross(direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(direction, a)
    s = np.linspace(-1.05, 1.05, n)
    grid = s[:, None, None] * a + s[None, :, None] * b
    origins = grid.reshape(-1, 3) - 3.0 * direction
    hit = tm.ray.intersects_any(origins, np.broadcast_to(direction, origins.shape))
    labels, count = ndimage.label(~hit.reshape(n, n))
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return count - np.count_nonzero(border)


@pytest.mark.parametrize("genus", [0, 1, 2, 5, 13, 30])
def test_holes_visible_from_several_directions(genus):
    tm = jaxgenus.genus_primitive(genus, n_faces=max(2000, 100 * genus)).to_trimesh()
    tilt = math.radians(30.0)
    for direction in [
        (0.0, 0.0, 1.0),
        (0.0, 0.0, -1.0),
        (math.sin(tilt), 0.0, math.cos(tilt)),
        (0.0, math.sin(tilt), -math.cos(tilt)),
    ]:
        assert _through_holes(tm, direction) == genus, direction


def test_deterministic():
    for genus in (0, 1, 4):
        a = jaxgenus.genus_primitive(genus, n_faces=1500)
        b = jaxgenus.genus_primitive(genus, n_faces=1500)
        np.testing.assert_array_equal(np.asarray(a.vertices), np.asarray(b.vertices))
        np.testing.assert_array_equal(np.asarray(a.faces), np.asarray(b.faces))


@pytest.mark.parametrize("genus", [-1, 2.5, 2.0, True, "3", None, np.float64(1.0)])
def test_bad_genus(genus):
    with pytest.raises(ValueError, match="genus"):
        jaxgenus.genus_primitive(genus)


def test_numpy_integer_genus_accepted():
    v, f = jaxgenus.genus_primitive(np.int64(2), n_faces=500).to_numpy()
    assert _euler_numpy(v, f) == -2


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"n_faces": 99}, "n_faces"),
        ({"n_faces": 0}, "n_faces"),
        ({"n_faces": 1000.0}, "n_faces"),
        ({"n_faces": 30 * 40 - 1, "genus": 30}, "n_faces"),
        ({"extent": 0.0}, "extent"),
        ({"extent": -1.0}, "extent"),
        ({"extent": float("nan")}, "extent"),
        ({"extent": float("inf")}, "extent"),
        ({"extent": "1"}, "extent"),
    ],
)
def test_bad_sizes(kwargs, name):
    kwargs = {"genus": 1, **kwargs}
    with pytest.raises(ValueError, match=name):
        jaxgenus.genus_primitive(**kwargs)


@pytest.mark.parametrize("genus", [2, 3, 5, 7, 13, 31])
def test_plate_sdf_matches_brute_force(genus):
    """The O(1) nearest-hole lookup equals a brute-force minimum over every hole."""
    sdf, (bx, by, bz) = _primitives._plate_sdf(genus)
    rows, cols, _ = _primitives._hole_grid(genus)
    sp, radius, half_t = _primitives._HOLE_SPACING, _primitives._HOLE_R, _primitives._HALF_T
    corner = radius + _primitives._MARGIN
    centres = []
    for r in range(rows):
        n = min(cols, genus - r * cols)
        centres += [((c - 0.5 * (n - 1)) * sp, (r - 0.5 * (rows - 1)) * sp) for c in range(n)]
    centres = np.asarray(centres)
    assert len(centres) == genus
    p = np.random.default_rng(0).uniform(-1.0, 1.0, (20000, 3)) * np.array([bx, by, bz])
    hole = np.min(np.linalg.norm(p[:, None, :2] - centres[None], axis=2), axis=1)
    half = np.abs(centres).max(axis=0) + corner
    q = np.abs(p[:, :2]) - (half - corner)
    outline = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - corner
    profile = np.maximum(outline, radius - hole)
    ref = np.hypot(np.maximum(profile + half_t, 0.0), p[:, 2]) - half_t
    np.testing.assert_allclose(sdf(*p.T), ref, atol=1e-12)
    np.testing.assert_allclose([sdf(*x) for x in p[:100].tolist()], ref[:100], atol=1e-12)
