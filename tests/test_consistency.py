"""Photo-consistency (jaxgenus.optim._consistency) against photos ray cast by trimesh, not by our renderer."""

import numpy as np
import pytest

import jax
import jax.numpy as jnp

import jaxgenus as jg
from jaxgenus.optim import (ROBUST_SPREAD, consistency_windows, optimize_block, init_optimizer_state, photo_consistency,
                            robust_cost, view_neighbours)
from _dumps import assert_full_precision, dumped_programs
from _meshes import torus, torus_trimesh
from _raycast import cell_albedo, raycast_depth, raycast_lambert

LIGHT = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])


#: A high-frequency albedo: 3D cells of 0.1 with hashed colours.
cells = cell_albedo(0.1)


@pytest.fixture(scope="module")
def scene():
    tm = torus_trimesh(1.0, 0.35, 64, 32)
    cams = jg.sphere_cameras(24, radius=3.0, fov_deg=40.0, resolution=96)
    photos = np.asarray(raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.25, albedo=cells), np.float32)
    photos[..., :3] *= photos[..., 3:4]  # premultiplied, as the pipeline fits them
    return cams, jnp.asarray(photos), view_neighbours(cams)


def _smoothed(photos):
    """`photos` blurred by the binomial kernel [1, 4, 6, 4, 1] / 16 along both image axes (edges
    clamped), written here in NumPy: the unblurred term's value is smooth enough in the vertices for
    central differences only on smooth photos (on these 96² cells the bilinear sampling's kinks put
    them 21 % off)."""
    k = np.asarray([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    x = np.asarray(photos, np.float64)
    for axis in (1, 2):
        pad = [(0, 0)] * x.ndim
        pad[axis] = (2, 2)
        p = np.pad(x, pad, mode="edge")
        x = sum(w * np.take(p, np.arange(i, i + x.shape[axis]), axis=axis) for i, w in enumerate(k))
    return x


def _loss(mesh, cams, photos, table, gain=1.0, blur=1.0, colour=False):
    nb = jnp.asarray(table[:, 0])
    r = jg.render(mesh, cams, channels=("alpha", "depth"))
    nd = jg.render(mesh, cams[nb], channels=("depth", "alpha"))
    return photo_consistency(r[..., 1], r[..., 0], cams, photos * jnp.asarray([gain, gain, gain, 1.0]), cams[nb],
                             photos[nb], nd, blur=blur, colour=colour)


def _isoluminant(p):
    """Checker cells of 0.1 in red or in green of the same grey level (luma 0.299 R = 0.587 G): an
    edge only R, G, B show."""
    c = np.floor(np.asarray(p, np.float64) / 0.1).astype(np.int64)
    odd = (c.sum(axis=1) % 2 == 1)[:, None]
    return np.where(odd, [[0.8, 0.0, 0.0]], [[0.0, 0.8 * 0.299 / 0.587, 0.0]])


def test_neighbours_are_nearby_views_not_itself(scene):
    cams, _, table = scene
    assert table.shape == (24, 4) and table.dtype == np.int32
    d = np.array(cams.centers)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for i, row in enumerate(table):
        angles = np.degrees(np.arccos(np.clip(d[row] @ d[i], -1, 1)))
        assert np.all(row != i) and np.all((angles >= 5) & (angles <= 60))
        assert len(set(row.tolist())) == 4  # a sparse ring (views ~40 degrees apart) fills up with wider ones
    lone = jg.Cameras(cams.rotation[:1], cams.translation[:1], cams.focal[:1], cams.principal_point[:1], 96, 96)
    assert view_neighbours(lone).tolist() == [[0, 0, 0, 0]]  # no neighbour: paired with itself (no signal)


@pytest.mark.parametrize("blur, colour", [(1.0, False), (0.0, False), (0.0, True)])
def test_minimum_at_the_true_surface_and_exposure_invariant(scene, blur, colour):
    cams, photos, table = scene
    losses = {s: float(_loss(torus(1.0, 0.35 * s, 64, 32), cams, photos, table, blur=blur, colour=colour)[0])
              for s in (0.9, 0.97, 1.0, 1.03, 1.1)}
    assert losses[1.0] < 0.85 * min(losses[0.97], losses[1.03]) and losses[1.0] < 0.5 * min(losses[0.9], losses[1.1]), losses
    darker, count = _loss(torus(1.0, 0.35, 64, 32), cams, photos, table, gain=0.6, blur=blur,
                          colour=colour)  # exposure changed
    assert abs(float(darker) - losses[1.0]) < 0.02 and float(count) > 100
    if blur == 0.0 and not colour:  # half a blur lies between none and all of it
        half = float(_loss(torus(1.0, 0.35, 64, 32), cams, photos, table, blur=0.5)[0])
        full = float(_loss(torus(1.0, 0.35, 64, 32), cams, photos, table)[0])
        assert min(full, losses[1.0]) < half < max(full, losses[1.0]), (full, half, losses[1.0])
        with pytest.raises(ValueError, match="blur"):
            _loss(torus(1.0, 0.35, 64, 32), cams, photos, table, blur=1.5)
        with pytest.raises(ValueError, match="consistency_blur"):
            jg.LossWeights(consistency_blur=2.0)
        with pytest.raises(ValueError, match="consistency_colour"):
            jg.LossWeights(consistency_colour=0.5)


def test_colour_sees_an_edge_of_equal_grey():
    """Red and green cells of one grey level: the grey term finds no texture, the colour term finds it
    and has its minimum at the true surface."""
    cams = jg.sphere_cameras(12, radius=3.0, fov_deg=40.0, resolution=96)
    tm = torus_trimesh(1.0, 0.35, 64, 32)
    photos = np.asarray(raycast_lambert(cams, tm, light_direction=LIGHT, ambient=1.0, albedo=_isoluminant), np.float32)
    photos[..., :3] *= photos[..., 3:4]
    grey = np.asarray(photos[..., :3] @ np.asarray([0.299, 0.587, 0.114], np.float32))
    inside = photos[..., 3] > 0.99
    assert np.std(grey[inside]) < 0.3 * np.std(photos[..., 0][inside])  # the shading alone varies the grey
    table, photos = view_neighbours(cams), jnp.asarray(photos)
    _, grey_windows = _loss(torus(1.0, 0.35, 64, 32), cams, photos, table, blur=0.0)
    losses = {s: _loss(torus(1.0, 0.35 * s, 64, 32), cams, photos, table, blur=0.0, colour=True)
              for s in (0.93, 1.0, 1.07)}
    assert float(losses[1.0][1]) > 3 * float(grey_windows), (float(losses[1.0][1]), float(grey_windows))
    assert float(losses[1.0][0]) < 0.7 * min(float(losses[0.93][0]), float(losses[1.07][0])), losses


@pytest.mark.parametrize("splat, blur, colour", [("default", 1.0, False), ("jax", 1.0, False), ("default", 0.0, False),
                                                 ("default", 0.0, True)])
def test_gradient_matches_finite_differences_and_points_to_the_surface(scene, splat, blur, colour):
    """Both renderer paths: the default (native kernel on CPU) and the JAX splat with one fixed plan
    (the GPU path; a plan per call would differ between the traced and the concrete evaluations).
    Unblurred (`blur` 0, as for a fine texture) on photos this test smooths itself (`_smoothed`)."""
    cams, photos, table = scene
    if splat == "default" and jax.default_backend() != "cpu":
        pytest.skip("off CPU the default path plans per call; the 'jax' case covers it")
    with jax.enable_x64(True):
        m = torus(1.0, 0.35 * 1.04, 32, 16, dtype=jnp.float64)
        c64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), cams)
        p64 = jnp.asarray(photos if blur else _smoothed(photos) if not colour else _smoothed(_smoothed(photos)),
                          jnp.float64)  # each channel's cells jump more than their grey level: smoothed twice
        nb = jnp.asarray(table[:, 0])
        plan = None if splat == "default" else jg.rendering.plan_render(m, c64, sigma=0.1)
        nd = jax.lax.stop_gradient(jg.render(m, c64[nb], channels=("depth", "alpha"), plan=plan))

        def f(v, spread=0.0):  # 0: the plain residual (the robust scale is held constant, its gradient not taken)
            mm = jg.Mesh(vertices=v, faces=m.faces, n_vertices=m.n_vertices, n_faces=m.n_faces)
            r = jg.render(mm, c64, channels=("alpha", "depth"), plan=plan)
            return photo_consistency(r[..., 1], r[..., 0], c64, p64, c64[nb], p64[nb], nd, spread=spread,
                                     blur=blur, colour=colour)[0]

        g = jax.grad(f)(m.vertices)
        assert bool(jnp.all(jnp.isfinite(g)))
        rng = np.random.default_rng(0)
        for _ in range(3):  # directional derivatives along smooth random fields
            d = jnp.asarray(np.sin(m.vertices @ rng.normal(size=(3, 3))) * 1e-3)
            h = 1e-3
            fd = (f(m.vertices + h * d) - f(m.vertices - h * d)) / (2 * h)
            an = jnp.sum(g * d)
            assert abs(float(fd - an)) <= 0.1 * abs(float(fd)) + 1e-6, (float(fd), float(an))
        # too fat: descending moves the vertices inwards (towards the tube's core circle)
        v = np.asarray(m.vertices)
        radial = v.copy()
        radial[:, 2] = 0.0  # the torus is about z
        core = radial / np.linalg.norm(radial, axis=1, keepdims=True)
        outward = v - core
        outward /= np.linalg.norm(outward, axis=1, keepdims=True)
        assert float(np.sum(np.asarray(g) * outward)) > 0
        robust = np.asarray(jax.grad(lambda v: f(v, ROBUST_SPREAD))(m.vertices))  # the default cost
        assert np.all(np.isfinite(robust)) and float(np.sum(robust * outward)) > 0


def test_robust_cost_follows_the_median_and_bounds_outliers():
    r = jnp.asarray([0.02, 0.03, 0.05, 0.5, 1.0, 3.0])
    w = jnp.asarray([1.0, 1.0, 1.0, 1.0, 1.0, 0.0])  # the last window is not valid
    c = ROBUST_SPREAD * 0.05  # the median of the valid residuals is 0.05
    cost = np.asarray(robust_cost(r, w))
    np.testing.assert_allclose(cost[:5], c * r[:5] / (r[:5] + c), rtol=1e-5)
    assert np.all(np.diff(cost[:5]) > 0) and np.all(cost <= c + 1e-7)
    slope = np.asarray(jax.grad(lambda x: jnp.sum(robust_cost(x, w)))(r))
    assert slope[0] > 0.6 and slope[4] < 0.01  # a fitting window pulls nearly as its residual, an outlier hardly
    np.testing.assert_allclose(np.asarray(robust_cost(r, w, spread=0.0)), np.clip(r, 0.0, 1.0))
    none = robust_cost(r, jnp.zeros_like(w))  # no valid window: scale spread x 1, finite
    assert np.all(np.isfinite(np.asarray(none)))


def test_highlights_in_some_views_leave_the_minimum_at_the_surface(scene):
    """A specular highlight (a saturated blob in 6 views that no neighbour shares) must not move the
    minimum off the true surface, nor give NaN."""
    cams, photos, table = scene
    v, u = np.mgrid[0:96, 0:96]
    blob = np.exp(-((u - 40.0) ** 2 + (v - 52.0) ** 2) / (2 * 6.0**2))[..., None]
    shiny = np.asarray(photos).copy()
    shiny[::4, ..., :3] = np.minimum(shiny[::4, ..., :3] + 2.0 * blob * shiny[::4, ..., 3:4], shiny[::4, ..., 3:4])
    shiny = jnp.asarray(shiny)
    losses = {s: float(_loss(torus(1.0, 0.35 * s, 64, 32), cams, shiny, table)[0]) for s in (0.95, 1.0, 1.05)}
    assert all(np.isfinite(list(losses.values()))) and losses[1.0] < min(losses[0.95], losses[1.05]), losses


def test_nothing_to_work_with_gives_zero_not_nan(scene):
    cams, photos, table = scene
    flat = photos.at[..., :3].set(0.5 * photos[..., 3:4])  # textureless
    loss, count = _loss(torus(1.0, 0.35, 64, 32), cams, flat, table)
    assert float(loss) == 0.0 and float(count) == 0.0
    empty = photos.at[..., 3].set(0.0)  # no mask anywhere
    loss, count = _loss(torus(1.0, 0.35, 64, 32), cams, empty, table)
    assert float(loss) == 0.0 and float(count) == 0.0
    far = torus(1.0, 0.35, 64, 32)
    far = jg.Mesh(vertices=far.vertices + jnp.asarray([50.0, 0.0, 0.0]), faces=far.faces, n_vertices=far.n_vertices,
                  n_faces=far.n_faces)  # out of every view
    assert np.isfinite(float(_loss(far, cams, photos, table)[0]))


def test_windows_and_block_with_neighbours(scene):
    cams, photos, table = scene
    m = torus(1.0, 0.36, 48, 24)
    nb = jnp.asarray(table[:, 0])
    r = jg.render(m, cams, channels=("alpha", "depth"))
    nd = jg.render(m, cams[nb], channels=("depth", "alpha"))
    ncc, w = consistency_windows(r[..., 1], r[..., 0], cams, photos, cams[nb], photos[nb], nd)
    assert ncc.shape == w.shape and ncc.shape[0] == 24
    assert bool(jnp.all(jnp.abs(jnp.where(w > 0, ncc, 0.0)) <= 1.0 + 1e-4))
    state = init_optimizer_state(m, jax.random.key(0), albedo=0.5)
    opts = jg.OptimizeOptions(weights=jg.LossWeights(consistency=0.5))
    state, rec = optimize_block(state, cams, photos, n_steps=3, options=opts, neighbours=table)
    assert np.all(np.asarray(rec["consistency"]) > 0) and np.all(np.asarray(rec["status"]) == 0)
    with pytest.raises(ValueError, match="neighbours"):
        optimize_block(state, cams, photos, n_steps=1, options=opts, neighbours=table[:3])
    with pytest.raises(ValueError, match="neighbours"):
        optimize_block(state, cams, photos, n_steps=1, options=opts, neighbours=table + 20)


def test_reconstruct_with_photo_consistency_reports_residuals(tmp_path):
    """A small photo fit end to end; every program it compiles asks for full-precision float32 products
    (test_precision)."""
    tm = torus_trimesh(1.0, 0.35, 64, 32)
    cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
    straight = np.asarray(raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.25, albedo=cells), np.float32)
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=15, consistency=1.0, polish_cycles=2)
    rows, lines = [], []
    with dumped_programs(tmp_path):
        rec = jg.reconstruct(straight, cams, 1, targets="photo", options=opts, key=jax.random.key(0),
                             callback=lambda row, mesh: rows.append(row), log=lines.append)
    assert_full_precision(tmp_path)
    res = np.asarray(rec.history["photo_consistency"], np.float64)
    assert res.shape == (16,) and np.any(np.isfinite(res)) and np.all(res[np.isfinite(res)] <= 1.0)
    assert np.any(np.asarray(rec.history["consistency"]) > 0)
    # two polish cycles close the fit (set here; by default for fine textures): no remesh, silhouettes and
    # photo-consistency only
    cycles = rec.history["cycles"]
    assert [c.polish for c in cycles] == [False, False, True, True] and rows == list(cycles)
    assert all(c.n_cycles == 4 and c.remesh_status is None and c.faces == cycles[1].faces for c in cycles[2:])
    # the last level is the photos' own size: the depth sweep runs before the polish, not after the fit
    assert rec.history.resolution[-1]["factor"] == 1
    assert [line.split(",")[0] for line in lines if line.startswith("photo depth:")] == [
        "photo depth: before the polish"], lines
    polish = slice(30, 60)
    assert len(rec.history["loss"]) == 60 and np.all(np.isfinite(rec.history["loss"]))
    terms = {k: np.asarray(rec.history[k])[polish] for k in ("photo", "consistency")}
    assert np.all(terms["photo"] == 0) and np.any(terms["consistency"] > 0)
    # 30 steps leave this fit short of the ray-cast torus: where the photos agree less on it than on the
    # visual hull it started from, the verdict says so (the rule itself: test_capture_layouts)
    warnings = rec.history["warnings"]
    assert rec.genus == 1 and (rec.history["ok"] or any(w.startswith("the photos agree less") for w in warnings)), warnings
    # without the term: no residuals and no polish (test_unseen's photo fits, which turn it off)


def test_occluding_contours_inside_the_silhouette_are_left_out():
    """Where the torus's near tube hides its far tube, the depth steps inside the silhouette; there
    the rendered depth blends both tubes and the term would move the contour sideways. The pixels
    next to the steps of trimesh's ray-cast depth are left out; the smooth surface away from them
    (grazing parts included) is kept."""
    from scipy import ndimage

    from jaxgenus.optim._consistency import _depth_steps

    tm = torus_trimesh(1.0, 0.35, 96, 48)
    cams = jg.sphere_cameras(12, radius=3.0, fov_deg=40.0, resolution=96)
    truth = raycast_depth(cams, tm)
    hit = truth > 0
    jump = np.zeros_like(hit)
    for axis in (1, 2):
        a, b = np.swapaxes(truth, axis, -1)[..., :-1], np.swapaxes(truth, axis, -1)[..., 1:]
        j = (a > 0) & (b > 0) & (np.abs(a - b) > 0.05 * np.minimum(a, b))
        j = np.swapaxes(np.concatenate([j, np.zeros_like(j[..., :1])], -1), axis, -1)
        jump |= j | np.roll(j, 1, axis=axis)
    r = jg.render(torus(1.0, 0.35, 96, 48), cams, channels=("alpha", "depth"))
    alpha, depth = np.asarray(r[..., 0]), np.asarray(r[..., 1]) / np.maximum(np.asarray(r[..., 0]), 0.99)
    inner = ndimage.binary_erosion(alpha >= 0.99, np.ones((1, 5, 5)))  # what the term uses before this test
    steps = np.asarray(_depth_steps(jnp.asarray(depth)))
    on = jump & inner
    away = inner & ~ndimage.binary_dilation(jump, np.ones((1, 7, 7)))
    assert on.sum() > 100, on.sum()  # the scene has inner contours
    assert steps[on].mean() > 0.95, steps[on].mean()
    assert steps[away].mean() < 0.03, steps[away].mean()
