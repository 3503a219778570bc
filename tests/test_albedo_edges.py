"""Albedo edges (jaxgenus.optim._intrinsic): the photometric term leaves out what a face's albedo cannot hold."""

import numpy as np
import pytest

import jax.numpy as jnp

import jaxgenus as jg
from jaxgenus.optim import EDGE_LOG_RATIO, albedo_edges
from _meshes import torus, torus_trimesh
from _raycast import cell_albedo, raycast_lambert

LIGHT = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])


def _photo(rgb, alpha=None):
    rgb = np.asarray(rgb, np.float32)
    a = np.ones(rgb.shape[:-1], np.float32) if alpha is None else np.asarray(alpha, np.float32)
    return jnp.asarray(np.concatenate([rgb * a[..., None], a[..., None]], -1)[None])


def test_a_step_is_an_edge_and_shading_is_not():
    u = np.arange(12, dtype=np.float32)
    shade = (0.5 + 0.06 * u)[None, :, None] * np.ones((6, 1, 3), np.float32)  # up to 12 % per pixel
    step = shade * np.where(u < 6, 0.5, 1.0)[None, :, None]  # an albedo step between columns 5 and 6
    assert not np.asarray(albedo_edges(_photo(shade))).any()
    edges = np.asarray(albedo_edges(_photo(step)))[0]
    assert edges[:, 4:8].all() and not edges[:, :4].any() and not edges[:, 8:].any()  # one pixel either side
    assert np.asarray(albedo_edges(_photo(step), band=0))[0][:, 5:7].all()
    one = shade.copy()
    one[..., 2] *= np.where(u < 6, 0.6, 1.0)  # a jump in one channel only (blue) is an edge too
    assert np.asarray(albedo_edges(_photo(one)))[0][:, 5].all()


def test_the_mask_border_and_dark_noise_are_not_edges():
    alpha = np.zeros((8, 8), np.float32)
    alpha[2:6, 2:6] = 1.0
    grey = np.full((8, 8, 3), 0.6, np.float32)
    assert not np.asarray(albedo_edges(_photo(grey, alpha))).any()  # the silhouette is the alpha term's
    rng = np.random.default_rng(0)
    dark = rng.uniform(0.0, 0.015, size=(8, 8, 3)).astype(np.float32)  # noise under the dark floor
    assert not np.asarray(albedo_edges(_photo(dark))).any()


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="ratio"):
        albedo_edges(_photo(np.ones((4, 4, 3))), ratio=0.0)
    with pytest.raises(ValueError, match="band"):
        albedo_edges(_photo(np.ones((4, 4, 3))), band=-1)


def test_the_photometric_term_leaves_the_edges_out():
    u = np.arange(12, dtype=np.float32)
    target = _photo(np.ones((6, 12, 3), np.float32) * np.where(u < 6, 0.3, 0.6)[None, :, None])
    render = jnp.concatenate([target[..., 3:], target[..., :3]], -1)  # (alpha, colour), an exact fit
    smeared = render.at[..., 5:7, 1:].set(0.45)  # the render blends the two sides at the edge, as a face does
    loss = lambda r, w: float(jg.optim.image_loss(r, target, weights=jg.LossWeights(albedo_edges=w), photo=True))
    assert loss(smeared, 0.0) == 0.0
    assert loss(smeared, 1.0) > 0.0 and loss(smeared, 0.5) == pytest.approx(0.5 * loss(smeared, 1.0))  # the default keeps it
    off = render.at[..., 0:2, 1:].set(0.45)  # an error away from the edge still costs
    assert loss(off, 0.0) == pytest.approx(loss(off, 1.0)) and loss(off, 0.0) > 0.0


def test_cells_ray_cast_by_trimesh_are_found_where_their_borders_project():
    """Photos of a torus with 3D cells of hashed colours, ray cast by trimesh: nearly every pixel next to a
    change of cell is an edge, and a constant albedo under the same light gives few (where one part
    of the torus passes in front of another)."""
    tm = torus_trimesh(1.0, 0.35, 64, 32)
    cams = jg.sphere_cameras(6, radius=3.0, fov_deg=40.0, resolution=96)
    hashed = cell_albedo(0.1)

    textured = raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.25, albedo=hashed)
    plain = raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.25, albedo=(0.6, 0.5, 0.4))
    pm = lambda x: jnp.asarray(np.concatenate([x[..., :3] * x[..., 3:], x[..., 3:]], -1))
    inside = textured[..., 3] >= 1.0
    assert np.asarray(albedo_edges(pm(plain)))[inside].mean() < 0.05  # inner contours (the hole) only
    edges = np.asarray(albedo_edges(pm(textured), band=0))
    # which cell each pixel sees, from the torus's own ray-cast colours: a change of colour between neighbours
    col = textured[..., :3]
    change = np.zeros(inside.shape, bool)
    differ = np.abs(np.log(np.maximum(col[:, :, 1:], 0.02) / np.maximum(col[:, :, :-1], 0.02))).max(-1) > 2 * EDGE_LOG_RATIO
    both = inside[:, :, 1:] & inside[:, :, :-1]
    change[:, :, 1:] |= differ & both
    assert change.sum() > 200 and edges[change].mean() > 0.99
    assert 0.1 < edges[inside].mean() < 0.7  # the cells' insides are kept
