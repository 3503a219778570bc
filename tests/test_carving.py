"""The carving force: zero value, no push where the normals agree, a push away from the camera where they do not."""

from __future__ import annotations

import numpy as np
import pytest

import jax
import jax.numpy as jnp

import jaxgenus as jg
from _meshes import icosphere


def _scene():
    mesh = icosphere(3, radius=1.0, dtype=np.float32)
    cams = jg.sphere_cameras(3, radius=3.0, fov_deg=40.0, resolution=48)
    return mesh, cams


def _carve(mesh, cams, target, x):
    m = jg.Mesh(vertices=x, faces=mesh.faces, n_vertices=mesh.n_vertices, n_faces=mesh.n_faces)
    r = jg.render(m, cams, channels=("alpha", "normal", "depth"))
    return jg.optim.carving_term(r[..., :4], r[..., 4], target)


def test_carving_term_is_zero_valued_and_still_where_the_normals_agree():
    mesh, cams = _scene()
    own = jg.render_targets(mesh, cams)  # the mesh's own normal maps: nothing contradicts it
    x = mesh.vertices
    value, g = jax.value_and_grad(lambda y: _carve(mesh, cams, own, y))(x)
    assert float(value) == 0.0
    assert float(jnp.abs(g).max()) == 0.0


def test_carving_term_pushes_contradicted_surface_away_from_the_camera():
    mesh, cams = _scene()
    target = np.array(jg.render_targets(mesh, cams))
    # in view 0, the centre of the disc shows normals at right angles to the surface's
    n = 2.0 * target[0, 16:32, 16:32, :3] - 1.0
    turned = np.cross(n, np.array([0.0, 0.0, 1.0]) if abs(n[..., 2].mean()) < 0.9 else np.array([1.0, 0.0, 0.0]))
    turned /= np.linalg.norm(turned, axis=-1, keepdims=True)
    target[0, 16:32, 16:32, :3] = 0.5 * (turned + 1.0)
    target = jnp.asarray(target)
    x = mesh.vertices
    value, g = jax.value_and_grad(lambda y: _carve(mesh, cams, target, y))(x)
    assert float(value) == 0.0
    g = np.asarray(g)
    moved = np.linalg.norm(g, axis=1) > 0
    assert 0 < moved.sum() < 0.2 * len(g)  # only the vertices under the contradicted pixels
    c0 = np.asarray(cams.centers[0])
    away = (np.asarray(x) - c0)
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    # descent (-g) moves them away from camera 0: the rendered depth there grows
    assert np.sum(-g[moved] * away[moved]) > 0.9 * np.linalg.norm(g[moved], axis=1).sum()
    r0 = jg.render(mesh, cams, channels=("alpha", "normal", "depth"))[0, 16:32, 16:32, 4]
    y = jg.Mesh(vertices=x - 1e-2 * jnp.asarray(g) / np.abs(g).max(), faces=mesh.faces, n_vertices=mesh.n_vertices,
                n_faces=mesh.n_faces)
    r1 = jg.render(y, cams, channels=("alpha", "normal", "depth"))[0, 16:32, 16:32, 4]
    assert float(jnp.mean(r1 - r0)) > 0


def test_objective_carve_term_adds_a_force_not_a_value():
    mesh, cams = _scene()
    target = jg.render_targets(jg.Mesh.from_numpy(0.9 * np.asarray(mesh.vertices), np.asarray(mesh.faces)), cams)
    plain, t0 = jg.optim.objective(mesh, cams, target, mesh.vertices)
    carved, t1 = jg.optim.objective(mesh, cams, target, mesh.vertices, weights=jg.LossWeights(carve=1.0))
    assert "carve" not in t0 and float(t1["carve"]) == 0.0
    assert float(carved) == pytest.approx(float(plain), rel=1e-6)
    sil = jnp.asarray(np.asarray(target)[..., 3:])  # silhouettes have no normals: no carving
    _, t2 = jg.optim.objective(mesh, cams, sil, mesh.vertices, weights=jg.LossWeights(carve=1.0))
    assert "carve" not in t2


def test_carving_term_checks_shapes_and_options():
    with pytest.raises(ValueError, match="rendered, depth, target"):
        jg.optim.carving_term(jnp.zeros((1, 4, 4, 4)), jnp.zeros((1, 4, 5)), jnp.zeros((1, 4, 4, 4)))
    with pytest.raises(ValueError, match="refit_carve"):
        jg.ReconstructOptions(refit_carve=-1.0)
    assert jg.ReconstructOptions().refit_carve == 1.0

