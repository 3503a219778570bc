import time

import jax
import numpy as np
import pytest
import trimesh

import jaxgenus as jg


def _icosphere(levels=2, radius=1.0):
    s = trimesh.creation.icosphere(subdivisions=levels, radius=radius)
    return np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)


def test_new_vertices_lie_on_the_sphere_the_chords_cut():
    v, f = _icosphere(2, radius=3.7)
    v0 = v.copy()
    flat = jg.phong_subdivision((v, f), shape=0.0)
    sub = jg.phong_subdivision((v, f))
    np.testing.assert_array_equal(v, v0)  # the input is untouched
    vf, ff = flat.mesh.to_numpy()
    vs, fs = sub.mesh.to_numpy()
    assert len(fs) == 4 * len(f) and len(vs) == len(v) + len(f) * 3 // 2
    np.testing.assert_array_equal(fs, ff)
    np.testing.assert_allclose(vs[: len(v)], v, rtol=1e-6)  # the fitted vertices stay
    sag_flat = np.abs(np.linalg.norm(vf[len(v):], axis=1) - 3.7)
    sag = np.abs(np.linalg.norm(vs[len(v):], axis=1) - 3.7)
    # edges of ~0.33 rad: the midpoints sag r(1 - cos(t/2)) ~ 0.04; lifted, what the area-weighted
    # normals' tilt leaves (a 16th of it on average)
    assert sag_flat.mean() > 0.035 and sag.mean() < 0.1 * sag_flat.mean() and sag.max() < 0.2 * sag_flat.max()
    # the surface between the samples: the mean distance of the faces to the sphere drops
    dist = lambda vv, ff: np.abs(np.linalg.norm(trimesh.Trimesh(vv, ff).sample(20000, seed=1), axis=1) - 3.7).mean()  # noqa: E731
    assert dist(vs, fs) < 0.3 * dist(v, f)


def test_planes_stay_planar_and_genus_and_values_are_kept():
    g2 = jg.genus_primitive(2)
    v, f = g2.to_numpy()
    albedo = np.random.default_rng(0).uniform(size=(len(v), 3)).astype(np.float32)
    sub = jg.phong_subdivision(g2, values=albedo)
    assert jg.genus(sub.mesh) == 2 and jg.is_closed_manifold(sub.mesh)
    assert sub.values.shape == (int(sub.mesh.n_vertices), 3) and sub.values.dtype == np.float32
    vs, fs = sub.mesh.to_numpy()
    # an edge's new value is the mean of its ends: find the edge from the faces' corners
    e01 = fs[3 * len(f):][:, 0]  # the middle triangles hold (e01, e12, e20) of each old face
    np.testing.assert_allclose(sub.values[e01], 0.5 * (albedo[f[:, 0]] + albedo[f[:, 1]]), rtol=1e-6)
    # a flat grid: every vertex normal is the plane's, nothing leaves the plane
    xs, ys = np.meshgrid(np.arange(5.0), np.arange(4.0))
    pv = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 2.5)], 1)
    idx = np.arange(20).reshape(4, 5)
    pf = np.concatenate([np.stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()], 1),
                         np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()], 1)])
    out = jg.phong_subdivision((pv, pf)).mesh.to_numpy()[0]
    np.testing.assert_allclose(out[:, 2], 2.5, atol=1e-6)


def test_bad_inputs_are_named():
    v, f = _icosphere(0)
    with pytest.raises(ValueError, match="shape"):
        jg.phong_subdivision((v, f), shape=1.5)
    with pytest.raises(ValueError, match="values"):
        jg.phong_subdivision((v, f), values=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="mesh"):
        jg.phong_subdivision((v[:, :2], f))
    bad = v.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        jg.phong_subdivision((bad, f))
    with pytest.raises(ValueError, match="subdivide"):
        jg.ReconstructOptions(subdivide=1)


def test_reconstruct_returns_the_subdivided_fit_only_where_it_is_coarser_than_the_images():
    gt = jg.builtin_scene("torus")
    cams = jg.sphere_cameras(8, radius=3.0, fov_deg=40.0, resolution=48)
    img = jg.render_targets(gt, cams)
    # one cycle: the result has the start's edges, 4 px (coarser than the images: subdivided)
    opts = jg.ReconstructOptions().updated(n_cycles=1, steps_per_cycle=20, initial_faces=600, refits=0,
                                           initial_edge_length=4.0, final_edge_length=4.0)
    lines = []
    wall = time.perf_counter()
    on = jg.reconstruct(img, cams, 1, options=opts, key=jax.random.key(1), log=lines.append)
    wall = time.perf_counter() - wall
    # the history times the whole call and counts the faces of the mesh returned, after the subdivision
    assert 0.9 * wall <= on.history["seconds"] <= wall and on.history["faces"] == int(on.mesh.n_faces)
    off = jg.reconstruct(img, cams, 1, options=opts.updated(subdivide=False), key=jax.random.key(1))
    assert int(on.mesh.n_faces) == 4 * int(off.mesh.n_faces) and on.genus == off.genus == 1
    vo, _ = off.mesh.to_numpy()
    np.testing.assert_allclose(on.mesh.to_numpy()[0][: len(vo)], vo, rtol=1e-6, atol=1e-6)
    assert any(line.startswith("subdivided:") for line in lines)
    # the verdict judged the mesh returned (subdivided), not the fitted one
    assert any(line.startswith("verdict on the mesh written (") for line in lines), lines
    from jaxgenus.pipeline._verdict import silhouette_ious
    written = silhouette_ious(on.mesh, cams, np.asarray(img)[..., 3], sigma=opts.render.sigma)[0]
    np.testing.assert_allclose(on.history["silhouette_iou"], written, atol=0.01)
    # a stage after the fit that spoils the mesh is caught by that verdict (here: a mesh shrunk by 0.7)
    import jaxgenus.pipeline._reconstruct as stages

    def shrunk(mesh, albedo, cams, say):
        v, f = mesh.to_numpy()
        return jg.Mesh.from_numpy(0.7 * v, f), albedo
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(stages, "_subdivided_if_coarse", shrunk)
        bad = jg.reconstruct(img, cams, 1, options=opts, key=jax.random.key(1))
    assert not bad.history["ok"] and any(w.startswith("silhouette IoU under") for w in bad.history["warnings"])
    assert on.history["ok"]
    # edges of 1.5 px: as fine as the images resolve, the result is the fit (a 48-px torus in 4k faces, not 16k)
    lines = []
    fine = jg.reconstruct(img, cams, 1, options=opts.updated(initial_edge_length=1.5, final_edge_length=1.5), key=jax.random.key(1),
                          log=lines.append)
    assert any(line.startswith("not subdivided: the median edge is") for line in lines), lines
    assert int(fine.mesh.n_faces) == int(fine.history["cycles"][-1]["faces"])
    assert jg.ReconstructOptions.nicolet().subdivide is False
