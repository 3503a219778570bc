"""`jaxgenus.metrics.reprojection_psnr` against photos it did not make: a textured torus ray cast
by trimesh (tests/_raycast.py), predicted through the true mesh and through wrong ones."""

from __future__ import annotations

import numpy as np
import pytest
from _meshes import torus_trimesh
from _raycast import raycast_lambert

import jaxgenus as jg
from jaxgenus.metrics import reprojection_psnr


def _stripes(points):
    """A high-frequency albedo: stripes 0.1 wide across x and y."""
    s = 0.5 + 0.4 * np.sin(30.0 * points[:, 0]) * np.cos(30.0 * points[:, 1])
    return np.stack([s, 0.6 * s + 0.2, 1.0 - 0.8 * s], axis=1)


@pytest.fixture(scope="module")
def capture():
    tm = torus_trimesh(1.0, 0.4, 48, 24)
    cams = jg.sphere_cameras(14, radius=3.5, fov_deg=45, resolution=96)
    photos = raycast_lambert(cams, tm, light_direction=(0.3, 0.5, 1.0), ambient=0.6, albedo=_stripes)
    return tm, cams, photos


def _split(cams, photos, held):
    train = [i for i in range(len(cams)) if i not in held]
    return cams[np.array(train)], photos[train], cams[np.array(held)], photos[held]


def test_a_training_view_is_predicted_from_itself(capture):
    tm, cams, photos = capture
    r = reprojection_psnr(tm, photos[..., :3], cams, photos[:2, ..., :3], cams[np.array([0, 1])],
                          photos[:2, ..., 3], neighbours=1)
    assert np.all(r.psnr > 45.0), r  # the same pixel centres, sampled bilinearly: exact up to float32
    assert np.all(r.coverage > 0.99)


def test_the_true_mesh_beats_wrong_ones(capture):
    tm, cams, photos = capture
    tc, tp, hc, hp = _split(cams, photos, [3, 9])
    true = reprojection_psnr(tm, tp, tc, hp[..., :3], hc, hp[..., 3])
    fat = torus_trimesh(1.0, 0.48, 48, 24)
    shifted = tm.copy().apply_translation((0.06, 0.0, 0.0))
    for wrong in (fat, shifted):
        other = reprojection_psnr(wrong, tp, tc, hp[..., :3], hc, hp[..., 3])
        assert other.mean < true.mean - 2.0, (true, other)
    assert true.mean > 20.0 and np.all(true.coverage > 0.9), true
    half = reprojection_psnr(tm, tp, tc, hp[..., :3], hc, hp[..., 3], downsample=2)
    assert abs(half.mean - true.mean) < 3.0 and np.all(half.pixels < true.pixels)


def test_bad_input_is_named(capture):
    tm, cams, photos = capture
    with pytest.raises(ValueError, match="held_photos"):
        reprojection_psnr(tm, photos, cams, photos[:2], cams)
    with pytest.raises(ValueError, match="held_masks"):
        reprojection_psnr(tm, photos, cams, photos[:2], cams[np.array([0, 1])], photos[:2, :4, :4, 3])
    with pytest.raises(ValueError, match="mesh"):
        reprojection_psnr((np.full((3, 3), np.nan), [[0, 1, 2]]), photos, cams, photos[:1], cams[np.array([0])])


def test_views_that_cut_the_object_hand_over_to_views_that_see_it(capture):
    """The two training views nearest the held-out one zoomed in (the torus runs out of their
    frames): every held-out pixel is still predicted, from the nearest views that see its point."""
    tm, cams, photos = capture
    held = [3]
    train = np.array([i for i in range(len(cams)) if i not in held])
    centres = -np.einsum("nji,nj->ni", np.asarray(cams.rotation), np.asarray(cams.translation))
    nearest = train[np.argsort(-(centres[train] @ centres[held[0]]))[:2]]  # zoomed in: the torus runs out
    zoom = np.where(np.isin(train, nearest), 2.5, 1.0)[:, None]
    tc = jg.Cameras(cams.rotation[train], cams.translation[train], cams.focal[train] * zoom,
                    cams.principal_point[train], cams.height, cams.width)
    tp = raycast_lambert(tc, tm, light_direction=(0.3, 0.5, 1.0), ambient=0.6, albedo=_stripes)
    hc, hp = cams[np.array(held)], photos[held]
    r = reprojection_psnr(tm, tp[..., :3], tc, hp[..., :3], hc, hp[..., 3], neighbours=1)
    assert np.all(r.coverage > 0.99) and r.mean > 17.0, r  # the zoomed views alone: coverage 0.25, 7.5 dB
    assert np.all(r.psnr_inside >= r.psnr - 1e-6)  # the true mesh's outline is the mask's
    bare = reprojection_psnr(tm, tp[..., :3], tc, hp[..., :3], hc, neighbours=1)
    np.testing.assert_allclose(bare.psnr_inside, bare.psnr)  # no masks: the mesh's pixels both times
