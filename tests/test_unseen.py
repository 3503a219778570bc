"""`jaxgenus.geometry.seen_counts` and `fill_unseen` against visibility worked out by hand: a box seen
from one side, a sphere with a deep pit that a ring of cameras cannot look into, an island no camera sees."""

from __future__ import annotations

import jax
import numpy as np
import pytest
import trimesh
from _meshes import torus_trimesh
from _raycast import raycast_lambert

import jaxgenus as jg
from jaxgenus.geometry import fill_unseen, seen_counts
from jaxgenus.metrics import reprojection_psnr


def _box():
    tm = trimesh.creation.box((1.0, 1.0, 1.0))
    tm = tm.subdivide().subdivide()  # vertices inside every face, not only at the corners
    return np.asarray(tm.vertices), np.asarray(tm.faces)


def test_a_camera_above_a_box_sees_its_top_face_only():
    v, f = _box()
    cams = jg.look_at(np.array([[0.0, 0.0, 5.0]]), fov_deg=40.0, resolution=64)
    seen, in_frame = seen_counts((v, f), cams)
    # the whole box projects inside the frame (half-width 0.5 at depth >= 4.5 against tan(20 deg) * 4.5)
    assert np.all(in_frame == 1)
    # the top face (z = 0.5) faces the camera and nothing hides it; the sides' inner vertices have
    # horizontal normals, the bottom faces away
    np.testing.assert_array_equal(seen == 1, np.isclose(v[:, 2], 0.5))


def _pitted_sphere(depth=0.55, half_angle_deg=14.0):
    """A unit icosphere whose cap within `half_angle_deg` of +z is pushed down to radius 1 - depth."""
    tm = trimesh.creation.icosphere(subdivisions=4)
    v = np.asarray(tm.vertices).copy()
    pit = v[:, 2] > np.cos(np.radians(half_angle_deg))
    v[pit] *= 1.0 - depth
    return v, np.asarray(tm.faces), pit


def _ring(n=8, elevation_deg=25.0, radius=4.0):
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    e = np.radians(elevation_deg)
    eyes = radius * np.stack([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.full(n, np.sin(e))], axis=1)
    return jg.look_at(eyes, up=(0.0, 0.0, 1.0), fov_deg=40.0, resolution=96)


def test_fill_lifts_a_pit_no_camera_looks_into_and_keeps_the_seen_surface():
    v, f, pit = _pitted_sphere()
    cams = _ring()
    before = v.copy()
    seen, _ = seen_counts((v, f), cams)
    bottom = pit & (np.linalg.norm(v, axis=1) < 0.5)
    assert np.all(seen[bottom] == 0)  # 25 degrees up cannot see the floor of a pit 0.55 deep and 0.48 wide
    out = fill_unseen((v, f), cams)
    np.testing.assert_array_equal(v, before)  # the input is not modified
    assert np.all(out.moved[bottom]) and not np.any(out.moved[seen > 0])
    np.testing.assert_array_equal(out.vertices[~out.moved], v[~out.moved])
    # the floor rises to the membrane the seen rim spans (near z = cos(14 deg) ~ 0.97, at least well above 0.45)
    assert np.all(out.vertices[bottom, 2] > 0.8), out.vertices[bottom, 2].min()
    assert np.allclose(out.distance, np.linalg.norm(out.vertices - v, axis=1))
    filled = trimesh.Trimesh(out.vertices, f, process=False)
    assert filled.is_watertight and jg.genus(jg.Mesh.from_numpy(out.vertices.astype(np.float32), f.astype(np.int32))) == 0
    # a view from straight above (not a training view) sees the pit: its floor is seen by no training
    # camera, so the prediction there is black; after the fill every pixel of the object is predicted
    above = jg.look_at(np.array([[0.0, 0.0, 4.0]]), up=(0.0, 1.0, 0.0), fov_deg=40.0, resolution=96)
    photos = np.full((len(cams), 96, 96, 3), 0.5, np.float32)
    held = np.full((1, 96, 96, 3), 0.5, np.float32)
    cover_before = reprojection_psnr((v, f), photos, cams, held, above).coverage[0]
    cover_after = reprojection_psnr((out.vertices, f), photos, cams, held, above).coverage[0]
    assert cover_before < 0.97 and cover_after > 0.99, (cover_before, cover_after)


def test_an_island_no_camera_sees_stays_put():
    outer = trimesh.creation.icosphere(subdivisions=3)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    v = np.concatenate([outer.vertices, inner.vertices])
    f = np.concatenate([outer.faces, inner.faces + len(outer.vertices)])
    cams = jg.sphere_cameras(6, radius=4.0, resolution=48)
    out = fill_unseen((v, f), cams)
    island = np.arange(len(v)) >= len(outer.vertices)
    assert not out.moved[island].any()
    np.testing.assert_array_equal(out.vertices[island], v[island])


def test_bad_input_is_named():
    v, f = _box()
    cams = jg.look_at(np.array([[0.0, 0.0, 5.0]]))
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        fill_unseen((bad, f), cams)
    with pytest.raises(ValueError, match="mesh"):
        seen_counts((v[:, :2], f), cams)
    with pytest.raises(ValueError, match="fill_unseen"):
        jg.ReconstructOptions(fill_unseen=1)


def test_reconstruct_fills_unseen_surface_of_photo_targets_only():
    tm = torus_trimesh(1.0, 0.4, 48, 24)
    cams = _ring(6, 30.0, 3.5)
    photos = raycast_lambert(cams, tm, light_direction=(0.3, 0.5, 1.0), ambient=0.6)
    # the fit's photo-consistency and stereo terms are tested elsewhere: off, so the fit compiles the plain
    # photo program; polish cycles asked for, but they polish by photo-consistency: none without it
    opts = jg.ReconstructOptions().updated(n_cycles=1, steps_per_cycle=10, initial_faces=600, refits=0,
                                           subdivide=False, consistency=0.0, stereo=0.0, polish_cycles=2)
    lines, quiet = [], []
    on = jg.reconstruct(photos, cams, 1, targets="photo", options=opts, key=jax.random.key(0), log=lines.append)
    off = jg.reconstruct(photos, cams, 1, targets="photo", options=opts.updated(fill_unseen=False),
                         key=jax.random.key(0), log=quiet.append)
    assert any(line.startswith("unseen surface:") for line in lines)
    assert not any(line.startswith("unseen surface:") for line in quiet)
    (vo, fo), (vf, ff) = off.mesh.to_numpy(), on.mesh.to_numpy()
    np.testing.assert_array_equal(fo, ff)
    moved = fill_unseen((vo, fo), cams).moved
    np.testing.assert_allclose(vf[~moved], vo[~moved], atol=1e-6)  # the fill moves only what no camera sees
    assert on.genus == off.genus == 1
    for rec in (on, off):  # without photo-consistency: no residuals, no polish cycles
        assert rec.history["photo_consistency"] is None and np.all(np.asarray(rec.history["consistency"]) == 0)
        assert len(rec.history["cycles"]) == 1 and len(rec.history["loss"]) == 10
