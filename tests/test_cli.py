import jaxgenus as jg
from jaxgenus.__main__ import main


def test_primitives_command_writes_meshes_of_the_right_genus(tmp_path, capsys):
    assert main(["primitives", "--genus", "0", "2", "--faces", "800", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "-2" in out
    for g in (0, 2):
        mesh = jg.load_mesh(tmp_path / f"genus_{g}.obj")
        assert jg.genus(mesh) == g
