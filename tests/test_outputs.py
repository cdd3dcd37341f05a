"""Every command's output place is checked before any work: a file in the way, a place
that cannot hold a folder, each refused in one line with exit code 2 (a typed error from
the API), nothing written anywhere."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from lodsprite.errors import InputError
from lodsprite.files import writable_folder

# (command, its arguments before --out): each would run for seconds to minutes if the
# output place were not checked first
COMMANDS = [
    ("render", "--terrain", "fractal:64", "--frames", "2", "--size", "32"),
    ("render", "--scene", "crowd:20", "--frames", "2", "--size", "32"),
    ("reproduce", "chen1999", "--quick"),
    ("demo", "--quick"),
    ("tile", "fractal:64"),
    ("crowd", "--frames", "2"),
    ("keys",),
    ("lumigraph", "capture", "--uv", "8"),
    ("lumigraph", "render", "missing.lf"),
    ("client", "--frames", "2"),
    ("profile", "sphere"),
]


def tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.mark.parametrize("args", COMMANDS, ids=[" ".join(c[:2]) for c in COMMANDS])
def test_an_output_place_that_cannot_be_written_is_refused_before_any_work(
        args, cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a-file").write_text("x")
    before = tree(tmp_path)
    for out, why in ((tmp_path / "a-file" / "sub", "is a file, not a folder"),
                     (Path("/proc/lodsprite-out"), "cannot write in /proc")):
        target = out / "t.npz" if args[0] == "profile" else out
        proc = cli(*args, "--out", target)
        lines = [x for x in (proc.stdout + proc.stderr).splitlines() if x.strip()]
        assert proc.returncode == 2 and len(lines) == 1, (args, proc.stdout, proc.stderr)
        assert why in lines[0] and "--out" in lines[0], lines
        assert "Traceback" not in proc.stderr
    assert tree(tmp_path) == before  # nothing written, not even a folder


def test_writable_folder_makes_nothing_and_names_what_is_in_the_way(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"--frames-dir .*f is a file, not a folder"):
        writable_folder(tmp_path / "f" / "a" / "b", "--frames-dir")
    with pytest.raises(InputError, match="is a file"):
        writable_folder(tmp_path / "f")
    with pytest.raises(InputError, match="cannot write in /proc"):
        writable_folder("/proc/x/y")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    with pytest.raises(InputError, match="dangling is a broken link"):
        writable_folder(tmp_path / "dangling" / "run")
    (tmp_path / "dangling").unlink()
    deep = tmp_path / "new" / "deeper"
    assert writable_folder(deep) == deep and not (tmp_path / "new").exists()
    assert writable_folder(tmp_path) == tmp_path
    assert sorted(os.listdir(tmp_path)) == ["f"]  # the probe is gone


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_a_folder_this_user_may_not_write_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(InputError, match="cannot write in"):
            writable_folder(locked / "out")
    finally:
        locked.chmod(0o700)


def test_the_api_refuses_the_same_place_with_a_typed_error(tmp_path):
    from lodsprite import RenderConfig, render_path
    from lodsprite.run import render_spec

    (tmp_path / "a-file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        render_path(RenderConfig(terrain="fractal:64", frames=2, size=(32, 32)),
                    tmp_path / "a-file" / "run")
    with pytest.raises(InputError, match="is a file"):
        render_spec("crowd:20", tmp_path / "a-file" / "run", frames=2)
