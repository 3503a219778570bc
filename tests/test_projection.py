"""The hand-written VJP of the per-face projection against float64 finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from jax.test_util import check_grads

import jaxgenus as jg
from jaxgenus.rendering._projection import projected_faces
from _meshes import icosphere_arrays


def _scene(n_views=3, z_shift=0.0):
    rng = np.random.default_rng(1)
    v, f = icosphere_arrays(1, noise=0.1, seed=rng)  # draws the noise from rng, which goes on below
    verts = jnp.asarray(v, jnp.float64)
    faces = jnp.asarray(f)
    cams = jg.sphere_cameras(n_views, radius=2.6 + z_shift, fov_deg=45.0, resolution=32)
    f64 = lambda x: jnp.asarray(x, jnp.float64)
    live = jnp.asarray(rng.random(len(f)) > 0.1)  # some slots unused
    args = (verts, f64(cams.rotation), f64(cams.translation), f64(cams.focal), f64(cams.principal_point))
    # finite differences of the inverse-depth plane are only accurate away from edge-on
    # faces (its coefficients grow like 1/area): keep faces of at least 0.5 px² in every view
    uv = projected_faces(verts[faces], *args[1:], live, znear=1e-4).uv
    e1, e2 = uv[:, :, 1] - uv[:, :, 0], uv[:, :, 2] - uv[:, :, 0]
    area = 0.5 * jnp.abs(e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0])
    return (*args, faces, live & jnp.all(area > 0.5, axis=0))


def _weighted(args, faces, live, znear=1e-4):
    """A random linear functional of every differentiable output (fixed weights), as a
    function of the vertices (not per-face corner copies: the depth range's min over
    copies of one vertex would be a kink) and the cameras."""
    rng = np.random.default_rng(7)
    outs = lambda p: (p.uv, p.plane, p.qrange, p.dconst)

    def pj(verts, rot, trans, focal, pp):
        return projected_faces(verts[faces], rot, trans, focal, pp, live, znear=znear)

    ws = [jnp.asarray(rng.standard_normal(x.shape), x.dtype) for x in outs(pj(*args))]

    def f(*a):
        return sum(jnp.sum(x * w_) for x, w_ in zip(outs(pj(*a)), ws))

    return f


def test_vjp_matches_central_differences_float64():
    with jax.enable_x64(True):
        verts, rot, trans, focal, pp, faces, live = _scene()
        # every float argument: vertices and all camera parameters
        args = (verts, rot, trans, focal, pp)
        check_grads(_weighted(args, faces, live), args, order=1, modes=["rev"], eps=1e-6, atol=1e-5, rtol=1e-5)


def test_vjp_with_faces_behind_the_near_plane_float64():
    with jax.enable_x64(True):
        # cameras inside the sphere's reach: some corners lie behind the near plane
        verts, rot, trans, focal, pp, faces, live = _scene(z_shift=-1.6)
        pj = projected_faces(verts[faces], rot, trans, focal, pp, live, znear=0.05)
        assert not bool(jnp.all(pj.front)) and bool(jnp.any(pj.front))
        args = (verts, rot, trans, focal, pp)
        check_grads(_weighted(args, faces, live, 0.05), args, order=1, modes=["rev"], eps=1e-6, atol=1e-5, rtol=1e-5)


def test_degenerate_projection_is_finite():
    with jax.enable_x64(True):
        verts, rot, trans, focal, pp, faces, live = _scene(n_views=1)
        # face 0 seen edge-on: its corners lie on one ray from the camera centre
        centre = -rot[0].T @ trans[0]
        a = verts[faces[0, 0]]
        verts = verts.at[faces[0, 1]].set(a + 0.1 * (centre - a)).at[faces[0, 2]].set(a + 0.3 * (centre - a))
        live = live.at[0].set(True)
        args = (verts, rot, trans, focal, pp)
        g = jax.grad(_weighted(args, faces, live), argnums=(0, 1, 2, 3, 4))(*args)
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in g)


def test_render_gradient_matches_central_differences_float64():
    """The default render's gradient (set-up VJP + native splat VJP) along a random direction."""
    with jax.enable_x64(True):
        s = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=16, minor_sections=8)
        mesh = jg.Mesh.from_numpy(np.asarray(s.vertices, np.float64), s.faces)
        cams = jg.sphere_cameras(4, radius=3.5, fov_deg=45.0, resolution=24)
        rng = np.random.default_rng(0)
        cot = jnp.asarray(rng.standard_normal((4, 24, 24, 4)))

        def loss(verts):
            m = jg.Mesh(verts, mesh.faces, mesh.n_vertices, mesh.n_faces)
            return jnp.sum(jg.render(m, cams, channels=("alpha", "normal"), sigma=0.7) * cot)

        g = jax.grad(loss)(mesh.vertices)
        for eps in (1e-4, 1e-5):  # the quotient converges to the analytic value (O(eps^2))
            d = rng.standard_normal(mesh.vertices.shape)
            d = jnp.asarray(d / np.linalg.norm(d))
            fd = (loss(mesh.vertices + eps * d) - loss(mesh.vertices - eps * d)) / (2 * eps)
            assert abs(float(jnp.sum(g * d)) - float(fd)) <= 1e-5 * abs(float(fd))
