"""The one batch driver: ``render`` runs any technique on any scene, and every batch command
(``render``, ``render --scene``, ``crowd``, ``lumigraph render``) goes through
:func:`lodsprite.driver.drive`, whose files and columns are the same whoever calls it."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from conftest import run_cli
from lodsprite import driver, run
from lodsprite.lumigraph.run import capture_lumigraph

SIZE = "64x48"


@pytest.fixture(scope="module")
def lf_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("driver") / "lf"
    capture_lumigraph("still-life", folder, n_st=6, n_uv=32, codec="png")
    return folder


@pytest.fixture
def drives(monkeypatch):
    """The techniques :func:`lodsprite.driver.drive` ran, in order (by name)."""
    ran: list[str] = []
    real = driver.drive

    def counted(technique, *args, **kwargs):
        ran.append(technique.name)
        return real(technique, *args, **kwargs)

    monkeypatch.setattr(driver, "drive", counted)
    monkeypatch.setattr(run, "drive", counted)  # its name for it, bound on import
    return ran


def rows(folder):
    with open(folder / "frames.csv") as f:
        return list(csv.DictReader(f))


def test_every_batch_command_goes_through_the_one_driver(tmp_path, lf_dir, drives):
    """Each command's run is one call of ``drive`` with the technique it names, and its
    frames.csv has a row per frame with the record's core columns first."""
    commands = [
        (["render", "--frames", "3", "--mode", "lod"], "lod"),
        (["crowd", "--objects", "40", "--frames", "3", "--discrete"], "discrete"),
        (["lumigraph", "render", str(lf_dir), "--frames", "3", "--method", "fixed"], "fixed"),
        (["render", "--scene", "crowd:40", "--frames", "3"], "manager"),
        (["render", "--scene", str(lf_dir), "--frames", "3", "--mode", "full"], "full"),
    ]
    for i, (args, name) in enumerate(commands):
        out = tmp_path / f"run{i}"
        r = run_cli(*args, "--size", SIZE, "--out", str(out))
        assert r.returncode == 0, (args, r.stderr)
        assert drives[-1] == name, args
        got = rows(out)
        assert [int(row["frame"]) for row in got] == [0, 1, 2], args
        assert list(got[0])[0] == "frame"
        assert {"kind", "ms", "triangles", "error_px"} <= set(got[0]), args
    assert len(drives) == len(commands)  # one run each, no second driver underneath


def test_render_runs_a_crowd_technique_with_its_option_and_the_crowds_own_column(tmp_path):
    """``render --scene crowd:N --mode discrete --slots 8``: the crowd technique with the
    option given, the crowd's ``fps`` column (its ``outputs``) beside the harness's ms."""
    out = tmp_path / "c"
    r = run_cli("render", "--scene", "crowd:60", "--mode", "independent", "--slots", "8",
                "--frames", "4", "--size", SIZE, "--out", str(out))
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert (s["mode"], s["technique"], s["path"]) == ("independent", "independent", "walk")
    got = rows(out)
    np.testing.assert_allclose([float(x["fps"]) for x in got],
                               [1e3 / float(x["ms"]) for x in got], rtol=1e-4)


def test_render_on_a_lumigraph_compares_with_the_captured_object(tmp_path, lf_dir):
    """``--ground-truth`` on a lumigraph scene: the technique's reference is the object
    drawn directly, so a full reconstruction is close to it but not identical."""
    out = tmp_path / "l"
    r = run_cli("render", "--scene", str(lf_dir), "--mode", "full", "--frames", "3",
                "--size", SIZE, "--ground-truth", "--out", str(out))
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["technique"] == "lumigraph-full"
    assert 15.0 < s["psnr_mean"] < 80.0   # a reconstruction, not the reference itself
    assert all(row["psnr"] for row in rows(out))


@pytest.mark.parametrize("args, fragment", [
    (["--scene", "crowd:40", "--ground-truth"], "gives no ground truth"),
    (["--scene", "crowd:40", "--mode", "sprite"], "unknown mode 'sprite'"),
])
def test_what_a_scene_cannot_do_is_one_line_and_exit_code_2(tmp_path, args, fragment):
    out = tmp_path / "bad"
    r = run_cli("render", *args, "--frames", "3", "--size", SIZE, "--out", str(out))
    assert r.returncode == 2, r.stderr
    assert fragment in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()  # nothing half-written


@pytest.mark.parametrize("tiles", [1, 2])
def test_render_with_worker_keyframes_plays_the_path_in_time(tmp_path, tiles):
    """``--keyframes worker``: keyframes (or tiles) from the worker process while the
    path plays in time, at the display rate asked; every frame judged at its display
    time, with the played run's columns."""
    out = tmp_path / "w"
    r = run_cli("render", "--terrain", "fractal:64:3", "--grid", "64", "--mode", "sprite",
                "--keyframes", "worker", "--tiles", str(tiles), "--display-fps", "40",
                "--frames", "12", "--size", SIZE, "--ground-truth", "--out", str(out))
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    got = rows(out)
    shown = np.array([float(x["shown_s"]) for x in got])
    start = np.array([float(x["start_s"]) for x in got])
    assert (start >= np.arange(len(got)) / 40.0 - 1e-3).all()   # never before its slot
    assert (shown >= start).all() and s["display_rate"] == 40.0
    assert s["truncated"] is False
    # the image on screen judged at each 60 Hz tick; each tick counted on the frame shown
    ticks = list(csv.DictReader((out / "ticks.csv").open()))
    assert len(ticks) == s["ticks"] > 0 and all(float(t["rmse"]) >= 0 for t in ticks)
    assert sum(int(x["ticks"]) for x in got if x["ticks"]) == len(ticks)
    shown_keys = {int(x["keyframe"]) for x in got}
    assert len(json.loads((out / "keyframes.json").read_text())["keyframes"]) > max(shown_keys)
    # the keyframes the display showed, though none of its frames is one (was 0)
    assert s["keyframes"] == len(shown_keys) >= 1
    assert s["keyframes_rendered"] >= s["keyframes"]
    if tiles > 1:  # no tile budget (the display renders no tile; it read 0.0)
        assert s["tiles"] == tiles and s["tile_budget_ms"] is None
        assert "tiles_discarded" in s


def test_render_play_plays_inline_keyframes_in_time_too(tmp_path):
    """``--play`` with inline keyframes: the same played loop as the worker's (so the two
    are compared alike), keyframes drawn in the frames that need them."""
    out = tmp_path / "p"
    r = run_cli("render", "--terrain", "fractal:64:3", "--grid", "64", "--mode", "sprite",
                "--play", "--display-fps", "40", "--frames", "8", "--size", SIZE,
                "--out", str(out))
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    got = rows(out)
    start = np.array([float(x["start_s"]) for x in got])
    assert s["display_rate"] == 40.0 and s["played_s"] >= 7 / 40.0 - 1e-3  # paced at 40 Hz
    assert (np.diff(start) > 0).all() and (start >= np.arange(len(got)) / 40.0 - 1e-3).all()
    assert s["keyframes"] >= 1 and "latency_ms_mean" in s


@pytest.mark.parametrize("args, fragment", [
    (["--keyframes", "worker", "--key-sse", "1", "--proxy-sse", "4"], "no --proxy-sse"),
    (["--keyframes", "worker", "--save-frames"], "keeps no images"),
    (["--display-fps", "30"], "--display-fps goes with --play or --keyframes worker"),
])
def test_worker_keyframes_refuse_what_a_played_run_cannot_do(tmp_path, args, fragment):
    r = run_cli("render", "--mode", "sprite", *args, "--frames", "3", "--size", SIZE,
                "--out", str(tmp_path / "bad"))
    assert r.returncode == 2 and fragment in r.stderr, r.stderr
    assert not (tmp_path / "bad").exists()
