"""The command line through the console script's own ``main``: real runs and refusals in
this process (``conftest.run_cli`` and the ``cli`` fixture, exit codes and output as a user
sees them), ``info`` and one refusal as real processes."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import run_cli

SMALL = ["--terrain", "fractal:64:3", "--size", "64x64"]


def lodsprite(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()", *args],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def assert_user_error(proc, fragment):
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert fragment in lines[0]


def test_info_prints_renderer_and_texture_size():
    proc = lodsprite("info")
    assert proc.returncode == 0, proc.stderr
    assert "renderer" in proc.stdout and "max texture size" in proc.stdout


@pytest.mark.parametrize("mode", ["full", "lod", "sprite"])
def test_render_writes_one_row_per_frame(tmp_path, mode):
    out = tmp_path / "o"
    lod = [] if mode == "full" else ["--lod", "8"]  # full takes no --lod
    proc = run_cli("render", *SMALL, "--mode", mode, *lod, "--frames", "7",
                   "--out", str(out), "--save-frames")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert [int(r["frame"]) for r in rows] == list(range(7))
    assert list(rows[0])[:5] == ["frame", "kind", "ms", "triangles", "error_px"]
    assert all(float(r["ms"]) > 0 for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    for key in ("frames", "mode", "terrain", "size", "median_ms", "mean_ms", "std_ms",
                "p95_ms", "p99_ms", "max_ms", "total_s", "gl_renderer"):
        assert key in summary
    assert summary["frames"] == 7 and summary["mode"] == mode
    assert len(list((out / "frames").glob("frame_*.png"))) == 7
    if mode == "full":
        assert max(int(r["triangles"]) for r in rows) == 2 * 64 * 64
    if mode == "lod":
        assert max(int(r["triangles"]) for r in rows) <= 2 * 8 * 8


def test_sprite_mode_with_ground_truth_reports_quality(tmp_path):
    out = tmp_path / "s"
    proc = run_cli("render", *SMALL, "--mode", "sprite", "--lod", "8", "--frames", "12",
                     "--ground-truth", "--epsilon", "0.5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert rows[0]["kind"] == "keyframe"
    assert {r["kind"] for r in rows} <= {"keyframe", "first_sprite", "sprite"}
    for key in ("error_px", "rmse", "psnr", "ssim", "rmse_lod"):
        assert key in rows[0]
    keyframes = [r for r in rows if r["kind"] == "keyframe"]
    # A keyframe frame shows the keyframe's centre, the full-resolution frame: against the
    # band-limited reference it is off by the one-sample aliasing only, far closer than
    # the plain coarse level at the same frame.
    exact = [r for r in keyframes if float(r["error_px"]) == 0]
    assert exact and all(float(r["rmse"]) < float(r["rmse_lod"]) for r in exact)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["keyframes"] == len(keyframes)
    for key in ("rmse_mean", "rmse_lod_mean", "psnr_mean", "psnr_lod_mean",
                "ssim_mean", "ssim_lod_mean"):
        assert np.isfinite(summary[key])


@pytest.mark.parametrize(("args", "fragment"), [
    (["render", "--terrain", "/no/such.tif"], "/no/such.tif"),
    (["render", *SMALL, "--mode", "warp"], "mode"),
    (["render", *SMALL, "--mode", "lod", "--lod", "12"], "power of two"),
    (["render", *SMALL, "--path", "nowhere"], "nowhere"),
    (["render", "--terrain", "fractal:64", "--size", "wide"], "size"),
    (["render", *SMALL, "--frames", "1"], "frames"),
    (["render", *SMALL, "--texture", "/no/image.png"], "/no/image.png"),
    (["render", *SMALL, "--mode", "sprite", "--epsilon", "0"], "epsilon"),
    (["render", *SMALL, "--mode", "sprite", "--guard", "-1"], "guard"),
    (["render", *SMALL, "--mode", "sprite", "--cache-mb", "-1"], "cache-mb"),
    (["render", *SMALL, "--mode", "sprite", "--cache-policy", "fifo"], "cache-policy"),
    (["render", *SMALL, "--mode", "sprite", "--cache-mb", "0.01"], "at least"),
    (["render", *SMALL, "--path", "patrol:1:2:0"], "passes"),
    (["render", *SMALL, "--mode", "sprite", "--metric", "sampling"], "metric"),
    (["render", *SMALL, "--mode", "distributed", "--metric", "resample"], "metric"),
    (["render", "--no-such-option"], "no-such-option"),
    (["reproduce", "nobody2000"], "nobody2000"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, cli, args, fragment):
    # In this process (the console script's main): the refusal comes before any work, and
    # a process each cost ~2 s of start-up; the real process's exit code is checked below.
    out = tmp_path / "never"
    proc = cli(*args, "--out", str(out)) if args[0] == "render" and "--no-such-option" \
        not in args else cli(*args)
    assert_user_error(proc, fragment)
    assert not out.exists()


def test_a_real_process_exits_2_with_one_line(tmp_path):
    out = tmp_path / "never"
    assert_user_error(lodsprite("render", *SMALL, "--mode", "warp", "--out", str(out)), "mode")
    assert not out.exists()


def test_malformed_geotiff_exits_2(tmp_path, cli):
    bad = tmp_path / "broken.tif"
    bad.write_bytes(b"II*\x00 this is not a tiff")
    assert_user_error(cli("render", "--terrain", str(bad), "--out", str(tmp_path / "o")),
                      "broken.tif")


def test_reproduce_quick_writes_results_plots_and_report(tmp_path, cli, monkeypatch):
    from lodsprite.experiments.chen1999.run import ReproduceConfig

    # The command in this process, its --quick shortened for the suite (the suite's
    # slowest test at 256², 115 frames: 30 s): 96², 36 frames, quality every 3rd frame.
    quick = ReproduceConfig.quick
    monkeypatch.setattr(ReproduceConfig, "quick", classmethod(lambda cls, **kw: quick(
        **{"size": 96, "frames": 36, "fig10_frames": (18, 36), **kw})))
    out = tmp_path / "r"
    proc = cli("reproduce", "chen1999", "--quick", "--terrain", "fractal:64:1",
               "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    results = json.loads((out / "results.json").read_text())
    for key in ("frames", "keyframes", "epsilon", "mean_ms_keyframe", "mean_ms_first_sprite",
                "mean_ms_sprite", "total_s_full", "total_s_sprite", "speedup",
                "rmse_mean", "rmse_lod_mean", "psnr_mean", "psnr_lod_mean",
                "fig10", "fig11", "fig12"):
        assert key in results
    # The speedup from the per-frame times, independently of the run's own totals: the
    # full-resolution frames' mean time scaled to the path, over the sum of LOD-sprite times.
    pf = results["per_frame"]
    assert len(pf["ms_sprite"]) == len(pf["ms_full"]) == results["frames"]
    ms_full = [v for v in pf["ms_full"] if v is not None]
    assert len(ms_full) == results["full_sample_frames"]
    total_full = float(np.mean(ms_full)) * results["frames"] / 1e3
    total_sprite = sum(pf["ms_sprite"]) / 1e3
    assert results["speedup"] == pytest.approx(total_full / total_sprite, rel=1e-9)
    # Keyframes: counted from the frame types, one logged view each, fewer than the frames.
    assert results["keyframes"] == pf["type"].count("keyframe") == len(results["keyframe_views"])
    assert 0 < results["keyframes"] < results["frames"]
    report = (out / "report.md").read_text()
    assert "12.32" in report
    for png in ("fig08_error.png", "fig09_time.png", "fig13.png", "fig14.png"):
        assert (out / png).stat().st_size > 1000


@pytest.mark.parametrize(("args", "fragment"), [
    (["--tiles", "9"], "option --tiles: got 9, allowed: 1..4"),
    (["--tiles", "2", "--tile-budget-ms", "-1"],
     "option --tile-budget-ms: got -1.0, allowed: >= 0 ms"),
    (["--tiles", "2", "--mode", "lod"], "--tiles does not go with --mode lod"),
])
def test_render_refuses_bad_tile_options(cli, args, fragment):
    assert_user_error(cli("render", *SMALL, "--mode", "sprite", "--frames", "2", *args),
                      fragment)
