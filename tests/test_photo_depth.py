"""`fit_photo_depth`: the surface moved along its normals to where photos at their own size agree,
judged on photos ray cast by trimesh (tests/_raycast.py), not by this library's renderer."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from _raycast import cell_albedo, raycast_lambert

import jaxgenus as jg
from jaxgenus.geometry import fit_photo_depth

LIGHT = (0.3, -0.5, 0.8)


def _ring(n=16, elevation_deg=15.0, radius=4.0, resolution=160):
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    e = np.radians(elevation_deg)
    eyes = radius * np.stack([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.full(n, np.sin(e))], axis=1)
    return jg.look_at(eyes, up=(0.0, 0.0, 1.0), fov_deg=40.0, resolution=resolution)


@pytest.fixture(scope="module")
def scene():
    """A unit sphere with 3D colour cells of about 3 px, 16 views of 160^2 around it."""
    cams = _ring()
    sphere = trimesh.creation.icosphere(subdivisions=5)
    photos = raycast_lambert(cams, sphere, light_direction=LIGHT, ambient=0.4, albedo=cell_albedo(0.05))
    pixel = 4.0 * np.tan(np.radians(20.0)) / 80  # world size of a pixel at the sphere's centre
    return cams, sphere, photos, pixel


def _seen_band(v):
    """Vertices the ring faces squarely (|z| small), where every view's neighbours see them too."""
    return np.abs(v[:, 2]) < 0.4


def test_a_sphere_two_pixels_too_large_moves_onto_the_photos(scene):
    cams, sphere, photos, pixel = scene
    big = trimesh.creation.icosphere(subdivisions=4, radius=1.0 + 2.5 * pixel)
    v, f = np.asarray(big.vertices), np.asarray(big.faces)
    before, photos_before = v.copy(), photos.copy()
    out = fit_photo_depth((v, f), cams, photos)
    np.testing.assert_array_equal(v, before)  # the inputs are not modified
    np.testing.assert_array_equal(photos, photos_before)
    band = _seen_band(v)
    r_before, r_after = np.linalg.norm(v[band], axis=1), np.linalg.norm(out.vertices[band], axis=1)
    # 2.5 px outside before; within half a pixel of the true radius afterwards (faces are chords: the
    # vertices of a 4-subdivided icosphere sit slightly outside the ray-cast 5-subdivided one)
    assert abs(np.median(r_before) - 1.0) > 2.0 * pixel
    assert abs(np.median(r_after) - 1.0) < 0.5 * pixel, (np.median(r_after) - 1.0) / pixel
    assert out.measured[band].mean() > 0.5
    assert out.offset_px[0] > 1.5 and out.ncc_after[0] > out.ncc_before[0]
    assert np.all(np.isfinite(out.vertices))
    assert trimesh.Trimesh(out.vertices, f, process=False).is_watertight


def test_exposure_differences_between_views_do_not_count(scene):
    cams, sphere, photos, pixel = scene
    gains = np.linspace(0.5, 1.4, len(photos))[np.random.default_rng(0).permutation(len(photos))]
    dimmed = photos.copy()
    dimmed[..., :3] = np.clip(photos[..., :3] * gains[:, None, None, None] + 0.05, 0.0, 1.0)
    big = trimesh.creation.icosphere(subdivisions=4, radius=1.0 + 2.5 * pixel)
    out = fit_photo_depth(big, cams, dimmed)
    band = _seen_band(np.asarray(big.vertices))
    assert abs(np.median(np.linalg.norm(out.vertices[band], axis=1)) - 1.0) < 0.5 * pixel


def test_8_bit_photos_sweep_as_their_float_copies(scene):
    """8-bit photos stay 8-bit on the device (a quarter of float32's memory) and are read as the 16-bit
    levels float photos are kept as (each 8-bit level is 257 of them, exactly), so uint8 photos and the
    same photos as float32 in [0, 1] give the same surface."""
    cams, _, photos, pixel = scene
    eight = np.rint(np.clip(photos, 0.0, 1.0) * 255).astype(np.uint8)
    big = trimesh.creation.icosphere(subdivisions=3, radius=1.0 + 2.0 * pixel)
    a = fit_photo_depth(big, cams, eight, rounds=1)
    b = fit_photo_depth(big, cams, eight.astype(np.float32) / 255.0, rounds=1)
    assert a.measured.sum() > 50
    np.testing.assert_allclose(a.vertices, b.vertices, rtol=0, atol=1e-9)
    sixteen = eight.astype(np.uint16) * np.uint16(257)  # 16-bit photos (as reconstruct takes them): the same levels
    c = fit_photo_depth(big, cams, sixteen, rounds=1)
    np.testing.assert_allclose(c.vertices, b.vertices, rtol=0, atol=1e-9)


def test_views_split_in_two_sweep_as_all_views_do(scene):
    """The views split over two holders (as processes joined by `jax.distributed` hold them; here two
    threads, `tests/_processes.py`), every other view each, so most vertices' reference and neighbour
    views sit with different holders: each passes every camera, its own photos and `held`, and the
    sums through `total` give both the surface of one sweep over all views."""
    from _processes import as_two_processes

    cams, _, photos, pixel = scene
    big = trimesh.creation.icosphere(subdivisions=3, radius=1.0 + 2.0 * pixel)
    whole = fit_photo_depth(big, cams, photos, rounds=1)
    halves = (np.arange(0, len(cams), 2), np.arange(1, len(cams), 2))
    parts = as_two_processes(lambda i, total: fit_photo_depth(big, cams, photos[halves[i]], rounds=1, held=halves[i],
                                                              total=total))
    assert whole.measured.sum() > 50
    for part in parts:
        assert np.array_equal(part.measured, whole.measured)
        np.testing.assert_allclose(part.vertices, whole.vertices, rtol=0, atol=1e-3 * pixel)
    with pytest.raises(ValueError, match="held"):
        fit_photo_depth(big, cams, photos[halves[0]], held=halves[0])  # split views need the sum over them


def test_the_right_surface_stays_and_fixed_vertices_do_not_move(scene):
    cams, _, photos, pixel = scene
    sphere = trimesh.creation.icosphere(subdivisions=4)  # its vertices lie on the ray-cast surface
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    fixed = v[:, 0] > 0.9
    out = fit_photo_depth((v, f), cams, photos, fixed=fixed)
    band = _seen_band(v)
    assert np.median(out.distance[band]) < 0.25 * pixel, np.median(out.distance[band]) / pixel
    assert np.max(out.distance[fixed]) == 0.0


def test_curved_squares_keep_a_curved_surface_in_place():
    """A square of 12 px on a sphere of 1.6 px^-1 curvature: a flat square fits best about 0.3 px
    inside the surface, and every vertex of the right sphere would move in; the squares bent with the
    mesh's mean curvature keep them where they are (signed, the median over the band)."""
    cams = _ring(resolution=96)
    sphere = trimesh.creation.icosphere(subdivisions=4)
    photos = raycast_lambert(cams, sphere, light_direction=LIGHT, ambient=0.4, albedo=cell_albedo(0.08))
    pixel = 4.0 * np.tan(np.radians(20.0)) / 48
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    out = fit_photo_depth((v, f), cams, photos, rounds=1, anchor=1.0)
    band = _seen_band(v) & out.measured
    moved = np.einsum("vi,vi->v", out.vertices - v, v)[band] / pixel  # + outward, in pixels
    assert band.sum() > 100 and abs(np.median(moved)) < 0.1, (band.sum(), np.median(moved))


def test_one_pair_of_views_alone_moves_nothing_and_near_offsets_hold(scene):
    """Two views: each vertex has one neighbour, and a pair alone does not count (`min_views`, 2);
    with `min_views=1` it does. A surface 2.5-3.5 px out with `hold_px` 6 stays."""
    cams, _, photos, pixel = scene
    big = trimesh.creation.icosphere(subdivisions=3, radius=1.0 + 2.5 * pixel)
    pair = fit_photo_depth(big, cams[:2], photos[:2], rounds=1)
    assert not pair.measured.any()
    assert fit_photo_depth(big, cams[:2], photos[:2], rounds=1, min_views=1).measured.sum() > 20
    held = fit_photo_depth(big, cams, photos, rounds=1, hold_px=6.0, anchor=1.0)
    assert held.measured.sum() > 50 and np.max(held.distance) < 0.05 * pixel


def test_a_surface_without_texture_is_left_alone(scene):
    cams, sphere, _, _ = scene
    flat = raycast_lambert(cams, sphere, light_direction=LIGHT, ambient=1.0, albedo=(0.6, 0.5, 0.4))
    sphere = trimesh.creation.icosphere(subdivisions=3)  # no vertex may move, whatever the mesh
    out = fit_photo_depth(sphere, cams, flat)
    assert not out.measured.any() and np.all(np.isnan(out.offset_px))
    np.testing.assert_allclose(out.vertices, sphere.vertices, atol=1e-9)


def test_bad_input_is_named(scene):
    cams, sphere, photos, _ = scene
    with pytest.raises(ValueError, match="photos"):
        fit_photo_depth(sphere, cams, photos[:3])
    with pytest.raises(ValueError, match="photos"):
        fit_photo_depth(sphere, cams, photos[:, :80])
    with pytest.raises(ValueError, match="fixed"):
        fit_photo_depth(sphere, cams, photos, fixed=np.zeros(5, bool))
    with pytest.raises(ValueError, match="rounds"):
        fit_photo_depth(sphere, cams, photos, rounds=-1)
    with pytest.raises(ValueError, match="fit_photo_depth"):
        jg.ReconstructOptions(fit_photo_depth=1)



def test_reconstruct_sweeps_photos_when_it_fitted_coarser_images():
    from _meshes import torus_trimesh
    import jax

    tm = torus_trimesh(1.0, 0.4, 48, 24)
    cams = _ring(6, 30.0, 3.5, resolution=256)
    photos = raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.4, albedo=cell_albedo(0.08))
    # two short cycles at 1/2 (a coarse level of 128): the sweep runs at 256^2 after the outline, on the
    # mesh subdivided once (its edges are longer than the images resolve). The fit's own photo terms
    # (photo-consistency, stereo, the fine-texture settings) are tested elsewhere: off here, so the fit
    # compiles the plain photo program
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=5, initial_faces=600, refits=0,
                                           max_faces=600, detail_faces=0,
                                           consistency=0.0, stereo=0.0, fine_texture=False)
    lines = []
    rec = jg.reconstruct(photos, cams, 1, targets="photo", options=opts, key=jax.random.key(0), log=lines.append)
    assert min(r["factor"] for r in rec.history.resolution) > 1
    assert any(line.startswith("photo depth:") for line in lines), lines
    finer = [line.split(",")[0].split() for line in lines if line.startswith("subdivided:")]
    assert len(finer) == 1 and int(finer[0][3]) == 4 * int(finer[0][1]), lines
    assert int(rec.mesh.n_faces) == int(finer[0][3]) == int(rec.history["faces"])
    v, f = rec.mesh.to_numpy()
    assert rec.genus == 1 and np.all(np.isfinite(v))
