"""benchmarks/reproduce_digest.py (issue 31, must-have 8): what it keeps of a run's
results, and its comparison of two digests (equal to the digit, or not)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmark_scripts import load_benchmark

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def digest():
    return load_benchmark("reproduce_digest")


def test_every_reproduction_has_a_run_and_a_selection(digest):
    from lodsprite import experiments

    assert set(digest.RUNS) == set(digest.SELECT) == set(experiments.names())


def test_the_digest_keeps_decisions_and_errors_not_times_inputs_or_paths(digest, tmp_path):
    results = {
        "config": {"frames": 115}, "gl_renderer": "llvmpipe", "keyframes": 4,
        "mean_ms_keyframe": 124.2, "total_s_full": 14.1, "speedup": 16.0,
        "rmse_sprite_mean": 5.709, "per_frame": {"type": ["keyframe", "sprite"],
                                                 "ms_sprite": [98.1, 5.3]},
        "keyframe_views": [{"frame": 0, "viewpoint": {"o": [0.0, 0.0, 4.8e4]}}],
        "images": {"fig13": {"frame": 83, "full": "fig13_full.png"}},
        "scene_file": "/tmp/x/battlefield.toml", "world": ["terrain: /tmp/x/a.zarr"],
        "critical": {"psnr_mean": 20.4},
    }
    run = tmp_path / "chen1999"
    run.mkdir()
    (run / "results.json").write_text(json.dumps(results))
    (run / "fig13_full.png").write_bytes(b"png")
    figures = digest.extract("chen1999", run)
    assert {k: v for k, v in figures.items() if not k.startswith("png.")} == {
        "keyframes": 4, "rmse_sprite_mean": 5.709, "per_frame.type": ["keyframe", "sprite"],
        "keyframe_views.0.frame": 0, "keyframe_views.0.viewpoint.o": [0.0, 0.0, 4.8e4],
        "images.fig13.frame": 83, "critical.psnr_mean": 20.4}
    assert len(figures["png.fig13_full.png"]) == 64  # the image's SHA-256
    assert figures["png.fig14_full.png"] is None     # not written: a figure that differs
    # sloan1997's time-critical runs choose their images by measured time: dropped there.
    run = tmp_path / "sloan1997"
    run.mkdir()
    (run / "results.json").write_text(json.dumps(results))
    assert "critical.psnr_mean" not in digest.extract("sloan1997", run)


def test_figures_are_equal_to_six_digits_and_integers_exactly(digest):
    same = digest.same
    assert same(5.7094849800118315, 5.709485)          # six significant digits
    assert not same(5.70948, 5.70958)
    assert same(7.75e-15, 0.0)                         # noise at zero
    assert not same(4, 5) and same(4, 4) and not same(True, 1)
    assert same(float("nan"), float("nan")) and not same(float("nan"), 1.0)
    assert same([1, [2.0, None]], [1, [2.0000001, None]])
    assert not same([1, 2], [1, 2, 3]) and not same([1, 2], 1)
    assert not same("keyframe", "sprite")


def test_compare_names_each_difference_and_exits_non_zero(digest, tmp_path, capsys):
    before = {"chen1999": {"keyframes": 4, "rmse": 5.70948, "gone": 1}}
    after = {"chen1999": {"keyframes": 5, "rmse": 5.709481, "new": 2}}
    for name, figures in (("b.json", before), ("a.json", after)):
        (tmp_path / name).write_text(json.dumps({"figures": figures}))
    assert digest.compare(tmp_path / "b.json", tmp_path / "a.json") == 1
    out = capsys.readouterr().out
    assert "DIFFERS chen1999 keyframes: before 4  after 5" in out
    assert "DIFFERS chen1999 gone" in out and "new     chen1999 new" in out
    assert "chen1999: 1 of 3 figures equal to the digit" in out
    assert digest.compare(tmp_path / "b.json", tmp_path / "b.json") == 0
