"""A client names a scene, never reaches past the data folder (Datasets.scene and the
confined scene-file reader): files outside the data folder, escaping meshes, symlinks out,
glTF files with external URIs outside, unlisted kinds, oversized crowds and URLs are each
refused in one line, before anything is opened; what is inside opens."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import lodsprite.scene.kinds as kinds
from lodsprite.distributed.datasets import MAX_SESSION_OBJECTS, Datasets
from lodsprite.errors import InputError
from lodsprite.scene import open_scene

TERRAIN = '[terrain]\nsource = "fractal:64"\n'


@pytest.fixture
def data(tmp_path: Path) -> Path:
    import trimesh

    root = tmp_path / "data"
    root.mkdir()
    trimesh.creation.box((1.0, 1.0, 2.0)).export(root / "box.off")
    (tmp_path / "secret.off").write_bytes((root / "box.off").read_bytes())
    (root / "ok.toml").write_text(TERRAIN + '[[objects]]\nmesh = "box.off"\nheight_m = 2.0\n'
                                  'count = 3\n')
    return root


def refused(datasets: Datasets, name: str, fragment: str) -> None:
    with pytest.raises(InputError) as info:
        datasets.scene(name)
    message = str(info.value)
    assert "\n" not in message and fragment in message, message


def gltf(folder: Path, name: str, uri: str) -> None:
    doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": 4}]}
    (folder / name).write_text(json.dumps(doc))


def test_a_scene_file_inside_opens_confined(data: Path) -> None:
    name = Datasets(data).scene("ok.toml")
    assert name.kind == "scene-file" and Path(name.spec) == (data / "ok.toml").resolve()
    scene = open_scene(name.spec, light=True, root=name.root)
    assert "objects" in scene.layers


@pytest.mark.parametrize("body, fragment", [
    ('[[objects]]\nmesh = "../secret.off"\nheight_m = 2.0\n', "leads outside"),
    ('[[objects]]\nmesh = "/etc/passwd"\nheight_m = 2.0\n', "absolute paths are refused"),
    ('[[objects]]\nmesh = "~/box.off"\nheight_m = 2.0\n', "absolute paths are refused"),
    ('[[objects]]\nmesh = "../../etc/passwd"\nheight_m = 2.0\n', "data folder"),
    ('[[objects]]\nmesh = "http://example.com/box.glb"\n', "a URL is refused"),
    ('[[objects]]\nmesh = "link.off"\nheight_m = 2.0\n', "leads outside"),
    ('[[objects]]\nmesh = "out.gltf"\n', "leads outside"),
    ('[[objects]]\nmesh = "abs.gltf"\n', "absolute paths are refused"),
    ('[[objects]]\nmesh = "url.gltf"\n', "a URL is refused"),
    ('[[objects]]\nmesh = "escaped.gltf"\n', "escaped"),
])
def test_a_scene_file_reaching_out_is_refused_by_field(data: Path, body: str,
                                                       fragment: str) -> None:
    os.symlink(data.parent / "secret.off", data / "link.off")
    gltf(data, "out.gltf", "../secret.bin")
    (data.parent / "secret.bin").write_bytes(b"\0" * 4)
    gltf(data, "abs.gltf", str(data.parent / "secret.bin"))
    gltf(data, "url.gltf", "https://example.com/b.bin")
    gltf(data, "escaped.gltf", "%2e%2e/secret.bin")
    (data / "bad.toml").write_text(TERRAIN + body)
    refused(Datasets(data), "bad.toml", fragment)
    refused(Datasets(data), "bad.toml", "objects[0].mesh")


def test_a_gltf_whose_files_are_inside_is_accepted(data: Path) -> None:
    (data / "in.bin").write_bytes(b"\0" * 4)
    gltf(data, "in.gltf", "in.bin")
    gltf(data, "inline.gltf", "data:application/octet-stream;base64,AAAAAA==")
    from lodsprite.scene.file import read_scene_file

    for mesh in ("in.gltf", "inline.gltf"):
        (data / "g.toml").write_text(TERRAIN + f'[[objects]]\nmesh = "{mesh}"\ncount = 2\n')
        sf = read_scene_file(data / "g.toml", root=data)
        assert Path(sf.objects[0].mesh).parent == data.resolve()


@pytest.mark.parametrize("name, fragment", [
    ("../secret.off", "'..' is refused"),
    ("/etc/passwd", "absolute paths are refused"),
    ("~/x.toml", "absolute paths are refused"),
    ("http://example.com/scene.toml", "a URL is refused"),
    ("file:///etc/passwd", "a URL is refused"),
    ("missing.toml", "no such file"),
    (f"crowd:{MAX_SESSION_OBJECTS + 1}", "a crowd of"),
    ("crowd:100000000", "a crowd of"),
    ("crowd:10:99999", "a crowd of"),
    ("crowd:x", "whole numbers"),
    ("fractal:16384", "not a power of two in 16..4096"),
])
def test_hostile_names_are_refused_before_anything_opens(data: Path, name: str, fragment: str,
                                                         monkeypatch) -> None:
    opened = []
    monkeypatch.setattr(kinds, "load_scene", lambda *a, **k: opened.append(a))
    refused(Datasets(data), name, fragment)
    assert opened == []


def test_a_scene_file_symlinked_out_of_the_data_folder_is_refused(data: Path,
                                                                  tmp_path: Path) -> None:
    (tmp_path / "outside.toml").write_text(TERRAIN)
    os.symlink(tmp_path / "outside.toml", data / "in.toml")
    refused(Datasets(data), "in.toml", "leads outside")


def test_kinds_are_served_only_when_listed(data: Path) -> None:
    terrains_only = Datasets(data, kinds=())
    refused(terrains_only, "ok.toml", "does not serve scene-file scenes")
    refused(terrains_only, "crowd:10", "does not serve crowd scenes")
    assert terrains_only.scene("fractal:64").terrain is not None
    assert Datasets(data).scene("crowd:10").kind == "crowd"


def test_session_caps_of_a_scene_file(data: Path) -> None:
    (data / "many.toml").write_text(TERRAIN + '[[objects]]\nmesh = "ogre"\ncount = '
                                    f'{MAX_SESSION_OBJECTS + 1}\n')
    refused(Datasets(data), "many.toml", "more than a session's")
    (data / "big.toml").write_text('[terrain]\nsource = "fractal:8192"\n')
    refused(Datasets(data), "big.toml", "not a power of two in 16..4096")


def test_no_data_folder_serves_built_ins_only(data: Path) -> None:
    refused(Datasets(None), "ok.toml", "serves no files")
    assert Datasets(None).scene("jacksboro").kind is None


@pytest.mark.parametrize("body, fragment", [
    ('mode = "nonesuch"\n', "terrain.mode: unknown technique"),
    ('mode = "adaptive"\n[terrain.options]\nbogus = 1\n', "terrain.options.bogus"),
])
def test_a_scene_files_technique_is_checked_before_anything_opens(
        data: Path, body: str, fragment: str, monkeypatch) -> None:
    """A scene file's ``[terrain] mode`` and options are the registry's to check: a page
    naming one with a bad one is refused at ``load`` (one line naming the field, the file
    as the page named it), nothing of it loaded."""
    opened = []
    monkeypatch.setattr(kinds, "load_scene", lambda *a, **k: opened.append(a))
    (data / "tech.toml").write_text(TERRAIN.rstrip("\n") + "\n" + body)
    refused(Datasets(data), "tech.toml", fragment)
    assert opened == []
