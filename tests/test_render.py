"""Tests of jaxgenus.render against a dense reference, finite differences and analytic values."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxgenus as jg
from _meshes import icosphere, torus
from dense_reference import dense_render

ALL = ("alpha", "normal", "depth", "shaded")


def _with_vertices(mesh, v):
    return jg.Mesh(v, mesh.faces, mesh.n_vertices, mesh.n_faces)


def _weights(shape, seed=1):
    return jnp.asarray(np.random.default_rng(seed).standard_normal(shape), jnp.float32)


def _rel(a, b):
    return float(jnp.max(jnp.abs(a - b)) / jnp.maximum(jnp.max(jnp.abs(b)), 1e-30))


def _value_and_grad(mesh, cams, channels=ALL, **kw):
    """Image, loss and vertex gradient of a random linear loss, in one pass."""
    c = sum(jg.rendering.CHANNEL_SIZES[x] for x in channels)
    w = _weights((len(cams), cams.height, cams.width, c))

    def loss(v):
        img = jg.render(_with_vertices(mesh, v), cams, channels=channels, **kw)
        return jnp.sum(img * w), img

    (val, img), g = jax.value_and_grad(loss, has_aux=True)(mesh.vertices)
    return img, val, g


# ---------------------------------------------------------------- dense reference


@pytest.mark.parametrize(
    "channels,cull,sigma,gamma",
    [
        (ALL, True, 0.5, 0.01),
        (("alpha",), True, 2.0, 0.01),
        (("normal", "depth", "shaded"), False, 0.1, 0.02),
    ],
)
def test_matches_dense_reference(channels, cull, sigma, gamma):
    mesh = icosphere(2, noise=0.1)
    cams = jg.sphere_cameras(2, radius=4.0, resolution=24)
    c = sum(jg.rendering.CHANNEL_SIZES[x] for x in channels)
    w = _weights((2, 24, 24, c))
    kw = dict(channels=channels, sigma=sigma, gamma=gamma)
    plan = jg.rendering.plan_render(mesh, cams, sigma=sigma, cull_backfaces=cull)

    def fast(v):
        return jg.render(_with_vertices(mesh, v), cams, cull_backfaces=cull, plan=plan, **kw)

    def ref(v):
        return dense_render(_with_vertices(mesh, v), cams, cull=cull, **kw)

    a, b = fast(mesh.vertices), ref(mesh.vertices)
    assert a.shape == b.shape == (2, 24, 24, c)
    assert _rel(a, b) <= 1e-4
    ga = jax.grad(lambda v: jnp.sum(fast(v) * w))(mesh.vertices)
    gb = jax.grad(lambda v: jnp.sum(ref(v) * w))(mesh.vertices)
    assert _rel(ga, gb) <= 3e-4  # float32; the blend's coverage exponent amplifies rounding
    assert float(jnp.linalg.norm(ga - gb) / jnp.linalg.norm(gb)) <= 1e-4


def test_two_tier_plan_matches_dense_reference():
    """Faces larger than the small window go to the big tier and are rendered in full."""
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(1, radius=3.0, resolution=24)
    plan = jg.rendering.RasterPlan(window=5, max_faces=80, big_window=24, max_big_faces=80)
    img, info = jg.render(mesh, cams, channels=ALL, sigma=0.5, plan=plan, return_info=True)
    assert int(info.n_overflow) == 0
    ref = dense_render(mesh, cams, channels=ALL, sigma=0.5, gamma=0.01)
    assert _rel(img, ref) <= 1e-4
    w = _weights(img.shape)
    ga = jax.grad(lambda v: jnp.sum(jg.render(_with_vertices(mesh, v), cams, channels=ALL, sigma=0.5, plan=plan) * w))(
        mesh.vertices
    )
    gb = jax.grad(lambda v: jnp.sum(dense_render(_with_vertices(mesh, v), cams, channels=ALL, sigma=0.5,
                                                 gamma=0.01) * w))(mesh.vertices)
    assert _rel(ga, gb) <= 3e-4  # float32; the blend's coverage exponent amplifies rounding


# ---------------------------------------------------------------- finite differences


def test_finite_differences_float64():
    with jax.enable_x64(True):
        v = np.array([[-0.6, -0.5, 0.1], [0.7, -0.4, 0.0], [0.1, 0.6, -0.1], [0.0, 0.0, 0.8]])
        f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
        mesh = jg.Mesh.from_numpy(v, f)
        assert mesh.vertices.dtype == jnp.float64
        cams = jg.look_at(np.array([[0.3, 0.2, 3.0], [2.5, 0.5, -1.0]]), resolution=12, fov_deg=45.0)
        w = jnp.asarray(np.random.default_rng(2).standard_normal((2, 12, 12, 6)))
        plan = jg.rendering.plan_render(mesh, cams, sigma=4.0)

        def loss(x):
            img = jg.render(_with_vertices(mesh, x.reshape(4, 3)), cams, channels=ALL, sigma=4.0, gamma=0.3,
                            plan=plan)
            assert img.dtype == jnp.float64
            return jnp.sum(img * w)

        x0 = mesh.vertices.reshape(-1)
        g = np.asarray(jax.grad(loss)(x0))
        h = 1e-6
        fd = np.array([(loss(x0.at[i].add(h)) - loss(x0.at[i].add(-h))) / (2 * h) for i in range(12)])
        assert np.allclose(g, fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize(
    "shape,res,channels",
    [
        ("sphere", 128, ("alpha",)),
        ("torus", 96, ("alpha", "normal")),
        ("torus", 64, ALL),
    ],
)
def test_default_render_is_continuous_central_differences(shape, res, channels):
    """The default render (smooth facing cull, no plan) against float64 central
    differences along random directions: a hard cut of faces that turn away at the
    contour, or a faint tail that switches a pixel's surface at the blur cutoff, makes
    the difference quotient jump (main before this: -211 / -1908 against 56)."""
    with jax.enable_x64(True):
        if shape == "sphere":
            s = trimesh.creation.icosphere(subdivisions=3)
        else:
            s = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=48, minor_sections=24)
        mesh = jg.Mesh.from_numpy(np.asarray(s.vertices, np.float64), s.faces)
        cams = jg.sphere_cameras(12, radius=3.5, resolution=res, fov_deg=45.0)
        target = jg.render(jg.Mesh.from_numpy(0.9 * np.asarray(s.vertices), s.faces), cams, channels=channels)

        def loss(x):
            return jnp.sum((jg.render(_with_vertices(mesh, x), cams, channels=channels) - target) ** 2)

        f = jax.jit(loss)
        g = jax.jit(jax.grad(loss))(mesh.vertices)
        assert g.dtype == jnp.float64
        rng = np.random.default_rng(0)
        eps = 1e-4
        for _ in range(3):
            d = rng.standard_normal(mesh.vertices.shape)
            d = jnp.asarray(d / np.linalg.norm(d))
            analytic = float(jnp.sum(g * d))
            fd = (float(f(mesh.vertices + eps * d)) - float(f(mesh.vertices - eps * d))) / (2 * eps)
            assert abs(fd - analytic) <= 0.03 * abs(analytic), (fd, analytic)


# ---------------------------------------------------------------- analytic silhouette


def test_sphere_alpha_matches_disc_area():
    s = trimesh.creation.icosphere(subdivisions=3)
    mesh = jg.Mesh.from_numpy(s.vertices, s.faces)
    d, r = 3.0, 1.0
    cams = jg.sphere_cameras(3, radius=d, resolution=128, fov_deg=50.0)
    f = float(cams.focal[0, 0])
    disc = math.pi * (f * r / math.sqrt(d * d - r * r)) ** 2
    area = jg.render(mesh, cams, channels=("alpha",), sigma=1e-3)[..., 0].sum(axis=(1, 2))
    assert np.all(np.abs(np.asarray(area) / disc - 1.0) < 0.03)


def test_fine_mesh_is_opaque_inside_and_its_silhouette_unbiased():
    """Faces about a pixel wide: every pixel well inside the disc has alpha 1
    (SoftRas' product gives 0.75 on each shared edge), and the area is the disc's
    (the outside tails of the thin faces at the contour add ~1.4 % at sigma = 0.1)."""
    s = trimesh.creation.icosphere(subdivisions=4)
    mesh = jg.Mesh.from_numpy(s.vertices, s.faces)
    d, r = 3.0, 1.0
    cams = jg.sphere_cameras(2, radius=d, resolution=64, fov_deg=50.0)
    f = float(cams.focal[0, 0])
    rpx = f * r / math.sqrt(d * d - r * r)
    alpha = np.asarray(jg.render(mesh, cams, channels=("alpha",))[..., 0])
    yy, xx = np.mgrid[0:64, 0:64] + 0.5
    rho = np.hypot(xx - 32.0, yy - 32.0)
    assert np.all(alpha[:, rho < rpx - 1.5] >= 1.0 - 1e-6)
    assert np.all(alpha[:, rho > rpx + 1.5] < 1e-3)
    ratio = alpha.sum(axis=(1, 2)) / (math.pi * rpx**2)
    assert np.all(np.abs(ratio - 1.0) < 0.02), ratio
    sharp = np.asarray(jg.render(mesh, cams, channels=("alpha",), sigma=0.03)[..., 0]).sum(axis=(1, 2))
    assert np.all(np.abs(sharp / (math.pi * rpx**2) - 1.0) < 0.005), sharp / (math.pi * rpx**2)


# ---------------------------------------------------------------- numerical stability


def _finite(mesh, cams, **kw):
    img, val, g = _value_and_grad(mesh, cams, **kw)
    assert bool(jnp.all(jnp.isfinite(img)))
    assert bool(jnp.isfinite(val))
    assert bool(jnp.all(jnp.isfinite(g)))
    return img, g


def _tri_mesh(v, f=((0, 1, 2),)):
    return jg.Mesh.from_numpy(np.asarray(v, float), np.asarray(f), capacity=4)


CAM = dict(eye=np.array([[0.0, 0.0, -3.0]]), resolution=16)


@pytest.mark.parametrize(
    "verts",
    [
        [[0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 1, 0]],  # all coincident
        [[0, 0, 0], [0.5, 0.5, 0], [0, 0, 0], [1, 1, 0]],  # two coincident
        [[-0.5, 0, 0], [0, 0, 0], [0.5, 0, 0], [1, 1, 0]],  # collinear
        [[0, -0.5, 0], [0, 0.5, 0], [0, 0, 0.5], [1, 1, 0]],  # edge-on (plane contains the view ray)
    ],
)
def test_degenerate_faces_are_finite(verts):
    _finite(_tri_mesh(verts, [(0, 1, 2), (1, 2, 3)]), jg.look_at(**CAM), cull_backfaces=False)


@pytest.mark.parametrize("z", [-3.0, -2.0, -3.5])  # vertex at the camera centre, on z=1 plane, behind
def test_vertex_at_or_behind_camera_is_finite(z):
    cams = jg.look_at(**CAM)
    mesh = _tri_mesh([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.0, z]], [(0, 1, 2), (0, 2, 1)])
    img, _ = _finite(mesh, cams, cull_backfaces=False)


def test_face_crossing_near_plane_is_skipped_and_finite():
    cams = jg.look_at(**CAM)
    big = _tri_mesh([[-0.5, -0.5, -2.99], [0.5, -0.5, 0.0], [0.0, 0.5, -3.5]], [(0, 1, 2), (0, 2, 1)])
    img, _ = _finite(big, cams, cull_backfaces=False, znear=0.05)
    assert float(jnp.max(img[..., 0])) == 0.0


@pytest.mark.parametrize("sigma", [1e-6, 10.0])
def test_sigma_range_is_finite(sigma):
    _finite(icosphere(1, noise=0.1), jg.sphere_cameras(2, radius=3.0, resolution=16), sigma=sigma)


@pytest.mark.parametrize("gamma", [1e-4, 1.0])
def test_gamma_range_is_finite(gamma):
    img, g = _finite(icosphere(1, noise=0.1), jg.sphere_cameras(2, radius=3.0, resolution=16), gamma=gamma)
    assert float(jnp.max(jnp.abs(g))) > 0


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_scaled_scene_is_scale_invariant(scale):
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    scaled_mesh = _with_vertices(mesh, mesh.vertices * scale)
    scaled_cams = jg.Cameras(cams.rotation, cams.translation * scale, cams.focal, cams.principal_point, 16, 16)
    img, g = _finite(scaled_mesh, scaled_cams, znear=1e-4 * min(scale, 1.0))
    ref = jg.render(mesh, cams, channels=ALL)
    scale_ch = jnp.array([1, 1, 1, 1, scale, 1], jnp.float32)  # depth scales
    assert _rel(img / scale_ch, ref) < 1e-3


def test_scaled_mesh_fixed_cameras_is_finite():
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    mesh = icosphere(1, noise=0.1)
    plan = jg.rendering.RasterPlan(window=16, max_faces=80)
    for scale in (1e-3, 1e3):  # a dot, and cameras inside a huge sphere
        _finite(_with_vertices(mesh, mesh.vertices * scale), cams, plan=plan)


def test_mesh_outside_view_renders_background():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    far = _with_vertices(mesh, mesh.vertices + jnp.array([50.0, 0.0, 0.0]))
    img, g = _finite(far, cams, background={"normal": (0.1, 0.2, 0.3), "depth": 7.0, "shaded": 0.5})
    expect = jnp.array([0.0, 0.1, 0.2, 0.3, 7.0, 0.5])
    assert float(jnp.max(jnp.abs(img - expect))) < 1e-6
    assert float(jnp.max(jnp.abs(g))) == 0.0


# ---------------------------------------------------------------- API behaviour


def test_padding_never_covers_a_pixel():
    tight = icosphere(1, noise=0.1)
    padded = icosphere(1, noise=0.1, capacity=200)
    cams = jg.sphere_cameras(3, radius=3.0, resolution=20)
    a = jg.render(tight, cams, channels=ALL)
    b = jg.render(padded, cams, channels=ALL)
    assert _rel(b, a) < 1e-5
    # padding vertices moved into view still render nothing
    moved = _with_vertices(padded, padded.vertices.at[tight.vertex_capacity :].set(0.3))
    assert _rel(jg.render(moved, cams, channels=ALL), a) < 1e-5


def test_channel_order_and_sizes():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    full = jg.render(mesh, cams, channels=ALL)
    assert full.shape == (2, 16, 16, 6)
    swapped = jg.render(mesh, cams, channels=("shaded", "normal", "alpha"))
    np.testing.assert_allclose(swapped[..., 0], full[..., 5], atol=1e-6)
    np.testing.assert_allclose(swapped[..., 1:4], full[..., 1:4], atol=1e-6)
    np.testing.assert_allclose(swapped[..., 4], full[..., 0], atol=1e-6)
    alpha = jg.render(mesh, cams, channels="alpha")
    np.testing.assert_allclose(alpha[..., 0], full[..., 0], atol=1e-6)
    # where the surface is solid, normals are blends of unit face normals (two
    # to four neighbours up to 40 degrees apart on this coarse sphere)
    n = np.asarray(full[..., 1:4])
    solid = np.asarray(full[..., 0]) > 0.99
    norms = np.linalg.norm(n[solid], axis=-1)
    assert np.all(norms <= 1.0 + 1e-5) and np.median(norms) > 0.99, (norms.min(), np.median(norms))
    assert np.all(norms > 0.8), norms.min()


def test_silhouette_only_call_does_no_blend_work():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    jaxpr = str(jax.make_jaxpr(lambda v: jg.render(_with_vertices(mesh, v), cams, channels=("alpha",)))(
        mesh.vertices))
    assert "scatter-max" not in jaxpr and "exp" in jaxpr
    jaxpr_n = str(jax.make_jaxpr(lambda v: jg.render(_with_vertices(mesh, v), cams, channels=("normal",)))(
        mesh.vertices))
    assert "scatter_max" in jaxpr_n or "scatter-max" in jaxpr_n


def test_jit_scan_value_and_grad_with_camera_subsets():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(6, radius=3.0, resolution=16)
    plan = jg.rendering.plan_render(mesh, cams)
    target = jg.render(_with_vertices(mesh, mesh.vertices * 0.9), cams, channels=("alpha", "normal"), plan=plan)

    def loss(v, idx):
        img = jg.render(_with_vertices(mesh, v), cams[idx], channels=("alpha", "normal"), plan=plan)
        return jnp.mean((img - target[idx]) ** 2)

    @jax.jit
    def run(v):
        def step(v, key):
            idx = jax.random.choice(key, 6, (2,), replace=False)
            val, g = jax.value_and_grad(loss)(v, idx)
            return v - 0.5 * g, val

        return jax.lax.scan(step, v, jax.random.split(jax.random.PRNGKey(0), 4))

    v, vals = run(mesh.vertices)
    assert bool(jnp.all(jnp.isfinite(v))) and bool(jnp.all(jnp.isfinite(vals)))


def test_vmap_over_meshes_and_cameras():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=16)
    plan = jg.rendering.plan_render(mesh, cams, face_margin=1.5)
    verts = jnp.stack([mesh.vertices, mesh.vertices * 0.8])
    batched = jax.jit(jax.vmap(lambda v: jg.render(_with_vertices(mesh, v), cams, plan=plan)))(verts)
    for i in range(2):
        single = jg.render(_with_vertices(mesh, verts[i]), cams, plan=plan)
        assert _rel(batched[i], single) < 1e-5
    # vmap over single cameras (a leading axis on every camera field)
    per_cam = jax.vmap(lambda r, t, f, c: jg.render(mesh, jg.Cameras(r[None], t[None], f[None], c[None], 16, 16),
                                                    plan=plan)[0])(
        cams.rotation, cams.translation, cams.focal, cams.principal_point)
    assert _rel(per_cam, jg.render(mesh, cams, plan=plan)) < 1e-5


def test_overflow_is_counted():
    mesh = icosphere(1, noise=0.1)
    cams = jg.sphere_cameras(2, radius=3.0, resolution=32)
    _, info = jg.render(mesh, cams, return_info=True)  # plan chosen from the geometry
    assert int(info.n_overflow) == 0 and int(jnp.min(info.n_visible)) > 0
    _, info = jg.render(mesh, cams, plan=jg.rendering.RasterPlan(window=4, max_faces=80), return_info=True)
    assert int(jnp.sum(info.n_truncated)) > 0 and int(jnp.sum(info.n_dropped)) == 0
    _, info = jg.render(mesh, cams, plan=jg.rendering.RasterPlan(window=32, max_faces=8), return_info=True)
    np.testing.assert_array_equal(info.n_dropped, info.n_visible - 8)
    # inside jit without a plan: the generic plan still reports its coverage
    _, info = jax.jit(lambda m: jg.render(m, cams, return_info=True))(mesh)
    assert int(info.n_overflow) == 0


@pytest.mark.parametrize(
    "kwargs,name",
    [
        (dict(channels=("alpha", "color")), "channels"),
        (dict(channels=()), "channels"),
        (dict(sigma=0.0), "sigma"),
        (dict(sigma=-1.0), "sigma"),
        (dict(gamma=0.0), "gamma"),
        (dict(background={"alpha": 1.0}), "background"),
        (dict(background={"normal": 1.0}), "background"),
        (dict(plan="big"), "plan"),
    ],
)
def test_bad_arguments_raise(kwargs, name):
    mesh = icosphere(0, noise=0.1)
    cams = jg.sphere_cameras(1, resolution=8)
    with pytest.raises(ValueError, match=name):
        jg.render(mesh, cams, **kwargs)


def test_bad_types_raise():
    mesh = icosphere(0, noise=0.1)
    cams = jg.sphere_cameras(1, resolution=8)
    with pytest.raises(ValueError, match="mesh"):
        jg.render(mesh.vertices, cams)
    with pytest.raises(ValueError, match="cameras"):
        jg.render(mesh, mesh)


def test_face_and_vertex_normals_match_trimesh():
    s = trimesh.creation.icosphere(subdivisions=1)
    mesh = jg.Mesh.from_numpy(s.vertices, s.faces, capacity=128)
    fn = np.asarray(jg.geometry.face_normals(mesh))
    np.testing.assert_allclose(fn[: len(s.faces)], s.face_normals, atol=1e-5)
    assert np.all(fn[len(s.faces):] == 0)
    vn = np.asarray(jg.geometry.vertex_normals(mesh))
    tm = trimesh.Trimesh(s.vertices, s.faces, process=False)
    w = tm.area_faces[:, None] * tm.face_normals
    acc = np.zeros_like(s.vertices)
    for k in range(3):
        np.add.at(acc, s.faces[:, k], w)
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    np.testing.assert_allclose(vn[: len(s.vertices)], acc, atol=1e-5)
    assert np.all(vn[len(s.vertices):] == 0)
    # a zero-area face has a zero normal and a finite gradient
    deg = jg.Mesh.from_numpy(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    g = jax.grad(lambda v: jnp.sum(jg.geometry.face_normals(_with_vertices(deg, v))))(deg.vertices)
    assert bool(jnp.all(jnp.isfinite(g)))


def test_values_rendered_beside_flat_colours_equal_their_own_render():
    """`"values"` (per-vertex, interpolated) in the pass of flat `"color"` and depth: the same images
    as two renders, each on its own, and the same gradients (float64: no summation-order noise)."""
    with jax.enable_x64(True):
        mesh = torus(1.0, 0.35, 24, 12, dtype=jnp.float64)
        cams = jg.sphere_cameras(3, radius=3.0, fov_deg=40.0, resolution=40)
        rng = np.random.default_rng(3)
        fc = jnp.asarray(rng.uniform(0, 1, (mesh.face_capacity, 3)))
        vv = jnp.asarray(rng.uniform(0, 1, (mesh.vertex_capacity, 3)))
        w = jnp.asarray(rng.normal(size=(3, 40, 40, 8)))

        def apart(v, fc, vv):
            m = eqx.tree_at(lambda q: q.vertices, mesh, v)
            a = jg.render(m, cams, channels=("alpha", "color", "depth"), face_colors=fc)
            b = jg.render(m, cams, channels=("alpha", "color"), vertex_colors=vv)
            return jnp.concatenate([a, b[..., 1:]], axis=-1)

        def together(v, fc, vv):
            m = eqx.tree_at(lambda q: q.vertices, mesh, v)
            return jg.render(m, cams, channels=("alpha", "color", "depth", "values"), face_colors=fc, vertex_values=vv)

        args = (mesh.vertices, fc, vv)
        np.testing.assert_array_equal(np.asarray(together(*args)), np.asarray(apart(*args)))
        ga = jax.grad(lambda *a: jnp.sum(apart(*a) * w), argnums=(0, 1, 2))(*args)
        gt = jax.grad(lambda *a: jnp.sum(together(*a) * w), argnums=(0, 1, 2))(*args)
        for x, y in zip(gt, ga):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-9, atol=1e-9 * float(jnp.abs(y).max()))
    with pytest.raises(ValueError, match="vertex_values"):
        jg.render(mesh, cams, channels=("alpha", "values"))
