"""Tests for jaxgenus.metrics against analytic values and independent references."""

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxgenus
from jaxgenus import metrics
from _meshes import icosphere_trimesh

R1, R2 = 1.0, 1.25
N = 20_000  # samples per metric call in these tests (the defaults are larger)


def _blob(subdivisions=3):
    """A smooth star-shaped surface with no rotational or mirror symmetry."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = m.vertices
    r = 1 + 0.3 * d[:, 0] + 0.25 * d[:, 1] * d[:, 2] + 0.2 * d[:, 2] ** 2 - 0.15 * d[:, 0] * d[:, 1]
    return trimesh.Trimesh(d * r[:, None], m.faces, process=False)


def _rigid(axis, angle, translation):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    t[:3, 3] = translation
    return t


@pytest.fixture(scope="module")
def spheres():
    return icosphere_trimesh(4, R1), icosphere_trimesh(4, R2)


def test_concentric_spheres_chamfer(spheres):
    inner, outer = spheres
    gap = R2 - R1
    c = metrics.chamfer_distance(inner, outer, n_samples=N, seed=1)
    assert c.l1 == pytest.approx(gap, rel=0.02)
    assert c.l1_a_to_b == pytest.approx(gap, rel=0.02)
    assert c.l1_b_to_a == pytest.approx(gap, rel=0.02)
    assert c.l1 == pytest.approx(0.5 * (c.l1_a_to_b + c.l1_b_to_a))
    # Sum over directions of the squared gap: 2 * 0.0625 = 0.125. A missing
    # square (0.5), a missing factor 2 (0.0625) or a mean instead of a sum fail.
    assert c.l2_pytorch3d == pytest.approx(2 * gap**2, rel=0.05)


def test_pytorch3d_convention_matches_brute_force():
    """l2_pytorch3d on two tiny meshes equals a dense nearest-neighbour computation."""
    a = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    b = (np.array([[0.0, 0, 0.5], [1, 0, 0.5], [0, 1, 0.7]]), np.array([[0, 1, 2]]))
    c = metrics.chamfer_distance(a, b, n_samples=300, seed=3)
    # the same samples, redrawn the way the private sampler draws them (this
    # mirrors its call sequence on purpose: one face, so the face choice is trivial)
    rng = np.random.default_rng(3)

    def sample(v):
        rng.choice(1, size=300, p=[1.0])
        r = rng.random((300, 2))
        flip = r.sum(axis=1) > 1
        r[flip] = 1 - r[flip]
        return v[0] + r[:, :1] * (v[1] - v[0]) + r[:, 1:] * (v[2] - v[0])

    pa, pb = sample(a[0]), sample(b[0])
    d2 = ((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)
    assert c.l2_pytorch3d == pytest.approx(d2.min(1).mean() + d2.min(0).mean(), rel=1e-12)
    # l1 against trimesh's independent closest-point query
    tb = trimesh.Trimesh(*b, process=False)
    ta = trimesh.Trimesh(*a, process=False)
    _, da, _ = trimesh.proximity.closest_point(tb, pa)
    _, db, _ = trimesh.proximity.closest_point(ta, pb)
    assert c.l1_a_to_b == pytest.approx(da.mean(), rel=1e-9)
    assert c.l1_b_to_a == pytest.approx(db.mean(), rel=1e-9)


def test_concentric_spheres_hausdorff_and_iou(spheres):
    inner, outer = spheres
    assert metrics.hausdorff_distance(inner, outer, n_samples=N) == pytest.approx(R2 - R1, rel=0.02)
    iou = metrics.volume_iou(inner, outer, n_samples=50_000, seed=2)
    assert iou == pytest.approx((R1 / R2) ** 3, abs=0.02)
    assert metrics.volume_iou(outer, inner, n_samples=50_000, seed=2) == pytest.approx(iou)


@pytest.mark.parametrize("d", [0.1, 0.5])
def test_shifted_cube_iou(d):
    cube = trimesh.creation.box()
    shifted = cube.copy()
    shifted.apply_translation([d, 0, 0])
    iou = metrics.volume_iou(cube, shifted, n_samples=N, seed=0)
    assert iou == pytest.approx((1 - d) / (1 + d), abs=0.02)


def test_mesh_with_itself():
    m = _blob()
    assert metrics.volume_iou(m, m, n_samples=N) == 1.0
    c = metrics.chamfer_distance(m, m, n_samples=N)
    assert c.l1 < 1e-12
    # only the point-cloud sampling bias, about 2 / (pi * density)
    density = N / m.area
    assert c.l2_pytorch3d < 4 / (np.pi * density)
    assert metrics.hausdorff_distance(m, m, n_samples=N) < 1e-12


def test_disjoint_and_empty_volume():
    a = icosphere_trimesh(2, 1.0)
    b = icosphere_trimesh(2, 1.0)
    b.apply_translation([3, 0, 0])
    assert metrics.volume_iou(a, b, n_samples=N) == 0.0
    flat = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    assert metrics.volume_iou(flat, flat, n_samples=1000) == 0.0


def test_normalize_to_unit_sphere():
    m = _blob()
    v0 = np.asarray(m.vertices) * 3.0 + [10.0, -2.0, 5.0]
    v, f, scale, translation = metrics.normalize_to_unit_sphere((v0, m.faces))
    centre = 0.5 * (v.min(0) + v.max(0))
    np.testing.assert_allclose(centre, 0, atol=1e-12)
    assert np.linalg.norm(v, axis=1).max() == pytest.approx(1.0)
    np.testing.assert_allclose(v, scale * v0 + translation)
    np.testing.assert_array_equal(f, m.faces)
    # a prediction normalized in the reference's frame gets the same map
    pred = (v0 + 0.01, m.faces)
    pv, _, ps, pt = metrics.normalize_to_unit_sphere(pred, reference=(v0, m.faces))
    assert ps == scale
    np.testing.assert_array_equal(pt, translation)
    np.testing.assert_allclose(pv, v + 0.01 * scale)


def _icp_case(mesh, angle=0.15, scale=1.0, offset=0.0):
    t0 = _rigid([1, 2, 3], angle, [0.05 * scale, -0.03 * scale, 0.02 * scale])
    v, f = np.asarray(mesh.vertices) * scale + offset, np.asarray(mesh.faces)
    target = (v, f)
    source = (v @ t0[:3, :3].T + t0[:3, 3], f)
    r = metrics.icp_align(source, target, n_samples=2000, seed=0)
    assert r.residual < 1e-6 * scale
    np.testing.assert_allclose(r.transform[:3, :3], np.linalg.inv(t0)[:3, :3], atol=1e-6)
    np.testing.assert_allclose(r.transform[:3, 3], np.linalg.inv(t0)[:3, 3], atol=1e-6 * scale)
    np.testing.assert_allclose(r.vertices, v, atol=1e-6 * scale)


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (50.0, 100.0)])
def test_icp_recovers_rigid_motion_blob(scale, offset):
    """Also far from the origin and at another scale (the rotation centre matters)."""
    _icp_case(_blob(), scale=scale, offset=offset)


def test_icp_recovers_rigid_motion_spot(shared_meshes):
    _icp_case(trimesh.load(shared_meshes / "spot_low.obj", process=False))


def test_icp_aligns_a_different_tessellation():
    """A finer mesh of the same shape, moved: ICP undoes the motion up to faceting error."""
    target = _blob(3)
    fine = _blob(5)
    t0 = _rigid([3, -1, 2], 0.2, [-0.04, 0.06, 0.03])
    source = (np.asarray(fine.vertices) @ t0[:3, :3].T + t0[:3, 3], fine.faces)
    r = metrics.icp_align(source, target, n_samples=3000)
    gap = metrics.chamfer_distance(fine, target, n_samples=5000).l1  # tessellation gap, ~3.5e-3
    assert r.residual < 1.5 * gap
    np.testing.assert_allclose(r.transform, np.linalg.inv(t0), atol=3e-3)
    before = metrics.chamfer_distance(source, target, n_samples=5000).l1
    after = metrics.chamfer_distance((r.vertices, fine.faces), target, n_samples=5000).l1
    assert after < 1.05 * gap < 0.1 * before


def test_icp_unconstrained_rotation_and_jax_state():
    """A sphere does not constrain rotations: the fit stays finite and rigid, the
    translation is recovered, and the float64 solve leaves jax's x64 flag as it was."""
    import jax

    flag = jax.config.jax_enable_x64
    target = icosphere_trimesh(3, 1.0)
    t0 = _rigid([0, 0, 1], 0.1, [0.03, -0.02, 0.01])
    v = np.asarray(target.vertices)
    r = metrics.icp_align((v @ t0[:3, :3].T + t0[:3, 3], target.faces), target, n_samples=1000)
    assert np.all(np.isfinite(r.transform)) and r.residual < 1e-3
    rot = r.transform[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    centre = r.transform[:3, :3] @ t0[:3, 3] + r.transform[:3, 3]  # where the moved centre lands
    np.testing.assert_allclose(centre, 0.0, atol=1e-3)
    assert jax.config.jax_enable_x64 == flag
    assert jnp.zeros(1).dtype == (jnp.float64 if flag else jnp.float32)


def test_icp_plane_moves_only_along_its_normal():
    """On a flat grid, in-plane rotation and translation are exactly unconstrained:
    the minimum-norm fit leaves them at 0 and recovers the offset along the normal."""
    g = np.linspace(-1.0, 1.0, 21)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = np.arange(v.shape[0]).reshape(21, 21)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    t0 = _rigid([0, 0, 1], 0.05, [0.0, 0.0, 0.1])
    r = metrics.icp_align((v @ t0[:3, :3].T + t0[:3, 3], f), (v, f), n_samples=500)
    expected = np.eye(4)
    expected[2, 3] = -0.1
    np.testing.assert_allclose(r.transform, expected, atol=1e-9)


def test_icp_initial_and_rigidity():
    target = _blob()
    t0 = _rigid([0, 1, 1], 0.1, [0.02, 0.0, -0.04])
    v = np.asarray(target.vertices)
    source = (v @ t0[:3, :3].T + t0[:3, 3], target.faces)
    exact = metrics.icp_align(source, target, initial=np.linalg.inv(t0), max_iterations=1)
    assert exact.residual < 1e-9
    r = metrics.icp_align(source, target, n_samples=500, max_iterations=3)
    rot = r.transform[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(r.transform[3], [0, 0, 0, 1])
    assert np.linalg.det(rot) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="initial"):
        metrics.icp_align(source, target, initial=2 * np.eye(4))
    with pytest.raises(ValueError, match="initial"):
        metrics.icp_align(source, target, initial=np.eye(3))
    with pytest.raises(ValueError, match="tolerance"):
        metrics.icp_align(source, target, tolerance=-1.0)


def test_input_kinds_and_dtypes_agree():
    m = _blob()
    other = icosphere_trimesh(3, 1.1)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    v32 = v.astype(np.float32)
    kinds = [
        (v32.astype(np.float64), f),
        (v32, f.astype(np.int32)),
        (jnp.asarray(v32), jnp.asarray(f, jnp.int32)),
        jaxgenus.Mesh.from_numpy(v32, f, capacity=2 * len(f)),  # padded buffers
        trimesh.Trimesh(v32, f, process=False),
    ]
    ref = None
    for k in kinds:
        out = (
            metrics.chamfer_distance(k, other, n_samples=5000),
            metrics.hausdorff_distance(k, other, n_samples=5000),
            metrics.volume_iou(k, other, n_samples=5000),
            metrics.normalize_to_unit_sphere(k).scale,
        )
        if ref is None:
            ref = out
        np.testing.assert_allclose(np.hstack(out[0]), np.hstack(ref[0]), rtol=1e-12)
        assert out[1:] == pytest.approx(ref[1:], rel=1e-12)
    # float32 rounding of the vertices moves the results only at float32 precision
    c64 = metrics.chamfer_distance((v, f), other, n_samples=5000)
    np.testing.assert_allclose(np.hstack(c64), np.hstack(ref[0]), rtol=1e-4)
    assert metrics.hausdorff_distance((v, f), other, n_samples=5000) == pytest.approx(
        ref[1], rel=1e-4
    )


def test_deterministic_given_seed():
    a, b = _blob(), icosphere_trimesh(3, 1.1)
    c1 = metrics.chamfer_distance(a, b, n_samples=3000, seed=7)
    assert metrics.chamfer_distance(a, b, n_samples=3000, seed=7) == c1
    assert metrics.chamfer_distance(a, b, n_samples=3000, seed=8) != c1
    assert metrics.volume_iou(a, b, n_samples=3000, seed=7) == metrics.volume_iou(
        a, b, n_samples=3000, seed=7
    )


def test_inputs_not_modified():
    m = _blob()
    v = np.asarray(m.vertices).copy()
    f = np.asarray(m.faces).copy()
    v_in, f_in = v.copy(), f.copy()
    tm = trimesh.Trimesh(v.copy(), f.copy(), process=False)
    init = _rigid([1, 0, 0], 0.05, [0.01, 0, 0])
    init_in = init.copy()
    metrics.chamfer_distance((v_in, f_in), tm, n_samples=1000)
    metrics.hausdorff_distance((v_in, f_in), tm, n_samples=1000)
    metrics.volume_iou((v_in, f_in), tm, n_samples=1000)
    metrics.normalize_to_unit_sphere((v_in, f_in), reference=tm)
    metrics.icp_align((v_in, f_in), tm, n_samples=500, max_iterations=2, initial=init_in)
    np.testing.assert_array_equal(v_in, v)
    np.testing.assert_array_equal(f_in, f)
    np.testing.assert_array_equal(tm.vertices, v)
    np.testing.assert_array_equal(init_in, init)


@pytest.mark.parametrize(
    "bad, match",
    [
        ((np.zeros((0, 3)), np.zeros((0, 3), int)), "vertices"),
        ((np.eye(3), np.zeros((0, 3), int)), "faces"),
        ((np.zeros((3, 2)), np.array([[0, 1, 2]])), "vertices"),
        ((np.eye(3), np.array([0, 1, 2])), "faces"),
        ((np.eye(3), np.array([[0.0, 1, 2]])), "faces"),
        ((np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]])), "NaN"),
        ((np.eye(3), np.array([[0, 1, 3]])), "out of range"),
        ("mesh.obj", "must be a"),
    ],
)
def test_bad_inputs_raise(bad, match):
    good = icosphere_trimesh(1, 1.0)
    with pytest.raises(ValueError, match=match) as e:
        metrics.chamfer_distance(bad, good, n_samples=10)
    assert str(e.value).startswith("a")
    with pytest.raises(ValueError, match=match) as e:
        metrics.volume_iou(good, bad, n_samples=10)
    assert str(e.value).startswith("b")
    with pytest.raises(ValueError) as e:
        metrics.icp_align(good, bad, n_samples=10)
    assert str(e.value).startswith("target")
    with pytest.raises(ValueError) as e:
        metrics.normalize_to_unit_sphere(good, reference=bad)
    assert str(e.value).startswith("reference")


@pytest.mark.parametrize("n", [0, -5, 2.5, True])
def test_bad_sample_counts_raise(n):
    s = icosphere_trimesh(1, 1.0)
    with pytest.raises(ValueError, match="n_samples"):
        metrics.hausdorff_distance(s, s, n_samples=n)
    with pytest.raises(ValueError, match="max_iterations"):
        metrics.icp_align(s, s, max_iterations=n)


def test_degenerate_inputs_raise():
    point = (np.zeros((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="zero surface area"):
        metrics.chamfer_distance(point, icosphere_trimesh(1, 1.0), n_samples=10)
    with pytest.raises(ValueError, match="zero bounding radius"):
        metrics.normalize_to_unit_sphere(point)


def test_public_namespace():
    assert jaxgenus.metrics is metrics
    for name in metrics.__all__:
        assert callable(getattr(metrics, name))
