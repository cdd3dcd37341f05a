"""``lodsprite crowd``, ``reproduce gumbau`` and ``view crowd``, small."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from lodsprite import experiments
from lodsprite.errors import InputError
from lodsprite.experiments.gumbau.report import write_outputs
from lodsprite.experiments.gumbau.run import GumbauConfig, reproduce_gumbau
from lodsprite.manager.run import CrowdConfig, run_crowd

SUMMARY_KEYS = ("extractions_total", "fps_mean", "median_ms", "p99_ms",
                "triangles_mean", "draw_calls_mean", "lod_cpu_ms_mean")


def lodsprite(*args):
    return subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()",
                           *args], capture_output=True, text=True, timeout=240)


def test_crowd_writes_frames_and_summary(tmp_path):
    r = lodsprite("crowd", "--objects", "150", "--frames", "6", "--size", "96x72",
                  "--slots", "8", "--out", str(tmp_path / "c"))
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "c" / "summary.json").read_text())
    for key in SUMMARY_KEYS:
        assert np.isfinite(s[key]), key
    with open(tmp_path / "c" / "frames.csv") as f:
        assert len(list(csv.DictReader(f))) == 6


@pytest.mark.parametrize("args, fragment", [
    (["--slots", "0"], "--slots"),
    (["--objects", "-5"], "must be >= 0"),
    (["--target-fps", "0"], "--target-fps"),
    (["--active", "0"], "--active"),
])
def test_impossible_options_are_refused_before_anything_is_written(tmp_path, args, fragment):
    cfg = dict(objects=10, frames=2)
    kw = {"--slots": "slots", "--objects": "objects", "--target-fps": "target_fps",
          "--active": "active"}
    cfg[kw[args[0]]] = float(args[1]) if args[0] == "--target-fps" else int(args[1])
    with pytest.raises(InputError, match=fragment):
        run_crowd(CrowdConfig(**cfg), tmp_path / "never")
    assert not (tmp_path / "never").exists()


def test_a_bad_mesh_is_one_line_and_exit_code_2(tmp_path):
    (tmp_path / "empty.obj").write_text("")
    r = lodsprite("crowd", "--mesh", str(tmp_path / "empty.obj"), "--objects", "5",
                  "--frames", "2", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1
    assert not (tmp_path / "o").exists()
    r = lodsprite("crowd", "--slots", "0", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "--slots" in r.stderr


def test_reproduction_writes_every_key_plots_and_report(tmp_path):
    cfg = GumbauConfig(objects=150, trees=2, frames=12, size=(96, 72), active=40,
                       sample_every=6)
    r = reproduce_gumbau(cfg)
    report = write_outputs(r, tmp_path)
    saved = json.loads((tmp_path / "results.json").read_text())
    for key in ("extractions_with", "extractions_without", "lod_cpu_ms_with",
                "lod_cpu_ms_without", "fps_mean_with", "fps_mean_without",
                "triangles_mean_with", "triangles_mean_without", "draw_calls_mean_with",
                "draw_calls_mean_without", "image_diff_mean", "target_fps",
                "frame_ms_median_at_target", "frame_ms_p99_at_target"):
        assert np.isfinite(saved[key]), key
    # sharing: the manager extracts far less than every object for itself
    assert saved["extractions_with"] * 5 < saved["extractions_without"]
    for name in ("fig05_with_without_diff.png", "fig06_fps_triangles.png",
                 "target_fps.png"):
        assert (tmp_path / name).stat().st_size > 2000
    assert "Baseline (b)" in report.read_text()
    table = experiments.get("gumbau").summary(saved)
    assert table.rows[0] == ("extractions", f"{saved['extractions_with']:,}",
                             f"{saved['extractions_without']:,}")


def test_the_crowd_in_the_viewer_switches_modes(gl):
    from lodsprite import techniques
    from lodsprite.gl.target import RenderTarget
    from lodsprite.scene import open_scene
    from lodsprite.viewer.controls import CameraController
    from lodsprite.viewer.core import ViewerCore

    scene = open_scene("crowd:100")  # the registry's modes for its object set
    assert scene.layers == ("objects",) and scene.mode == "manager"
    modes = techniques.factories(scene.layers, target_fps=30.0)
    assert list(modes) == ["manager", "independent", "discrete"]
    core = ViewerCore(gl.mgl, scene, (96, 72), modes, "manager",
                      CameraController.from_home(scene.camera_home()))
    target = RenderTarget(gl, 96, 72)
    try:
        for key, mode in (("1", "manager"), ("2", "independent"), ("3", "discrete")):
            core.key(key)
            assert core.mode == mode
            core.frame(1 / 30, target.fbo)
            core.log_frame()
            img = core.technique.read_image()
            assert (img != img[0, 0]).any(axis=2).mean() > 0.2   # ground and crowd drawn
        core.key("1")
        core.key("]")
        assert core.technique.params()["fps"].value == pytest.approx(37.5)
    finally:
        core.release()
        target.release()
