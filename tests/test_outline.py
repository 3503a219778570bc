"""`jaxgenus.geometry.fit_outline` against masks ray cast by trimesh from shapes it was not given: a
sphere 5 % larger than the mesh, a torus already on its own masks, bad input, and `reconstruct`'s use."""

from __future__ import annotations

import jax
import numpy as np
import pytest
import trimesh
from _meshes import torus_trimesh
from _raycast import raycast

import jaxgenus as jg
from jaxgenus.geometry import fit_outline


def _ring(n=8, elevation_deg=20.0, radius=4.0, resolution=128):
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    e = np.radians(elevation_deg)
    eyes = radius * np.stack([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.full(n, np.sin(e))], axis=1)
    return jg.look_at(eyes, up=(0.0, 0.0, 1.0), fov_deg=40.0, resolution=resolution)


def _iou(v, f, cams, masks):
    cover = raycast(cams, (v, f))[..., 3] > 0.5
    return float(np.sum(cover & masks) / np.sum(cover | masks))


def test_the_outline_moves_onto_the_masks_of_a_larger_sphere():
    cams = _ring()
    masks = raycast(cams, trimesh.creation.icosphere(subdivisions=5, radius=1.05))[..., 3]
    sphere = trimesh.creation.icosphere(subdivisions=4)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    before = v.copy()
    out = fit_outline((v, f), cams, masks)
    np.testing.assert_array_equal(v, before)  # the input is not modified
    # the unit sphere's outline lies about 2.8 px inside the masks; afterwards within a few tenths of a pixel
    assert out.before > 2.0 and out.after < 0.3, (out.before, out.after)
    radius = np.linalg.norm(out.vertices, axis=1)
    assert out.moved.sum() > 100
    assert abs(np.median(radius[out.moved]) - 1.05) < 0.01, np.median(radius[out.moved])
    np.testing.assert_array_equal(out.vertices[~out.moved], v[~out.moved])  # only outline vertices move
    assert np.allclose(out.distance, np.linalg.norm(out.vertices - v, axis=1))
    binary = masks > 0.5
    assert _iou(out.vertices, f, cams, binary) > _iou(v, f, cams, binary) + 0.02
    moved = jg.Mesh.from_numpy(out.vertices.astype(np.float32), f.astype(np.int32))
    assert jg.genus(moved) == 0 and trimesh.Trimesh(out.vertices, f, process=False).is_watertight


def test_views_split_in_two_move_the_outline_as_all_views_do():
    """The views split over two holders (as processes joined by `jax.distributed` hold them; here two
    threads), each fitting with its own cameras and masks and summing its moves with the other's
    through `total`: both get the outline of one fit on all views (to the summation order)."""
    from _processes import as_two_processes

    cams = _ring(6, 25.0)
    masks = raycast(cams, trimesh.creation.icosphere(subdivisions=5, radius=1.05))[..., 3]
    sphere = trimesh.creation.icosphere(subdivisions=3)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    whole = fit_outline((v, f), cams, masks, rounds=6)
    halves = (np.array([0, 2, 4]), np.array([1, 3, 5]))
    out = as_two_processes(lambda i, total: fit_outline((v, f), cams[halves[i]], masks[halves[i]], rounds=6,
                                                         total=total))
    for part in out:
        np.testing.assert_allclose(part.vertices, whole.vertices, rtol=0, atol=1e-12)
        assert np.array_equal(part.moved, whole.moved) and abs(part.after - whole.after) < 1e-9
    assert whole.moved.sum() > 50 and whole.after < whole.before  # a fit that moved


def test_a_torus_on_its_own_masks_stays_within_a_pixel():
    cams = _ring(6, 30.0, 3.5)
    tm = torus_trimesh(1.0, 0.4, 96, 48)
    masks = raycast(cams, tm)[..., 3]
    out = fit_outline(tm, cams, masks)
    pixel = 3.5 / (64 / np.tan(np.radians(20.0)))  # world size of a pixel at the object's centre
    # the masks are the torus's own, sampled at pixel centres: the moves fit that sampling (under a
    # pixel) and do not drift round after round
    assert out.after <= out.before and np.max(out.distance) < pixel, (out.before, out.after, out.distance.max() / pixel)
    assert np.median(out.distance[out.moved]) < 0.3 * pixel


def test_bad_input_is_named():
    cams = _ring(4)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    with pytest.raises(ValueError, match="masks"):
        fit_outline(sphere, cams, np.ones((3, 128, 128)))
    with pytest.raises(ValueError, match="masks"):
        fit_outline(sphere, cams, np.full((4, 128, 128), np.nan))
    with pytest.raises(ValueError, match="step"):
        fit_outline(sphere, cams, np.ones((4, 128, 128)), step=2.0)
    with pytest.raises(ValueError, match="fit_outline"):
        jg.ReconstructOptions(fit_outline=1)


def test_reconstruct_moves_the_outline_only_when_it_fitted_coarser_images():
    tm = torus_trimesh(1.0, 0.4, 48, 24)
    cams = _ring(6, 30.0, 3.5, resolution=256)
    masks = raycast(cams, tm)[..., 3]
    # two cycles at 256^2 from a coarse level of 128: both at 1/2 (600 faces cannot hold a finer outline)
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=10, initial_faces=600, refits=0,
                                           max_faces=600, subdivide=False)
    lines = []
    rec = jg.reconstruct(masks, cams, 1, options=opts, key=jax.random.key(0), log=lines.append)
    assert min(r["factor"] for r in rec.history.resolution) > 1
    assert any(line.startswith("outline:") for line in lines), lines
    assert rec.genus == 1
    quiet = []
    off = jg.reconstruct(masks, cams, 1, options=opts.updated(fit_outline=False), key=jax.random.key(0),
                         log=quiet.append)
    assert not any(line.startswith("outline:") for line in quiet)
    (vo, fo), (vn, fn) = off.mesh.to_numpy(), rec.mesh.to_numpy()
    np.testing.assert_array_equal(fo, fn)
    assert 0 < np.sum(np.any(vo != vn, axis=1)) < len(vo)  # some vertices moved, not all
