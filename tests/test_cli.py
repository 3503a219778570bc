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
    assert main(args + ["--out", str(tmp_path / "r.obj"), "--refit-carve", "-1"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refit_carve" in err
