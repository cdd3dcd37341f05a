"""``lodsprite crowd``, ``reproduce gumbau`` and ``view crowd``, small."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from conftest import run_cli
from lodsprite import experiments
from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.experiments.gumbau.report import write_outputs
from lodsprite.experiments.gumbau.run import GumbauConfig, reproduce_gumbau
from lodsprite.manager.run import CrowdConfig, crowd_models, make_crowd, run_crowd
from lodsprite.paths import CameraPath

SUMMARY_KEYS = ("extractions_total", "fps_mean", "median_ms", "p99_ms",
                "triangles_mean", "draw_calls_mean", "lod_cpu_ms_mean")


def lodsprite(*args):
    return run_cli(*args)  # in this process: no start-up per run


def test_crowd_writes_one_row_per_frame_and_a_summary_of_those_rows(tmp_path):
    r = lodsprite("crowd", "--objects", "150", "--frames", "6", "--size", "96x72",
                  "--slots", "8", "--out", str(tmp_path / "c"))
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "c" / "summary.json").read_text())
    with open(tmp_path / "c" / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(row["frame"]) for row in rows] == list(range(6))   # the walkthrough's frames
    col = {k: np.array([float(row[k]) for row in rows])
           for k in ("triangles", "visible", "draw_calls", "extractions")}
    member, _ = crowd_models(None, 0)
    fine, coarse = (len(member.extract(f)) // 3 for f in (1.0, 0.0))
    # every object drawn shows one LOD of the member, between its coarsest and finest
    assert (col["visible"] > 0).all() and (col["visible"] <= 150).all()
    assert (col["triangles"] >= col["visible"] * coarse).all()
    assert (col["triangles"] <= col["visible"] * fine).all()
    assert (col["draw_calls"] >= 2).all() and (col["draw_calls"] <= col["visible"] + 1).all()
    # the summary is of these rows (keys read: frames, objects, extractions_total,
    # triangles_mean, draw_calls_mean)
    assert s["frames"] == 6 and s["objects"] == 150
    assert s["extractions_total"] == col["extractions"].sum()
    assert s["triangles_mean"] == pytest.approx(col["triangles"].mean())
    assert s["draw_calls_mean"] == pytest.approx(col["draw_calls"].mean())


def _from_afar(extent: float, frames: int = 3) -> CameraPath:
    """A still camera high above the crowd's ground: every object in view (within the far
    plane, 4 extents + 100 m) and under 3 % of the screen high (the discrete baseline's
    coarsest level)."""
    vp = look_at((0.0, -2.0 * extent, 5.0 * extent), (0.0, 0.0, 0.0))
    return CameraPath("afar", (vp,) * frames, 60.0)


@pytest.mark.parametrize("mode, near, lod, warm_extractions, groups", [
    # beyond range_far every object wants the coarsest LOD, its starting one: no work
    ("manager", 5.0, 0.0, 0, 1),
    ("discrete", 5.0, 0.0, 0, 1),   # small on screen: the coarsest of the four levels
    # within range_near every object wants the finest: the manager extracts it once and
    # all share it; independent, each object extracts and draws its own copy
    ("manager", 1e4, 1.0, 1, 1),
    ("independent", 1e4, 1.0, 150, 150),
])
def test_a_crowd_on_one_lod_draws_objects_times_that_lods_triangles(mode, near, lod,
                                                                   warm_extractions, groups):
    cfg = CrowdConfig(objects=150, frames=3, size=(64, 48), slots=8, mode=mode,
                      range_near=near, range_far=2 * near)
    crowd = make_crowd(cfg)
    rows, s, _ = run_crowd(cfg, path=_from_afar(crowd.extent))
    per_object = len(crowd.models[0].extract(lod)) // 3
    assert len(rows) == 3 and s["frames"] == 3
    for row in rows:
        assert row["visible"] == 150
        assert row["triangles"] == 150 * per_object
        assert row["draw_calls"] == groups + 1            # and the ground
        assert row["extractions"] == 0                    # all done in the warm-up frame
    assert s["warmup_extractions"] == warm_extractions


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


def test_a_bad_mesh_is_one_line_and_exit_code_2(tmp_path, cli):
    (tmp_path / "empty.obj").write_text("")    # (in this process: refused before any work)
    r = cli("crowd", "--mesh", str(tmp_path / "empty.obj"), "--objects", "5",
            "--frames", "2", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1
    assert not (tmp_path / "o").exists()
    r = cli("crowd", "--slots", "0", "--out", str(tmp_path / "o"))
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
