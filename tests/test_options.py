"""`ReconstructOptions` composes the options of its parts: one field, one default, one place."""

import dataclasses

import pytest

import jaxgenus as jg


def test_updated_routes_each_name_to_the_part_that_holds_it():
    base = jg.ReconstructOptions()
    o = base.updated(learning_rate=0.05, sigma=0.03, carve=2.0, adaptive=True, max_faces=30000, n_cycles=6)
    assert o.optimize.learning_rate == 0.05 and o.optimize.render.sigma == 0.03 and o.optimize.weights.carve == 2.0
    assert o.remesh.adaptive and o.remesh.max_faces == 30000 and o.face_budget == 30000 and o.n_cycles == 6
    assert o.optimize.render.gamma == jg.RenderSettings().gamma and o.remesh.iterations == base.remesh.iterations
    assert base == jg.ReconstructOptions()  # a copy: the original is unchanged
    with pytest.raises(ValueError, match="no setting named 'sigmaa'"):
        base.updated(sigmaa=1.0)
    with pytest.raises(ValueError, match="without remeshing"):
        jg.ReconstructOptions.nicolet().updated(adaptive=True)
    with pytest.raises(ValueError, match="render settings: sigma"):
        base.updated(sigma=-1.0)


def test_one_default_per_setting_and_the_presets():
    o = jg.ReconstructOptions()
    assert o.optimize == jg.OptimizeOptions() and o.render == jg.RenderSettings()
    n = jg.ReconstructOptions.nicolet()
    assert n.start == "sphere" and n.remesh is None and n.optimize.adam_quantile == 1.0 and n.edge_lengths() == []
    f = o.fine()
    assert f.optimize.render.sigma == 0.03 and f.optimize.average == 0.95 and f.n_cycles == 5 and f.face_budget == 20000
    assert f.fine() == f  # idempotent
    assert o.for_refit("normals").optimize.weights.carve == o.refit_carve and o.for_refit("photo") is o
    with pytest.raises(ValueError, match="remesh.max_faces must be set"):
        jg.ReconstructOptions(remesh=jg.RemeshOptions())
    with pytest.raises(ValueError, match="options.optimize"):
        jg.ReconstructOptions(optimize=dataclasses.asdict(jg.OptimizeOptions()))
