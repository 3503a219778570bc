import dataclasses
import json

import jax
import numpy as np
import pytest
import trimesh

import jaxgenus as jg
from jaxgenus.__main__ import main
from jaxgenus.pipeline._setup import prepare
from _meshes import torus


@pytest.fixture(scope="module")
def torus_scene():
    gt = jg.builtin_scene("torus")
    cams = jg.sphere_cameras(12, radius=3.0, fov_deg=40.0, resolution=64)
    return gt, cams, jg.render_targets(gt, cams)


def test_render_targets_sphere_area_and_normals():
    s = jg.genus_primitive(0, n_faces=4000)
    cams = jg.look_at([0.0, 0.0, 3.0], fov_deg=40.0, resolution=64)
    img = jg.render_targets(s, cams)
    assert img.shape == (1, 64, 64, 4) and img.dtype == np.float32
    f = float(cams.focal[0, 0])
    disc = np.pi * (f * 1.0 / np.sqrt(9.0 - 1.0)) ** 2
    assert img[..., 3].sum() == pytest.approx(disc, rel=0.03)
    # the pixel at the centre sees the sphere's pole facing the camera: n = (0, 0, 1)
    np.testing.assert_allclose(img[0, 32, 32, :3], [0.5, 0.5, 1.0], atol=0.03)
    assert img.min() >= 0.0 and img.max() <= 1.0


def test_bad_inputs_are_named(torus_scene):
    gt, cams, img = torus_scene
    with pytest.raises(ValueError, match="genus"):
        jg.reconstruct(img, cams, -1)
    with pytest.raises(ValueError, match="genus"):
        jg.reconstruct(img, cams, 1.5)
    with pytest.raises(ValueError, match="views"):
        jg.reconstruct(img[:5], cams, 1)
    n = len(cams)  # views= names the views images holds; one process must hold them all
    with pytest.raises(ValueError, match=f"^views: one process must hold all {n} views"):
        jg.reconstruct(img[:2], cams, 1, views=[0, 1])
    with pytest.raises(ValueError, match="^views: expected increasing"):
        jg.reconstruct(img[:2], cams, 1, views=[1, 0])
    with pytest.raises(ValueError, match="^views: expected 2 view indices"):
        jg.reconstruct(img[:2], cams, 1, views=[0, 1, 2])
    with pytest.raises(ValueError, match="adam_quantile"):
        jg.ReconstructOptions().updated(adam_quantile=0.0)
    with pytest.raises(ValueError, match="average"):
        jg.ReconstructOptions().updated(average=1.0)
    with pytest.raises(ValueError, match="fine_below"):
        jg.ReconstructOptions(fine_below=-1.0)
    bad = img.copy()
    bad[0, 3, 3, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        jg.reconstruct(bad, cams, 1)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        jg.reconstruct(img * 2.0, cams, 1)
    empty = img.copy()
    empty[2, ..., 3] = 0.0
    with pytest.raises(ValueError, match="empty silhouettes"):
        jg.reconstruct(empty, cams, 1)
    with pytest.raises(ValueError, match="images"):
        jg.reconstruct(img[..., :2], cams, 1)
    with pytest.raises(ValueError, match="cams"):
        jg.reconstruct(img, "cams", 1)
    with pytest.raises(ValueError, match="height"):
        jg.reconstruct(img[:, :40], cams, 1)
    with pytest.raises(ValueError, match="options"):
        jg.ReconstructOptions(n_cycles=0)


def test_torus_end_to_end_genus_iou_and_determinism(torus_scene):
    gt, cams, img = torus_scene
    before = img.copy()
    opts = jg.ReconstructOptions().updated(n_cycles=3, steps_per_cycle=50, initial_faces=800, max_faces=3000)
    lines = []
    rec = jg.reconstruct(img, cams, 1, options=opts, key=jax.random.key(3), log=lines.append)
    np.testing.assert_array_equal(img, before)  # inputs untouched
    assert rec.genus == 1 and rec.genus_ok
    assert jg.genus(rec.mesh) == 1 and jg.is_closed_manifold(rec.mesh)
    iou = jg.metrics.volume_iou(rec.mesh, gt, n_samples=50_000)
    assert iou >= 0.8, iou
    h = rec.history
    # one compiled cycle (optimizer block + remesh) per rasterizer-plan bucket
    assert 1 <= h["compilations"]["cycle"] <= h["render_plans"], h["compilations"]
    assert h["compilations"]["all_cycles"] == 0
    assert sum(c["compilations"] for c in h["cycles"]) == sum(h["compilations"].values())
    assert h["start"] == "visual_hull"  # the torus' hull is one genus-1 component
    assert not h["fine"] and h["hull_thickness"] > 5.0 and rec.options == opts  # thick: no fine() switch
    assert h["loss"].shape == (150,) and np.all(np.isfinite(h["loss"]))
    assert h["loss"][-20:].mean() < 0.7 * h["loss"][:5].mean()
    # CAPACITY_EXCEEDED: the remesher coarsened to fit the face budget (still a valid mesh)
    assert all(c["remesh_status"] in ("OK", "CAPACITY_EXCEEDED") for c in h["cycles"][:-1])
    assert all(c["chi"] == 0 for c in h["cycles"])
    # the plan, made before any fit, is said first and is what ran
    plan = h["plan"]
    assert lines[:len(plan.lines())] == plan.lines(), lines
    assert plan.factors == tuple(r["factor"] for r in h["resolution"]) and plan.floor == 1
    assert (plan.settings["n_cycles"], plan.settings["max_faces"], plan.settings["normal"]) == (3, 3000, 1.0)
    assert "photo" not in plan.settings and plan.scene["genus_from"] == "given" and plan.scene["size"] == [64, 64]
    assert plan.stages[0] == "visual-hull start" and plan.stages[-1] == "verdict on the mesh written"
    assert json.loads(json.dumps(h.to_json()))["plan"]["factors"] == list(plan.factors)
    # alpha-only targets fit silhouettes only
    rec_a = jg.reconstruct(img[..., 3], cams, 1, options=jg.ReconstructOptions(n_cycles=1, steps_per_cycle=5))
    assert np.all(rec_a.history["normal"] == 0.0)


def test_visual_hull_of_torus_contains_it_and_keeps_the_hole(torus_scene):
    gt, cams, img = torus_scene
    hull = jg.visual_hull(img, cams, resolution=48)
    assert jg.is_closed_manifold(hull) and jg.geometry.connected_components(hull)[0] == 1 and jg.genus(hull) == 1
    vol_hull, vol_gt = hull.to_trimesh().volume, gt.to_trimesh().volume
    assert vol_gt * 0.97 <= vol_hull <= vol_gt * 1.6, (vol_hull, vol_gt)  # a superset, up to the grid
    assert jg.metrics.volume_iou(hull, gt, n_samples=50_000) >= 0.6
    alpha_only = jg.visual_hull(img[..., 3], cams, resolution=48)
    np.testing.assert_array_equal(alpha_only.vertices, hull.vertices)
    with pytest.raises(ValueError, match="resolution"):
        jg.visual_hull(img, cams, resolution=4)
    with pytest.raises(ValueError, match="closing"):
        jg.visual_hull(img, cams, closing=-1)
    with pytest.raises(ValueError, match="views"):
        jg.visual_hull(img[:3], cams)


def test_visual_hull_values_computed_at_once_give_the_same_mesh_as_per_point(torus_scene, monkeypatch):
    """The hull's level set takes the values at manifold3d's lattice computed at once, in the order
    it asks for them; the reference is the interpolation of each point as asked (`_point_field`)."""
    import manifold3d

    from jaxgenus.capture import _hull

    gt, cams, img = torus_scene
    occ = _hull.hull_occupancy(img, cams, resolution=40)
    phi = np.asarray(occ.values, np.float64) - 0.5
    points = _hull._lattice_points(np.asarray(occ.lo), np.asarray(occ.hi), occ.cell)
    field = _hull._point_field(phi, np.asarray(occ.lo), occ.cell)
    asked = []
    manifold3d.Manifold.level_set(lambda x, y, z: asked.append((x, y, z)) or -1.0, [*occ.lo, *occ.hi], occ.cell)
    np.testing.assert_array_equal(np.array(asked), points)  # the points and their order, exactly
    ref = np.array([field(*p) for p in points[::97]])
    np.testing.assert_array_equal(_hull._trilinear(phi, np.asarray(occ.lo), occ.cell, points[::97]), ref)
    fast = [jg.visual_hull(img, cams, closing=c, occupancy=occ) for c in (0, 2)]
    monkeypatch.setattr(_hull, "_lattice_field", lambda phi, lo, cell, hi: _hull._point_field(phi, lo, cell))
    slow = [jg.visual_hull(img, cams, closing=c, occupancy=occ) for c in (0, 2)]
    for a, b in zip(fast, slow):
        np.testing.assert_array_equal(a.to_numpy()[0], b.to_numpy()[0])
        np.testing.assert_array_equal(a.to_numpy()[1], b.to_numpy()[1])


def test_auto_start_drills_missing_handles_into_a_lower_genus_hull(torus_scene):
    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=5, initial_faces=800, max_faces=4000,
                                 hidden_handles="drill")
    rec = jg.reconstruct(img, cams, 3, options=opts)  # the hull has genus 1: 2 handles are added
    assert rec.history["start"] == "visual_hull+tunnels" and rec.history["tunnels"] == 2
    assert [h["source"] for h in rec.history["handles"]] == ["hull", "drilled", "drilled"]
    assert any("2 of 3 handles were drilled" in w for w in rec.history["warnings"])
    assert rec.genus == 3 and rec.genus_ok
    # looking in the images first (the default) finds no hole there, and drills the same two
    looked = jg.reconstruct(img, cams, 3, options=dataclasses.replace(opts, hidden_handles="images"))
    assert looked.history["start"] == "fit+images+tunnels" and looked.genus == 3
    assert [h["source"] for h in looked.history["handles"]] == ["hull", "drilled", "drilled"]
    # the small handles barely change the shape: still close to the torus
    al = jg.metrics.icp_align(rec.mesh, gt).vertices
    assert jg.metrics.volume_iou((al, rec.mesh.to_numpy()[1]), gt) > 0.7


def test_auto_start_falls_back_to_the_primitive_when_the_hull_genus_is_too_high(torus_scene):
    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=5, initial_faces=800, max_faces=3000)
    rec = jg.reconstruct(img, cams, 0, options=opts)  # the hull keeps the torus' hole: genus 1, not 0
    assert rec.history["start"] == "primitive" and rec.history["hull_grid"] is None
    assert rec.genus == 0 and rec.genus_ok


def test_refit_starts_from_the_previous_result(torus_scene):
    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=40, initial_faces=800, max_faces=3000, start="primitive")
    first = jg.reconstruct(img, cams, 1, options=opts)
    lines, rows = [], []  # a plain refit (a carving one fits this torus worse and is dropped: tests below)
    rec = jg.reconstruct(img, cams, 1, options=opts.replaced(refits=1, refit_carve=0.0), log=lines.append,
                         callback=lambda row, mesh: rows.append((row["fit"], row["fits"], row["cycle"], row["n_cycles"])))
    assert rec.genus == 1 and rec.history["start"] == "primitive+refit"
    # the refit starts from the first fit, not from the primitive: its start already matches the silhouettes
    start_first, start_refit = np.mean(first.history["start_silhouette_iou"]), np.mean(rec.history["start_silhouette_iou"])
    assert start_first < 0.85 and start_refit > 0.95 and start_refit >= np.mean(first.history["silhouette_iou"]) - 0.02
    assert rows == [(0, 2, 0, 2), (0, 2, 1, 2), (1, 2, 0, 2), (1, 2, 1, 2)] and rec.history["cycles"][-1]["fit"] == 1
    assert any(line.startswith("refit 1/1: start: primitive+refit") for line in lines)
    assert rec.history["seconds"] > rec.history["cycles"][-1]["elapsed"]  # the first fit's time is counted
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="refits"):
            jg.ReconstructOptions(refits=bad)


def test_a_refit_that_fits_worse_is_dropped(torus_scene, monkeypatch):
    """A refit started from a shrunken copy of the result cannot recover in 5 steps: the run
    keeps the first fit (same mesh), says why, and counts the refit's time."""
    import equinox as eqx

    import jaxgenus.pipeline._fit as R

    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions().updated(n_cycles=1, steps_per_cycle=30, initial_faces=800, max_faces=3000)
    first = jg.reconstruct(img, cams, 1, options=opts)
    refit_start = R.refit_start

    def shrunken(*args):
        start = refit_start(*args)
        return dataclasses.replace(start, mesh=eqx.tree_at(lambda m: m.vertices, start.mesh, start.mesh.vertices * 0.3))

    monkeypatch.setattr(R, "refit_start", shrunken)
    for carve in (0.0, 1.0):  # a carving refit (the default for normal maps) is retried once without carving
        lines, refit_seconds = [], []
        rec = jg.reconstruct(img, cams, 1, options=opts.replaced(refits=2, refit_carve=carve),
                             log=lines.append,
                             callback=lambda row, m: refit_seconds.append(row["seconds"]) if row["fit"] else None)
        assert rec.history["start"] == first.history["start"] and "refit" not in rec.history["start"]
        np.testing.assert_array_equal(rec.mesh.to_numpy()[0], first.mesh.to_numpy()[0])
        dropped = [w for w in rec.history["warnings"] if w.startswith("refit ") and " was dropped: " in w]
        assert dropped[0].startswith("refit 1 was dropped: ") and "silhouette IoU" in dropped[0]
        assert len(dropped) == (2 if carve else 1)
        said = [line for line in lines if line.startswith("refit 1/2: fits its images worse")]
        assert len(said) == 1 and said[0].endswith("the next refit runs without carving") == bool(carve)
        assert any(line.startswith("refit 2/2") for line in lines) == bool(carve)
        assert refit_seconds and rec.history["seconds"] > rec.history["cycles"][-1]["elapsed"] + sum(refit_seconds)


def test_default_refits_stop_when_a_refit_gains_little(torus_scene, monkeypatch):
    """Default refits (64² images over a 32 px coarse level: two) stop after a refit that
    lowers the normal error by less than the threshold; an explicit count does not."""
    import jaxgenus.pipeline._fit as R

    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions().updated(n_cycles=1, steps_per_cycle=20, initial_faces=800, max_faces=3000,
                                 coarse_resolution=32)
    assert opts.refit_count(64, 64) == 2
    monkeypatch.setattr(R, "_fits_worse", lambda new, old: "")  # keep every refit: only the stop rule acts
    monkeypatch.setattr(R, "_MIN_REFIT_GAIN", 1.0)  # no refit lowers the error by 100 %
    for refits, n_fits in ((None, 2), (2, 3)):
        lines = []
        rec = jg.reconstruct(img, cams, 1, options=dataclasses.replace(opts, refits=refits), log=lines.append)
        assert rec.history["start"].count("+refit") == n_fits - 1
        stopped = [line for line in lines if line.startswith("refit 1/2: lowered the mean normal error by")]
        assert len(stopped) == (refits is None) and not any(w.startswith("refit") for w in rec.history["warnings"])
        assert any(line.startswith("refit 2/2") for line in lines) == (refits == 2)


def test_tunnels_add_exactly_the_requested_handles_with_little_volume():
    from jaxgenus.pipeline._start import drill_tunnels

    sphere = jg.genus_primitive(0, n_faces=3000)
    v, f = sphere.to_numpy()
    size = 0.08
    out = drill_tunnels(sphere, 3, size)
    assert out is not None and jg.is_closed_manifold(out)
    assert jg.genus(out) == 3 and jg.geometry.connected_components(out)[0] == 1
    vol = lambda m: trimesh.Trimesh(*m.to_numpy(), process=False).volume
    assert vol(out) == pytest.approx(vol(sphere), rel=0.01)  # three thin half-ring tunnels
    # every new surface point lies within the torus' reach (1.3 size) of the sphere
    assert jg.metrics.hausdorff_distance(out, sphere) <= 1.3 * size + 1e-3
    np.testing.assert_array_equal(sphere.to_numpy()[0], v)  # input untouched
    assert drill_tunnels(sphere, 1, 2.0) is None  # a ring larger than the object cannot make a handle
    crowded = drill_tunnels(jg.genus_primitive(0, n_faces=200), 50, 0.5)  # overlapping cuts are refused
    assert crowded is None or (jg.genus(crowded) == 50 and jg.geometry.connected_components(crowded)[0] == 1)


def test_same_key_same_result(torus_scene):
    gt, cams, img = torus_scene
    # the options of the start tests above (their programs shared through the compilation cache)
    opts = jg.ReconstructOptions().updated(n_cycles=2, steps_per_cycle=5, initial_faces=800, max_faces=3000)
    key = jax.random.key(7)
    a = jg.reconstruct(img, cams, 1, options=opts, key=key)
    b = jg.reconstruct(img, cams, 1, options=opts, key=key)  # the caller's key is not consumed (donated)
    va, fa = a.mesh.to_numpy()
    vb, fb = b.mesh.to_numpy()
    np.testing.assert_array_equal(fa, fb)
    np.testing.assert_array_equal(va, vb)


def test_nicolet_baseline_keeps_the_sphere_connectivity(torus_scene):
    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions.nicolet(n_cycles=2, steps_per_cycle=10, initial_faces=600)
    assert opts.optimize.adam_quantile == 1.0  # Nicolet's uniform Adam: the max, not our robust quantile
    rec = jg.reconstruct(img, cams, 1, options=opts)
    assert rec.genus == 0 and rec.genus_ok  # the baseline cannot change topology
    assert all("remesh_status" not in c for c in rec.history["cycles"])
    assert int(rec.mesh.n_faces) == 600


def test_cli_reconstruct_writes_mesh_and_history(tmp_path, capsys):
    gt = jg.builtin_scene("torus")
    jg.save_mesh(gt, tmp_path / "gt.obj")
    out = tmp_path / "out.obj"
    code = main(["reconstruct", "--mesh", str(tmp_path / "gt.obj"), "--genus", "1", "--views", "8", "--res", "32",
                 "--option", "n_cycles=2", "steps_per_cycle=10", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0 and "chamfer" in text and "ETA" in text
    assert jg.genus(jg.load_mesh(out)) == 1
    hist = json.loads(out.with_suffix(".json").read_text())
    assert len(hist["loss"]) == 20 and len(hist["cycles"]) == 2
    assert "[##] cycle 2/2 " in text and "refit" not in text
    other = tmp_path / "seed1.obj"  # another seed samples other views each step: another result
    assert main(["reconstruct", "--mesh", str(tmp_path / "gt.obj"), "--genus", "1", "--views", "8", "--res", "32",
                 "--option", "n_cycles=2", "steps_per_cycle=10", "--seed", "1", "--out", str(other)]) == 0
    a, b = jg.load_mesh(out).to_numpy()[0], jg.load_mesh(other).to_numpy()[0]
    assert a.shape != b.shape or not np.allclose(a, b)


def test_fine_preset_keeps_the_method_and_sharpens_the_schedule():
    ours, base = jg.ReconstructOptions().fine(), jg.ReconstructOptions.nicolet().fine()
    for o in (ours, base):
        assert (o.render.sigma, o.lr_decay, o.n_cycles, o.optimize.average) == (0.03, 0.9, 5, 0.95)
    assert ours.remesh and ours.start == "auto" and ours.face_budget == 20000 and ours.optimize.adam_quantile == 0.99
    assert not base.remesh and base.start == "sphere" and base.optimize.adam_quantile == 1.0  # still the baseline
    assert ours.edge_lengths()[0] == 1.4 and ours.edge_lengths()[-1] == pytest.approx(1.0)


def test_hull_thickness_matches_a_torus_tube_radius():
    """2 V / A of a torus is its tube radius: the hull's measure, in pixels, against it."""
    from jaxgenus.capture._frame import pixel_footprint
    from jaxgenus.capture._hull import hull_thickness, visual_hull_bounds

    cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
    for minor in (0.05, 0.25):
        alpha = jg.render_targets(torus(0.7, minor, 96, 32, dtype=np.float32), cams)[..., 3]
        lo, hi = visual_hull_bounds(alpha, cams)
        pixel = pixel_footprint(cams, 0.5 * (lo + hi))
        got = hull_thickness(alpha, cams, 64, pixel)
        assert got == pytest.approx(minor / pixel, rel=0.3), (minor, got, minor / pixel)
    assert hull_thickness(np.zeros((16, 64, 64), np.float32), cams, 64, pixel) == np.inf  # empty: no hull


def test_thin_shapes_switch_to_the_fine_preset():
    cams = jg.sphere_cameras(12, radius=3.0, fov_deg=40.0, resolution=64)
    img = jg.render_targets(torus(0.7, 0.05, 96, 32, dtype=np.float32), cams)  # tube radius 1.5 px
    opts = jg.ReconstructOptions(steps_per_cycle=4)
    rec = jg.reconstruct(img, cams, 1, options=opts)
    h = rec.history
    assert h["fine"] and h["hull_thickness"] < opts.fine_below
    assert rec.options == opts.fine() and len(h["cycles"]) == 5 and h["loss"].shape == (20,)
    assert rec.genus == 1
    off = jg.reconstruct(img, cams, 1, options=jg.ReconstructOptions(n_cycles=1, steps_per_cycle=2, fine_below=0.0))
    assert not off.history["fine"] and off.history["hull_thickness"] is None and off.options.render.sigma == 0.1


def test_thin_switch_measures_the_level_the_first_cycles_fit():
    """A tube 1.5 px thick at 64² is 6 px thick at 256²: fitted through 64² copies it is still
    thin there, so fine() applies; fitted at full size (`coarse_resolution=0`) it does not."""
    cams = jg.sphere_cameras(8, radius=3.0, fov_deg=40.0, resolution=256)
    img = jg.render_targets(torus(0.7, 0.05, 96, 32, dtype=np.float32), cams)
    opts = jg.ReconstructOptions(n_cycles=2, steps_per_cycle=2, coarse_resolution=64)
    lines = []
    rec = jg.reconstruct(img, cams, 1, options=opts, log=lines.append)
    h = rec.history
    assert h["fine"] and h["hull_thickness"] > opts.fine_below  # thin at the 64² level, not in native pixels
    # fine(): its sharper edges, but the 2 cycles given by name hold (fine() alone would run 5)
    assert rec.options.render.sigma == 0.03 and rec.options.n_cycles == 2
    assert [r["factor"] for r in h["resolution"]] == [4, 1]
    # normal maps fitted through the schedule get two refits by default (refits=None), each one fine() again
    assert rec.options.refits is None
    assert any(line.startswith("refits: 2 more fits from this result (normal maps of 256x256") for line in lines)
    assert any(line.startswith("refit 1/2: start: visual_hull+refit") for line in lines)  # (2 steps: maybe dropped)
    at_size = dataclasses.replace(opts, coarse_resolution=0)  # fitted at its own size: neither (the run's setup)
    assert not prepare(img, cams, 1, None, at_size, lambda line: None).fine and at_size.refit_count(256, 256) == 0


def test_default_refits_follow_the_schedule_and_the_targets():
    o = jg.ReconstructOptions()
    assert o.refits is None and o.refit_count(128, 128) == 0 and o.refit_count(191, 120) == 0
    assert o.refit_count(192, 100) == 2 and o.refit_count(480, 640) == 2 and o.refit_count(2048, 2048) == 2
    assert o.refit_count(512, 512, "silhouette") == 0 and o.refit_count(512, 512, "photo") == 0
    assert jg.ReconstructOptions(coarse_resolution=0).refit_count(1024, 1024) == 0
    assert jg.ReconstructOptions(refits=1).refit_count(64, 64, "silhouette") == 1
    assert jg.ReconstructOptions(refits=0).refit_count(1024, 1024) == 0


def test_one_jit_runs_every_cycle_in_one_compiled_scan(torus_scene):
    gt, cams, img = torus_scene
    opts = jg.ReconstructOptions(n_cycles=3, steps_per_cycle=40, one_jit=True)
    seen = []
    rec = jg.reconstruct(img, cams, 1, options=opts, callback=lambda row, m: seen.append((row, jg.genus(m), int(m.n_faces))))
    h = rec.history
    assert rec.genus == 1 and rec.genus_ok
    assert h["compilations"]["all_cycles"] <= 1 and h["compilations"]["cycle"] == 0 and h["render_plans"] == 1
    assert len(h["loss"]) == 120 and np.all(np.isfinite(h["loss"]))
    assert [r["cycle"] for r, _, _ in seen] == [0, 1, 2]
    assert [g for _, g, _ in seen] == [1, 1, 1]  # the per-cycle meshes come out of the scan
    assert [r["faces"] for r, _, _ in seen] == [n for _, _, n in seen]
    assert all(r["remesh_status"] in ("OK", "CAPACITY_EXCEEDED") for r, _, _ in seen[:2])
    assert "remesh_status" not in seen[2][0]  # no remesh after the last cycle
    assert all(r["truncated_faces"] == 0 for r, _, _ in seen)
    elapsed = [r["elapsed"] for r, _, _ in seen]
    assert elapsed == sorted(elapsed) and elapsed[-1] <= h["seconds"] + 1e-6
    al = jg.metrics.icp_align(rec.mesh, gt).vertices
    assert jg.metrics.volume_iou((al, rec.mesh.to_numpy()[1]), gt) >= 0.8
