import jaxgenus as jg
from jaxgenus.__main__ import main


def test_primitives_command_writes_meshes_of_the_right_genus(tmp_path, capsys):
    assert main(["primitives", "--genus", "0", "2", "--faces", "800", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "-2" in out
    for g in (0, 2):
        mesh = jg.load_mesh(tmp_path / f"genus_{g}.obj")
        assert jg.genus(mesh) == g


def test_reconstruct_refuses_bad_genus_and_an_output_that_overwrites_an_input(tmp_path, capsys):
    import pytest

    (tmp_path / "masks").mkdir()
    (tmp_path / "cams.json").write_text("{}")
    args = ["reconstruct", "--images", str(tmp_path / "masks"), "--cameras", str(tmp_path / "cams.json")]
    assert main(args + ["--out", str(tmp_path / "cams.obj")]) == 1  # its JSON history would replace cams.json
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: --out") and "overwrite" in err
    assert (tmp_path / "cams.json").read_text() == "{}"
    with pytest.raises(SystemExit) as exc:
        main(args + ["--genus", "two"])
    assert exc.value.code == 2
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--option", "refit_carve=-1"]) == 2  # usage: names the flag
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: --option") and "refit_carve" in err
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--option", "no_such_setting=1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no_such_setting" in err
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--devices", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: --devices")
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--option", "learning_rate"]) == 1
    assert "NAME=VALUE" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--downsample", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: --downsample")
    # an output that cannot be written is refused before any work (exit 2), naming --out
    (tmp_path / "a_file").write_text("x")
    for out in (tmp_path / "a_file" / "x.obj", tmp_path / "a_file" / "deeper" / "x.obj", tmp_path / "masks"):
        assert main(args + ["--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: --out"), err


def test_cli_settings_map_onto_the_nested_options_and_hold_as_given():
    import argparse

    from jaxgenus.__main__ import _mask_source, _options, _plan_line, _settings_list, _UsageError

    base = dict(preset="default", max_faces=20000, downsample=2, devices=None,
                option=["learning_rate=0.05", "adaptive=True", "sigma=0.03", "lighting='directional'", "crop=64"])

    def options(**change):
        return _options(argparse.Namespace(**{**base, **change}))

    opts, default = options(), jg.ReconstructOptions()
    assert opts.optimize.learning_rate == 0.05 and opts.remesh_options.adaptive and opts.optimize.render.sigma == 0.03
    assert opts.remesh_options.max_faces == 20000 and opts.optimize.crop == 64 and opts.downsample == 2
    assert {"max_faces", "adaptive", "sigma"} <= opts.held  # held as given: no rise from the images
    assert "max_faces" not in options(max_faces=None).held
    assert options(max_faces=1000).initial_faces == 1000  # the start fits in the budget given
    assert opts.lighting == "directional" and opts.optimize.adam_quantile == jg.OptimizeOptions().adam_quantile
    assert opts.optimize.weights.albedo_edges == 1.0 and opts.optimize.render.shading == "flat"
    edges = options(option=["albedo_edges=0.0", "consistency=0.5", "shading_ratio=2.5"])
    assert edges.optimize.weights.albedo_edges == 0.0 and edges.optimize.weights.consistency == 0.5
    assert edges.optimize.weights.shading_ratio == 2.5
    assert "shading_ratio" in edges.held  # the shading ratio named holds, also for fine textures
    assert opts.optimize.weights.stereo == 1.0 and opts.stereo_carve == default.stereo_carve
    no_stereo = options(option=["stereo=0"])
    assert no_stereo.optimize.weights.stereo == 0.0 and no_stereo.stereo_carve == 0.0
    assert options(option=["stereo=2.0"]).stereo_carve == default.stereo_carve
    assert opts.n_cycles == 4 and "n_cycles" not in opts.held  # 5 for fine textures, unless n_cycles is named
    four = options(option=["n_cycles=4"])
    assert "n_cycles" in four.held  # the default named explicitly holds too
    assert _plan_line(opts, "photo").startswith("4 cycles (5 for photos of a fine texture that resolve under 4x the faces) x 150 steps")
    assert _plan_line(opts, "normals").startswith("4 cycles x 150")
    assert _plan_line(four, "photo").startswith("4 cycles x 150")
    assert "polish_cycles" in options(option=["polish_cycles=0"]).held  # none, also for textures
    nicolet = options(preset="nicolet", option=None, max_faces=None)
    assert not nicolet.remesh and nicolet.remesh_options is None and nicolet.optimize.adam_quantile == 1.0 and nicolet.initial_faces == 2000
    assert options(preset="nicolet", option=None, max_faces=1000).initial_faces == 1000
    fine = options(preset="nicolet-fine", option=None, max_faces=None)
    assert not fine.remesh and fine.optimize.render.sigma == 0.03 and fine.n_cycles == 5
    assert "n_cycles=4" in _settings_list(default) and "sigma=" in _settings_list(default)
    assert _mask_source("masks/") == ("masks/", None, 0.1) and _mask_source(None) == (None, None, 0.1)
    assert _mask_source("white") == (None, "white", 0.1) and _mask_source("black:0.25") == (None, "black", 0.25)
    import pytest
    with pytest.raises(_UsageError, match="--masks"):
        _mask_source("white:2")


def test_region_from_the_camera_file_or_the_command_line(tmp_path):
    """`--region`: X,Y,Z,R as given; 'auto' reads an IDR/NeuS file's scale_mat sphere and drops it
    (saying so) when the silhouettes' rays miss it; anything else is refused naming --region."""
    import argparse

    import numpy as np
    import pytest

    from jaxgenus.__main__ import _InputError, _region

    cams = jg.sphere_cameras(6, radius=3.0, fov_deg=40.0, resolution=32)
    alpha = np.asarray(jg.render_targets(jg.builtin_scene("torus"), cams))[..., 3:]
    rot, t = np.asarray(cams.rotation, np.float64), np.asarray(cams.translation, np.float64)
    (fx, fy), (cx, cy) = np.asarray(cams.focal[0], np.float64), np.asarray(cams.principal_point[0], np.float64)
    k = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]])  # IDR: the first pixel's centre at 0
    worlds = {f"world_mat_{i}": np.vstack([k @ np.c_[rot[i], t[i]], [0, 0, 0, 1]]) for i in range(len(cams))}

    def args(region, scale):
        np.savez(tmp_path / "cameras.npz", **worlds, **{f"scale_mat_{i}": scale for i in range(len(cams))})
        return argparse.Namespace(region=region, cameras=str(tmp_path / "cameras.npz"))

    said = []
    unit = np.diag([1.2, 1.2, 1.2, 1.0])
    centre, radius = _region(args("auto", unit), alpha, cams, said.append)
    assert np.allclose(centre, 0) and radius == pytest.approx(1.2) and not said
    small = np.diag([0.5, 0.5, 0.5, 1.0])  # cuts the torus: not used, and the run is told
    assert _region(args("auto", small), alpha, cams, said.append) is None and "not used" in said[-1]
    assert _region(args("none", unit), alpha, cams, said.append) is None
    centre, radius = _region(args("0.5,0,-1,2", unit), alpha, cams, said.append)
    assert np.allclose(centre, [0.5, 0, -1]) and radius == 2.0
    with pytest.raises(_InputError, match="--region"):
        _region(args("1,2", unit), alpha, cams, said.append)


def test_every_flag_has_help_with_its_default():
    import argparse

    from jaxgenus._cli import build_parser

    parser = build_parser("jaxgenus", {"primitives": None, "reconstruct": None, "demo": None}, main)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    missing = [f"{name} {a.option_strings or a.dest}" for name, sub in commands.items() for a in sub._actions
               if not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS
               and not (a.help and ("default" in a.help or "required" in a.help))]
    assert set(commands) == {"primitives", "reconstruct", "demo", "batch"} and missing == []


def test_reconstruct_has_few_flags_in_groups():
    """At most 20 flags (help included), each in a titled group; the rest is `--option`."""
    import argparse

    from jaxgenus._cli import build_parser

    parser = build_parser("jaxgenus", {"primitives": None, "reconstruct": None, "demo": None}, main)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices["reconstruct"]
    assert len(sub._actions) <= 20
    grouped = {a for g in sub._action_groups if g.title not in ("options", "optional arguments") for a in g._group_actions}
    assert [a.dest for a in sub._actions if a not in grouped and not isinstance(a, argparse._HelpAction)] == []
