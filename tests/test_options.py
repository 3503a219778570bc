"""`ReconstructOptions`: the settings a person holds, the plan entries, the parts derived from them."""

import dataclasses

import pytest

import jaxgenus as jg


def test_updated_routes_each_name_to_the_part_that_holds_it():
    base = jg.ReconstructOptions()
    o = base.updated(learning_rate=0.05, sigma=0.03, carve=2.0, adaptive=True, max_faces=30000, n_cycles=6)
    assert o.optimize.learning_rate == 0.05 and o.optimize.render.sigma == 0.03 and o.optimize.weights.carve == 2.0
    assert o.remesh_options.adaptive and o.remesh_options.max_faces == 30000 and o.face_budget == 30000
    assert o.n_cycles == 6 and o.carve == 2.0 and o.adaptive  # plan entries read as attributes
    assert o.optimize.render.gamma == jg.RenderSettings().gamma and o.remesh_options.iterations == 3
    assert base == jg.ReconstructOptions()  # a copy: the original is unchanged
    assert jg.ReconstructOptions(carve=2.0, n_cycles=6) == base.updated(n_cycles=6, carve=2.0)  # entries by name too
    with pytest.raises(ValueError, match="no setting named 'sigmaa'"):
        base.updated(sigmaa=1.0)
    with pytest.raises(ValueError, match="no setting named 'eps'"):  # a constant of the optimizer, not a setting
        jg.ReconstructOptions(eps=1e-6)
    with pytest.raises(ValueError, match="without remeshing"):
        jg.ReconstructOptions.nicolet().updated(adaptive=True)
    with pytest.raises(ValueError, match="render settings: sigma"):
        base.updated(sigma=-1.0)


def test_at_most_thirty_settings_and_a_short_repr():
    """What a person holds: at most 30 fields reachable from `ReconstructOptions()` (nested settings
    counted by their own fields), the plan entries besides them, and a repr of what differs."""
    def leaves(x):
        return sum(leaves(getattr(x, f.name)) if dataclasses.is_dataclass(getattr(x, f.name)) else 1
                   for f in dataclasses.fields(x))

    assert leaves(jg.ReconstructOptions()) <= 30
    from jaxgenus.pipeline._options import ENTRIES, setting_names
    fields = {f.name for f in dataclasses.fields(jg.ReconstructOptions)}
    assert set(ENTRIES) <= setting_names() and not set(ENTRIES) & fields
    assert repr(jg.ReconstructOptions()) == "ReconstructOptions()"
    assert repr(jg.ReconstructOptions(n_cycles=2, polish_cycles=1)) == "ReconstructOptions(n_cycles=2, polish_cycles=1)"
    given = jg.ReconstructOptions(n_cycles=4, polish_cycles=0)  # defaults given by name are held
    assert given == jg.ReconstructOptions().updated(n_cycles=4, polish_cycles=0) and given.held == {"n_cycles",
                                                                                                  "polish_cycles"}


def test_one_default_per_setting_and_the_presets():
    o = jg.ReconstructOptions()
    assert o.optimize == jg.OptimizeOptions(render=jg.RenderSettings()) and o.render == jg.RenderSettings()
    n = jg.ReconstructOptions.nicolet()
    assert n.start == "sphere" and not n.remesh and n.remesh_options is None and n.optimize.adam_quantile == 1.0
    assert n.edge_lengths() == [] and n.face_budget == n.initial_faces
    f = o.fine()
    assert f.optimize.render.sigma == 0.03 and f.optimize.average == 0.95 and f.n_cycles == 5 and f.face_budget == 20000
    assert f.fine() == f  # idempotent
    assert o.for_refit("normals").optimize.weights.carve == o.refit_carve and o.for_refit("photo") is o
    with pytest.raises(ValueError, match="options.max_faces must be >= options.initial_faces"):
        jg.ReconstructOptions(max_faces=100)
    with pytest.raises(ValueError, match="options.remesh"):
        jg.ReconstructOptions(remesh=None)


def test_photos_that_resolve_more_detail_get_a_larger_face_budget():
    import math

    import numpy as np
    import trimesh

    from jaxgenus.pipeline._setup import DETAIL_EDGE, detail_budget

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    hull = jg.Mesh.from_numpy(sphere.vertices.astype(np.float32), sphere.faces.astype(np.int32))
    face = lambda pixel: math.sqrt(3.0) / 4.0 * (DETAIL_EDGE * pixel) ** 2
    pixel_for = lambda faces: math.sqrt(sphere.area / faces / (math.sqrt(3.0) / 4.0)) / DETAIL_EDGE
    o = jg.ReconstructOptions()
    budget, resolved = detail_budget(o, "photo", hull, pixel_for(100_000))
    assert budget == o.detail_faces == 40000 and abs(resolved - sphere.area / face(pixel_for(100_000))) <= 1
    assert detail_budget(o.replaced(max_faces=5000), "photo", hull, pixel_for(25_500))[0] == 25000  # in 1000s
    assert detail_budget(o.updated(max_faces=5000), "photo", hull, pixel_for(25_500))[0] == 5000  # held as given
    # under 4 x max_faces (edges under 8 px at the budget): the photos' finest level is fitted already
    assert detail_budget(o, "photo", hull, pixel_for(40_000))[0] == 12000
    assert detail_budget(o, "photo", hull, pixel_for(49_000))[0] == 40000
    held = [o.updated(detail_faces=0), o.updated(consistency=0.0), o.replaced(max_faces=50000)]
    assert [detail_budget(h, "photo", hull, pixel_for(100_000))[0] for h in held] == [12000, 12000, 50000]
    assert detail_budget(o, "silhouette", hull, pixel_for(100_000)) == (12000, 0)
    assert detail_budget(o, "normals", hull, pixel_for(100_000)) == (12000, 0)
    assert detail_budget(o, "photo", None, pixel_for(100_000)) == (12000, 0)
    nic = jg.ReconstructOptions.nicolet()
    assert detail_budget(nic, "photo", hull, pixel_for(100_000)) == (nic.initial_faces, 0)  # no remeshing
    with pytest.raises(ValueError, match="detail_faces"):
        jg.ReconstructOptions(detail_faces=-1)
    with pytest.raises(ValueError, match="polish_cycles"):
        jg.ReconstructOptions(polish_cycles=-1)
    with pytest.raises(ValueError, match="held"):
        jg.ReconstructOptions(held=frozenset({"no_such_setting"}))
    with pytest.raises(ValueError, match="fine_texture"):
        jg.ReconstructOptions(fine_texture=1)


def test_a_photo_capture_that_resolves_more_gets_the_budget_from_its_visual_hull():
    from _raycast import raycast_lambert

    from jaxgenus.pipeline._setup import prepare

    gt = jg.builtin_scene("torus")
    cams = jg.sphere_cameras(12, radius=3.0, fov_deg=40.0, resolution=256)
    photos = raycast_lambert(cams, gt, light_direction=(0.3, 0.5, 0.8), albedo=(0.6, 0.5, 0.4))
    options = jg.ReconstructOptions(initial_faces=500).replaced(max_faces=2000, detail_faces=5000)  # max_faces not held
    said = []
    setup = prepare(photos, cams, 1, "photo", options, said.append)
    assert 2000 < setup.options.face_budget <= 5000 and setup.options.detail_faces == 5000
    assert any(line.startswith(f"face budget: {setup.options.face_budget} faces") for line in said)
    masks = prepare(photos[..., 3], cams, 1, "silhouette", options, said.append)
    assert masks.options.face_budget == 2000 and options.face_budget == 2000  # the caller's options unchanged
