"""``lodsprite lumigraph capture`` and ``render`` end to end (small lumigraphs)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import run_cli
from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.paths import object_path


def lodsprite(*args):
    """The command in this process (``conftest.run_cli``); ``test_capture_then_render_with_
    ground_truth`` runs the capture as a real process."""
    return run_cli(*args)


def real_process(*args):
    return subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()", *args],
                          capture_output=True, text=True, timeout=240)


def assert_user_error(proc, fragment):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and fragment in lines[0], proc.stderr


def test_capture_then_render_with_ground_truth(tmp_path):
    lf = tmp_path / "lf"
    cap = real_process("lumigraph", "capture", "--out", str(lf), "--st", "6", "--uv", "64",
                    "--codec", "png")
    assert cap.returncode == 0, cap.stderr
    header = json.loads((lf / "lumigraph.json").read_text())
    assert header["slabs"][0]["n_st"] == 6 and header["codec"] == "png"
    assert len(list((lf / "slab0").iterdir())) == 36
    out = tmp_path / "out"
    r = lodsprite("lumigraph", "render", str(lf), "--frames", "4", "--size", "96x96",
                  "--ground-truth", "--out", str(out))
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 4 and s["images_per_frame_mean"] == 36
    # a coarse 6x6 lumigraph of 64² images still resembles the object
    assert 15.0 < s["psnr_mean"] < 60.0
    with open(out / "frames.csv") as f:
        assert len(list(csv.DictReader(f))) == 4
    crit = tmp_path / "crit"
    r = lodsprite("lumigraph", "render", str(lf), "--frames", "6", "--size", "64x64",
                  "--method", "critical", "--texture-mb", "0.05", "--ground-truth",
                  "--every", "2", "--out", str(crit))
    assert r.returncode == 0, r.stderr
    s = json.loads((crit / "summary.json").read_text())
    # 0.05 MB of texture memory holds 3 node images of 64² RGBA
    assert s["method"] == "critical" and s["texture_layers"] == 3
    assert 1 <= s["images_per_frame_mean"] <= 3
    for key in ("mean_ms", "median_ms", "p99_ms", "psnr_mean", "target_ms"):
        assert np.isfinite(s[key])
    with open(crit / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["psnr"] != "" for r in rows] == [True, False] * 3


def test_render_options_out_of_range_are_one_line(tmp_path):
    lf = tmp_path / "lf"
    assert lodsprite("lumigraph", "capture", "--out", str(lf), "--st", "4", "--uv", "32",
                     "--codec", "png").returncode == 0
    assert_user_error(lodsprite("lumigraph", "render", str(lf), "--method", "nope"),
                      "unknown lumigraph method")
    # the other option checks are the API's InputError (the CLI turns any into one line)
    from lodsprite.errors import InputError
    from lodsprite.lumigraph.run import render_lumigraph

    for method, opts, fragment in (("critical", {"texture_mb": 0.001}, "holds no"),
                                   ("arbitrary", {"nodes": 0}, "--nodes"),
                                   ("subsample", {"level": 9}, "level")):
        with pytest.raises(InputError, match=fragment):
            render_lumigraph(lf, tmp_path / "never", frames=2, size=(32, 32), method=method,
                             **opts)
        assert not (tmp_path / "never").exists()
    # the viewer takes the lumigraph's methods as its modes (checked before any window)
    assert_user_error(lodsprite("view", str(lf), "--mode", "sprite"), "use one of critical")


def test_render_of_a_folder_that_is_not_a_lumigraph_is_one_line(tmp_path):
    assert_user_error(lodsprite("lumigraph", "render", str(tmp_path)), "not a lumigraph folder")


def test_capture_of_a_missing_mesh_is_one_line(tmp_path):
    assert_user_error(lodsprite("lumigraph", "capture", str(tmp_path / "nope.obj"), "--out",
                                str(tmp_path / "lf")), "no such mesh file")


def test_the_default_path_stays_in_front_of_the_st_plane():
    slab = Slab(np.eye(4), 3.0, 2.0, 2.5, 8, 64)
    path = object_path(slab, 30)
    eyes = path.eyes()
    assert len(path) == 30 and (eyes[:, 2] > slab.st_distance).all()
    # every eye looks at the uv plane's centre
    for vp in path.viewpoints:
        np.testing.assert_allclose(np.cross(vp.forward, -vp.o / np.linalg.norm(vp.o)), 0,
                                   atol=1e-9)
