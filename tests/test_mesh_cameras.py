import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxgenus as jg


def test_mesh_roundtrip_padding_and_no_mutation(tmp_path):
    m = trimesh.creation.icosphere(2)
    v = np.array(m.vertices)
    f = np.array(m.faces)
    v0, f0 = v.copy(), f.copy()
    mesh = jg.Mesh.from_numpy(v, f, capacity=2000)
    assert mesh.faces.shape == (2000, 3) and mesh.faces.dtype == jnp.int32
    assert mesh.vertices.dtype == jnp.float32
    assert np.all(np.asarray(mesh.faces)[len(f):] == 0)
    assert np.all(np.asarray(mesh.vertices)[len(v):] == 0)
    assert int(mesh.face_mask.sum()) == len(f) and int(mesh.vertex_mask.sum()) == len(v)
    vv, ff = mesh.to_numpy()
    np.testing.assert_allclose(vv, v, rtol=1e-6)
    np.testing.assert_array_equal(ff, f)
    np.testing.assert_array_equal(v, v0)
    np.testing.assert_array_equal(f, f0)
    assert mesh.to_trimesh().is_watertight
    for ext in ("obj", "ply"):
        p = tmp_path / f"m.{ext}"
        jg.save_mesh(mesh, p)
        back = jg.load_mesh(p)
        bv, bf = back.to_numpy()
        np.testing.assert_allclose(bv, vv, atol=1e-6)
        np.testing.assert_array_equal(bf, ff)


def test_mesh_bad_input():
    with pytest.raises(ValueError, match="vertices"):
        jg.Mesh.from_numpy(np.zeros((4, 2)), np.zeros((1, 3), int))
    with pytest.raises(ValueError, match="faces"):
        jg.Mesh.from_numpy(np.zeros((4, 3)), np.zeros((1, 4), int))
    with pytest.raises(ValueError, match="faces"):
        jg.Mesh.from_numpy(np.zeros((4, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="range"):
        jg.Mesh.from_numpy(np.zeros((4, 3)), np.array([[0, 1, 4]]))
    with pytest.raises(ValueError, match="NaN"):
        jg.Mesh.from_numpy(np.full((4, 3), np.nan), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="capacity"):
        jg.Mesh.from_numpy(np.zeros((4, 3)), np.array([[0, 1, 2]] * 5), capacity=3)
    with pytest.raises(ValueError, match="path"):
        jg.load_mesh("/nonexistent/file.obj")


def test_capacity_bucket_grows_geometrically():
    caps = sorted({jg.geometry.capacity_bucket(n)[1] for n in range(1, 100_000, 97)})
    assert caps[0] == 256
    ratios = np.array(caps[1:]) / np.array(caps[:-1])
    assert np.all((ratios > 1.3) & (ratios < 1.6))
    for n in (1, 255, 256, 257, 5000, 99_999):
        vcap, fcap = jg.geometry.capacity_bucket(n)
        assert fcap >= n and vcap == fcap // 2 + 2


unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=30, deadline=None)
@given(
    eye=st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5)),
    target=st.tuples(unit, unit, unit),
    res=st.tuples(st.integers(8, 300), st.integers(8, 300)),
    fov=st.floats(10.0, 120.0),
)
def test_look_at_centres_target(eye, target, res, fov):
    eye, target = np.array(eye), np.array(target)
    if np.linalg.norm(eye - target) < 0.1:
        return
    cams = jg.look_at(eye, target, fov_deg=fov, resolution=res)
    uv, z = jg.project(cams, jnp.asarray(target)[None], return_depth=True)
    h, w = res
    np.testing.assert_allclose(np.asarray(uv[0, 0]), [w / 2, h / 2], atol=1e-3 * max(h, w))
    assert float(z[0, 0]) == pytest.approx(np.linalg.norm(eye - target), rel=1e-4)
    rot = np.asarray(cams.rotation[0])
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-5)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(np.asarray(cams.centers[0]), eye, atol=1e-4 * (1 + np.abs(eye).max()))


def test_look_at_orientation_and_fov():
    cams = jg.look_at([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_deg=90.0, resolution=(100, 200))
    uv = np.asarray(jg.project(cams, jnp.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))[0])
    assert uv[0, 1] < 50  # world up is image up (smaller row)
    assert uv[1, 0] > 100  # seen from +z with y up, world +x is on the right
    # 90 degree vertical fov: a point at 45 degrees sits on the top image border
    top = np.asarray(jg.project(cams, jnp.array([[0.0, 5.0, 0.0]]))[0, 0])
    assert top[1] == pytest.approx(0.0, abs=1e-3)
    # degenerate up (parallel to the view direction) still gives a valid rotation
    c2 = jg.look_at([0.0, 3.0, 0.0], fov_deg=40.0, resolution=64)
    r = np.asarray(c2.rotation[0])
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-5)


def test_sphere_cameras_uniform_and_vmappable():
    cams = jg.sphere_cameras(24, radius=3.0, resolution=64)
    c = np.asarray(cams.centers)
    np.testing.assert_allclose(np.linalg.norm(c, axis=1), 3.0, rtol=1e-5)
    assert np.linalg.norm(c.mean(0)) < 0.2  # spread over the sphere
    d = np.linalg.norm(c[:, None] - c[None], axis=-1) + np.eye(24) * 10
    assert d.min(1).min() > 0.5 * d.min(1).max()  # near-uniform spacing
    uv = jg.project(cams, jnp.zeros((1, 3)))
    np.testing.assert_allclose(np.asarray(uv[:, 0]), 32.0, atol=1e-3)
    pts = jnp.array(np.random.default_rng(0).normal(size=(5, 3)) * 0.3, jnp.float32)
    a = jax.jit(jax.vmap(lambda cam: jg.project(cam, pts), in_axes=0))(
        jax.tree_util.tree_map(lambda x: x[:, None], cams)
    )
    np.testing.assert_allclose(np.asarray(a[:, 0]), np.asarray(jg.project(cams, pts)), rtol=1e-5, atol=1e-4)


def test_camera_convention_round_trips():
    cams = jg.sphere_cameras(5, radius=2.5, fov_deg=35.0, resolution=(96, 128))
    pts = jnp.array(np.random.default_rng(1).normal(size=(7, 3)) * 0.4, jnp.float32)
    uv = np.asarray(jg.project(cams, pts))
    K, R, t = jg.cameras_to_opencv(cams)
    # OpenCV: pixel centres at integers -> our coordinates minus 0.5
    xc = np.einsum("nij,pj->npi", np.asarray(R), np.asarray(pts)) + np.asarray(t)[:, None]
    cv = np.einsum("nij,npj->npi", np.asarray(K), xc)
    np.testing.assert_allclose(cv[..., :2] / cv[..., 2:], uv - 0.5, rtol=1e-5, atol=1e-3)
    back = jg.cameras_from_opencv(K, R, t, height=96, width=128)
    np.testing.assert_allclose(np.asarray(jg.project(back, pts)), uv, rtol=1e-5, atol=1e-3)
    view, fov = jg.geometry.cameras_to_opengl(cams)
    np.testing.assert_allclose(np.asarray(fov), 35.0, rtol=1e-5)
    # OpenGL view: visible points have negative z
    xgl = np.einsum("nij,pj->npi", np.asarray(view[:, :3, :3]), np.asarray(pts)) + np.asarray(view[:, :3, 3])[:, None]
    assert np.all(xgl[..., 2] < 0)
    gl = jg.cameras_from_opengl(view, 35.0, height=96, width=128)
    np.testing.assert_allclose(np.asarray(jg.project(gl, pts)), uv, rtol=1e-5, atol=1e-3)
    bl = jg.cameras_from_blender(np.linalg.inv(np.asarray(view)), 35.0, height=96, width=128)
    np.testing.assert_allclose(np.asarray(jg.project(bl, pts)), uv, rtol=1e-4, atol=1e-2)


def test_camera_bad_input():
    with pytest.raises(ValueError, match="rotation"):
        jg.Cameras(jnp.zeros((2, 3)), jnp.zeros((2, 3)), jnp.ones((2, 2)), jnp.ones((2, 2)), 8, 8)
    with pytest.raises(ValueError, match="focal"):
        jg.Cameras(jnp.zeros((2, 3, 3)), jnp.zeros((2, 3)), jnp.ones((3, 2)), jnp.ones((2, 2)), 8, 8)
    with pytest.raises(ValueError, match="fov"):
        jg.look_at([0, 0, 1.0], fov_deg=200.0)
    with pytest.raises(ValueError, match="eye"):
        jg.look_at([0, 0, 0.0])
    with pytest.raises(ValueError, match="resolution"):
        jg.sphere_cameras(4, resolution=0)
