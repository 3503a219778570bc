"""Images at their own resolution: pyramid levels, rescaled cameras, crops, the schedule."""

from __future__ import annotations

import dataclasses

import numpy as np
import jax
import jax.numpy as jnp
import pytest

import jaxgenus as jg
from jaxgenus.optim import _pyramid


def test_resolution_factors():
    """Coarse copies first, each level twice the last (down to 1/2), the images' own size last."""
    assert _pyramid.resolution_factors(128, 128, 4, 128, 1) == [1, 1, 1, 1]
    assert _pyramid.resolution_factors(512, 512, 4, 128, 1) == [4, 2, 2, 1]
    assert _pyramid.resolution_factors(256, 256, 4, 128, 1) == [2, 2, 2, 1]  # as before this schedule
    assert _pyramid.resolution_factors(1024, 1024, 5, 128, 2) == [8, 4, 2, 1, 1]
    assert _pyramid.resolution_factors(480, 640, 4, 128, 1) == [4, 2, 2, 1]  # 160 x 120 first
    assert _pyramid.resolution_factors(1200, 1600, 4, 128, 1) == [16, 8, 4, 1]  # DTU: 100x75, 200x150, 400x300
    assert _pyramid.resolution_factors(1200, 1600, 6, 128, 1) == [16, 8, 4, 2, 2, 1]
    assert _pyramid.resolution_factors(512, 512, 4, 0, 1) == [1, 1, 1, 1]  # off


def test_step_views_keep_a_step_within_its_pixels():
    opts = jg.OptimizeOptions()  # 4 views, 2^18 pixels
    assert jg.optim.step_views(24, 256, 256, opts) == (4, 0)  # 4 x 256^2 fit
    assert jg.optim.step_views(2, 64, 64, opts) == (2, 0)  # fewer views than asked
    assert jg.optim.step_views(41, 300, 400, opts) == (2, 0)  # DTU at 1/4: 2 whole views
    assert jg.optim.step_views(24, 512, 512, opts) == (1, 0)  # one whole view
    assert jg.optim.step_views(41, 1200, 1600, opts) == (1, 512)  # one view holds more: one 512^2 window
    assert jg.optim.step_views(41, 1200, 1600, dataclasses.replace(opts, max_pixels=None)) == (4, 0)
    assert jg.optim.step_views(41, 1200, 1600, dataclasses.replace(opts, max_pixels=1 << 21)) == (1, 0)
    assert jg.optim.step_views(41, 1200, 1600, dataclasses.replace(opts, crop=256)) == (4, 256)  # asked for
    assert jg.optim.step_views(41, 2000, 2000, dataclasses.replace(opts, views_per_step=None)) == (1, 512)
    assert jg.optim.step_views(41, 100, 100, dataclasses.replace(opts, views_per_step=None)) == (26, 0)
    with pytest.raises(ValueError, match="max_pixels"):
        jg.OptimizeOptions(max_pixels=0)


def test_pyramid_level_averages_blocks_and_premultiplies_normals():
    rng = np.random.default_rng(0)
    n, h, w = 2, 7, 10  # not multiples of the factor: the last blocks hang over the image
    alpha = (rng.random((n, h, w)) > 0.5).astype(np.float32)
    normal = rng.standard_normal((n, h, w, 3))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    fit = np.concatenate([0.5 * (normal + 1) * alpha[..., None], alpha[..., None]], -1).astype(np.float32)
    before = fit.copy()
    out = _pyramid.pyramid_level(fit, 4)
    assert np.array_equal(fit, before)  # input not modified
    assert out.shape == (n, 2, 3, 4)
    # hand-computed block (1, 2) of view 1: rows 4..6, cols 8..9 inside the image, the rest outside
    blk = alpha[1, 4:8, 8:12]
    assert np.isclose(out[1, 1, 2, 3], blk.sum() / 16.0)
    prem = (alpha[1, 4:8, 8:12, None] * normal[1, 4:8, 8:12]).sum(axis=(0, 1)) / 16.0
    assert np.allclose(out[1, 1, 2, :3], 0.5 * (prem + 1.0), atol=1e-6)
    assert _pyramid.pyramid_level(fit, 1) is not None and np.array_equal(_pyramid.pyramid_level(fit, 1), fit)


def test_scaled_cameras_project_to_the_block_grid():
    cams = jg.sphere_cameras(3, radius=3.0, resolution=(100, 140))
    coarse = _pyramid.scaled_cameras(cams, 4)
    assert (coarse.height, coarse.width) == (25, 35)
    pts = np.random.default_rng(1).standard_normal((20, 3)) * 0.5
    u = np.asarray(jg.project(cams, pts))
    uc = np.asarray(jg.project(coarse, pts))
    assert np.allclose(uc, u / 4.0, atol=1e-4)  # pixel edges at multiples of 4 map to integers


def test_crop_views_are_the_same_pixels():
    cams = jg.sphere_cameras(4, radius=3.0, resolution=64)
    scene = jg.builtin_scene("torus")
    full = jg.render_targets(scene, cams)
    boxes = _pyramid.target_boxes(jnp.asarray(full), margin=2)
    cc, crop = _pyramid.crop_views(jax.random.key(3), cams, jnp.asarray(full), boxes, 24)
    assert crop.shape == (4, 24, 24, 4) and (cc.height, cc.width) == (24, 24)
    again = np.asarray(jg.render_targets(scene, cc))
    # the crop of the full render and a render of the cropped cameras agree
    assert np.abs(np.asarray(crop)[..., 3] - again[..., 3]).max() < 1e-4
    assert np.asarray(crop)[..., 3].sum() > 0  # centred in the silhouette box


def test_target_boxes_hand_computed():
    t = np.zeros((2, 10, 12, 1), np.float32)
    t[0, 3:5, 4:9] = 1.0
    b = np.asarray(_pyramid.target_boxes(jnp.asarray(t), margin=1))
    assert b[0].tolist() == [2, 5, 3, 9]
    assert b[1].tolist() == [0, 9, 0, 11]  # empty view: whole image


@pytest.mark.slow
def test_reconstruct_takes_large_images_through_the_schedule():
    """256^2 images: early cycles at 128^2, the last through 64^2 native crops; the
    torus comes out with its genus and a good fit, and the history says what ran."""
    cams = jg.sphere_cameras(12, radius=3.0, resolution=256)
    targets = jg.render_targets(jg.builtin_scene("torus"), cams)
    opts = jg.ReconstructOptions().updated(n_cycles=3, steps_per_cycle=30, crop=64, max_faces=4000, refits=0)
    rec = jg.reconstruct(targets, cams, 1, options=opts)
    res = rec.history["resolution"]
    assert [r["factor"] for r in res] == [2, 2, 1]
    assert res[0]["size"] == [128, 128]
    assert res[-1] == {"factor": 1, "size": [256, 256], "crop": 64, "views": 4, "window": 64, "pixels": 4 * 64 * 64}
    assert rec.genus == 1
    assert min(rec.history["silhouette_iou"]) > 0.9


def test_window_reduce_equals_one_2d_reduction():
    window_reduce = _pyramid.window_reduce
    x = jnp.asarray(np.random.default_rng(0).uniform(0.0, 1.0, (2, 37, 53)), jnp.float32)
    two_d = lambda v, init, op, k, s, pad: jax.lax.reduce_window(v, init, op, (1, k, k), (1, s, s), pad)  # noqa: E731
    for k in (3, 5, 9):
        assert (window_reduce(x, jnp.inf, jax.lax.min, k) == two_d(x, jnp.inf, jax.lax.min, k, 1, "SAME")).all()
        b = x > 0.9
        assert (window_reduce(b, False, jax.lax.bitwise_or, k) == two_d(b, False, jax.lax.bitwise_or, k, 1, "SAME")).all()
    summed = window_reduce(x, 0.0, jax.lax.add, 7, 3, "VALID")
    np.testing.assert_allclose(summed, two_d(x, 0.0, jax.lax.add, 7, 3, "VALID"), rtol=1e-5)
    assert summed.shape == (2, 11, 16)
