"""The scene file's schema (issue 23, must-haves 1 and 6): each bad field is refused by
name in one line, the caps hold, syntax errors name the line, paths stay in the folder,
and the CLI answers a bad file with that line and exit code 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lodsprite.errors import InputError, SceneFileError
from lodsprite.scene import file as scene_file
from lodsprite.scene.file import read_scene_file
from lodsprite.scene.world import load_scene_file

TERRAIN = '[terrain]\nsource = "fractal:64"\n'


def write(folder: Path, text: str, name: str = "scene.toml") -> Path:
    p = folder / name
    p.write_text(text, encoding="utf-8")
    return p


def refusal(path: Path) -> str:
    with pytest.raises(SceneFileError) as info:
        load_scene_file(path)
    message = str(info.value)
    assert "\n" not in message
    assert isinstance(info.value, InputError)
    return message


@pytest.fixture
def box_off(tmp_path: Path) -> Path:
    import trimesh

    p = tmp_path / "box.off"
    trimesh.creation.box((1.0, 1.0, 2.0)).export(p)
    return p


BAD = [  # (the file after [terrain], the field the message must name, what it says)
    ('[[objects]]\nmesh = "ogre"\ncount = "many"\n', "objects[0].count", "expected `int`"),
    ('[[objects]]\nmesh = "ogre"\ncolour = 3\n', "objects[0].colour", "unknown field"),
    ('[[objects]]\ncount = 3\n', "objects[0].mesh", "required"),
    ('[[objects]]\nmesh = "ogre"\nlod = "best"\n', "objects[0].lod", "invalid enum"),
    ('[[objects]]\nmesh = "ogre"\nheight_m = -2.0\n', "objects[0].height_m", "must be > 0"),
    ('[[objects]]\nmesh = "ogre"\nheight_m = 20000.0\n', "objects[0].height_m", "<= 10000"),
    ('[[objects]]\nmesh = "ogre"\ncount = 5\n[[objects]]\nmesh = "tree"\ncount = 200001\n',
     "objects[1].count", "<= 200000"),
    ('[[objects]]\nmesh = "ogre"\ncount = 150000\n[[objects]]\nmesh = "ogre"\n'
     'count = 60000\n', "objects[1].count", "add up to more than 200000"),
    ('[[objects]]\nmesh = "ogre"\ncount = 5\npoints = "p.csv"\n', "objects[0].points",
     "not both"),
    ('[[objects]]\nmesh = "ogre"\nwalk_mps = -1.0\n', "objects[0].walk_mps", ">= 0"),
    ('[[objects]]\nmesh = "ogre"\nlod_floor = 0.0\n', "objects[0].lod_floor", ">= 0.005"),
    ('[[objects]]\nmesh = "ogre"\nlod_floor = 1.5\n', "objects[0].lod_floor", "<= 1"),
    ('[[objects]]\nmesh = "armadillo.off"\nheight_m = 2.0\n', "objects[0].mesh",
     "no such file"),
    ('[[objects]]\nmesh = "../box.off"\nheight_m = 2.0\n', "objects[0].mesh",
     "leads out of the scene file's folder"),
    ('[[lightfields]]\nsource = "statue.lf"\nposition = [0.0, 0.0]\nheight_m = 3.0\n',
     "lightfields[0].source", "no such file"),
    ('[[lightfields]]\nsource = "."\nposition = [0.0]\nheight_m = 3.0\n',
     "lightfields[0].position", "length 2"),
    ('[view]\npath = "flyover"\nsize = "big"\n', "view.size", "WxH"),
    ('[view]\npath = "loop-the-loop"\n', "view.path", "loop-the-loop"),
    ('[view]\nspeed = 3\n', "view.speed", "unknown field"),
]


@pytest.mark.parametrize(("body", "field", "what"), BAD, ids=[b[1] + ":" + b[2] for b in BAD])
def test_each_bad_field_is_refused_by_name(tmp_path: Path, body: str, field: str,
                                           what: str) -> None:
    folder = tmp_path / "scenes"
    folder.mkdir()
    message = refusal(write(folder, TERRAIN + body))
    assert message.startswith(f"{folder / 'scene.toml'}: {field}: "), message
    assert what.lower() in message.lower(), message


def test_terrain_fields_are_named(tmp_path: Path) -> None:
    assert ": terrain.source: required" in refusal(write(tmp_path, "[terrain]\ngrid = 64\n"))
    assert ": terrain.grid: must be a power of two" in refusal(
        write(tmp_path, TERRAIN + "grid = 100\n"))
    assert ": terrain.source: no such file" in refusal(
        write(tmp_path, '[terrain]\nsource = "alps.tif"\n'))
    assert ": terrain: " in refusal(write(tmp_path, '[terrain]\nsource = "fractal:65"\n'))
    assert ": terrain: required" in refusal(write(tmp_path, "[view]\npath = 'flyover'\n"))


def test_grid_is_capped_and_deep_nesting_is_one_line(tmp_path: Path) -> None:
    # review finding 5: grid had no upper cap; deep nesting escaped as RecursionError
    message = refusal(write(tmp_path, TERRAIN + "grid = 1073741824\n"))
    assert ": terrain.grid: must be a power of two >= 16 and <= 8192" in message, message
    deep = TERRAIN + "x = " + "[" * 20000 + "]" * 20000 + "\n"
    assert ": nested too deeply" in refusal(write(tmp_path, deep))


def test_a_mesh_file_other_than_gltf_needs_its_height(tmp_path: Path, box_off: Path) -> None:
    message = refusal(write(tmp_path, TERRAIN + '[[objects]]\nmesh = "box.off"\n'))
    assert ": objects[0].height_m: required for a mesh file other than glTF" in message


def test_syntax_error_names_line_and_column(tmp_path: Path) -> None:
    message = refusal(write(tmp_path, TERRAIN + "[[objects]]\nmesh = \n"))
    assert ": line 4, column 8: TOML syntax error" in message, message


def test_section_and_size_caps(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    many = TERRAIN + '[[objects]]\nmesh = "ogre"\n' * 65
    assert ": objects: at most 64 sections" in refusal(write(tmp_path, many))
    monkeypatch.setattr(scene_file, "MAX_FILE_BYTES", 64)
    assert "over 64 bytes" in refusal(write(tmp_path, TERRAIN + "# " + "x" * 80 + "\n"))


def test_points_caps_and_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    body = TERRAIN + '[[objects]]\nmesh = "ogre"\npoints = "p.csv"\n'
    scene = write(tmp_path, body)
    (tmp_path / "p.csv").write_text("x,y\n0,0\n# a comment\n\n1.5,oops\n")
    assert ": objects[0].points: p.csv line 5: expected x,y" in refusal(scene)
    (tmp_path / "p.csv").write_text("0,0\n1,1\n2,2\n")
    monkeypatch.setattr("lodsprite.scene.placement.MAX_POINTS_ROWS", 2)
    assert "p.csv has more than 2 rows" in refusal(scene)
    monkeypatch.setattr(scene_file, "MAX_POINTS_BYTES", 4)
    assert ": objects[0].points: p.csv is over 4 bytes" in refusal(scene)


def test_a_point_or_position_outside_the_terrain_is_refused(tmp_path: Path) -> None:
    # fractal:64 spans 64 * 30 m = 1920 m: x, y in -960..960
    (tmp_path / "p.csv").write_text("0,0\n100,-200\n950,961\n")
    body = TERRAIN + '[[objects]]\nmesh = "tree"\nheight_m = 5.0\npoints = "p.csv"\n'
    message = refusal(write(tmp_path, body))
    assert ": objects[0].points: line 3: (950, 961) is outside the terrain" in message
    lf = tmp_path / "statue.lf"
    lf.mkdir()
    (lf / "lumigraph.json").write_text("{}")
    body = (TERRAIN + '[[lightfields]]\nsource = "statue.lf"\nposition = [-1000.0, 0.0]\n'
            "height_m = 30.0\n")
    assert ": lightfields[0].position: (-1000, 0) is outside" in refusal(write(tmp_path, body))


def test_paths_resolve_against_the_folder_and_absolute_ones_are_kept(
        tmp_path: Path, box_off: Path) -> None:
    folder = tmp_path / "scenes"
    (folder / "sub").mkdir(parents=True)
    (folder / "p.csv").write_text("10,20\n")
    body = (TERRAIN + f'[[objects]]\nmesh = "{box_off}"\nheight_m = 2.0\n'
            'points = "sub/../p.csv"\n')
    sf = read_scene_file(write(folder, body))
    assert sf.objects[0].mesh == str(box_off)
    assert sf.objects[0].points == str(folder / "p.csv")
    assert sf.terrain.source == "fractal:64"          # a built-in spec is not a path


def test_missing_scene_file(tmp_path: Path) -> None:
    with pytest.raises(SceneFileError, match="no such scene file"):
        read_scene_file(tmp_path / "none.toml")


def test_scene_check_prints_the_layers_and_refuses_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    np.save(tmp_path / "plane.npy", np.zeros((17, 17), np.float32))
    good = write(tmp_path, '[terrain]\nsource = "plane.npy"\ngrid = 16\n'
                 '[[objects]]\nmesh = "tree"\nheight_m = 4.0\ncount = 3\n', "good.toml")
    bad = write(tmp_path, TERRAIN + '[[objects]]\nmesh = "ogre"\ncount = 0\n', "bad.toml")
    from lodsprite.cli import main

    codes = []
    for p in (good, bad):
        with pytest.raises(SystemExit) as exit_:
            main(["scene", "check", str(p)])
        codes.append(exit_.value.code)
    printed = capsys.readouterr()
    assert codes == [0, 2], printed.err
    assert "1 types, 3 instances" in printed.out and "480 x 480 m" in printed.out
    assert printed.err.strip().splitlines() == [
        f"lodsprite: error: {bad}: objects[0].count: must be >= 1 and <= 200000"]
