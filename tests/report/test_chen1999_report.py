"""The Chen 1999 report layer: plots and report.md from a synthetic ``results`` dict."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lodsprite.experiments.chen1999.report import PAPER, write_plots, write_report
from lodsprite.files import write_json

N = 40
ALL_PLOTS = [
    "fig08_error.png", "fig09_time.png", "fig10_keyframes_vs_frames.png",
    "fig11_keyframes_vs_epsilon.png", "fig12_speedup_vs_epsilon.png", "fig13.png", "fig14.png",
]


def _frame_types(n: int, period: int = 8) -> list[str]:
    return ["keyframe" if i % period == 0 else "first_sprite" if i % period == 1 else "sprite"
            for i in range(n)]


def _images(out_dir: Path) -> dict:
    rng = np.random.default_rng(0)
    names = {}
    for key in ("full", "lod", "sprite", "keyframe_image"):
        Image.fromarray(rng.integers(0, 255, (32, 32, 3), dtype=np.uint8)).save(
            out_dir / f"fig14_{key}.png")
        names[key] = f"fig14_{key}.png"
    for key in ("diff_lod", "diff_sprite"):
        Image.fromarray(rng.integers(0, 80, (32, 32), dtype=np.uint8), mode="L").save(
            out_dir / f"fig14_{key}.png")
        names[key] = f"fig14_{key}.png"
    fig13 = {k: names[k] for k in ("full", "lod", "sprite")}
    key = {"keyframe": 3, "keyframe_frame": 20, "keyframe_ahead": True}
    return {"fig13": {"frame": 17, **fig13}, "fig14": {"frame": 23, **key, **names}}


def _results(out_dir: Path) -> dict:
    types = _frame_types(N)
    err = [0.0 if t == "keyframe" else 0.15 * (i % 8) for i, t in enumerate(types)]
    ms = [12.0 if t == "keyframe" else 1.1 if t == "first_sprite" else 0.4 for t in types]
    ms_full = [11.5 if i % 5 == 0 else None for i in range(N)]
    return {
        "experiment": "chen1999-test", "terrain": "fractal", "grid": 512, "lod": 16,
        "path": "chen1999", "size": [512, 512], "frames": N, "epsilon": 1.0,
        "visibility": "vertex-depth", "gl_renderer": "Mesa llvmpipe", "machine": "ci-box",
        "keyframes": 5, "keyframe_fraction": 5 / N,
        "mean_ms_keyframe": 12.345, "mean_ms_first_sprite": 1.1, "mean_ms_sprite": 0.4,
        "total_s_full": 0.46, "total_s_sprite": 0.0745, "total_s_lod": 0.012,
        "speedup": 6.1745, "full_sampled": True, "full_sample_frames": 8,
        "rmse_mean": 4.5, "rmse_lod_mean": 12.25, "rmse_ratio": 0.3673,
        "psnr_mean": 35.12, "psnr_lod_mean": 26.4,
        "ssim_mean": 0.9512, "ssim_lod_mean": 0.8123,
        "per_frame": {
            "type": types, "error_px": err, "ms_sprite": ms, "ms_full": ms_full,
            "ms_lod": [0.3] * N, "rmse": [4.5] * N, "rmse_lod": [12.25] * N,
        },
        "fig10": {"frames": [115, 230, 460, 920], "keyframes": [20, 28, 30, 33],
                  "keyframe_fraction": [20 / 115, 28 / 230, 30 / 460, 33 / 920]},
        "fig11": {"epsilon": [0.5, 1.0, 2.0], "keyframes": [40, 28, 15],
                  "keyframe_fraction": [40 / 460, 28 / 460, 15 / 460]},
        "fig12": {"epsilon": [0.5, 1.0, 2.0], "total_s_sprite": [0.2, 0.0745, 0.05],
                  "speedup": [2.3, 6.1745, 9.2]},
        "images": _images(out_dir),
    }


@pytest.fixture
def results(tmp_path: Path) -> dict:
    return _results(tmp_path)


@pytest.fixture(scope="module")
def produced(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path], str]:
    """One full run shared by the tests that only read its outputs (plots are slow-ish)."""
    out_dir = tmp_path_factory.mktemp("chen1999")
    results = _results(out_dir)
    plots = write_plots(results, out_dir)
    report = write_report(results, out_dir, plots)
    assert report == out_dir / "report.md"
    return out_dir, plots, report.read_text(encoding="utf-8")


def test_every_plot_is_a_valid_png(produced: tuple[Path, list[Path], str]) -> None:
    out_dir, plots, _ = produced
    assert [p.name for p in plots] == ALL_PLOTS
    for p in plots:
        assert p.parent == out_dir and p.stat().st_size > 5_000, p
        with Image.open(p) as im:
            im.verify()
        with Image.open(p) as im:
            assert im.format == "PNG" and min(im.size) >= 300, (p, im.size)


def test_report_has_paper_and_our_numbers(produced: tuple[Path, list[Path], str]) -> None:
    _, _, text = produced
    for paper in ("28 of 460", "830.0", "36.0", "15.0", "383.20", "31.10", "12.32", "403"):
        assert paper in text, paper
    for ours in ("5 of 40", "12.3", "1.1", "0.40", "0.46", "0.074", "6.17", "0.367", "4.50",
                 "12.25", "35.12", "0.9512", "target ≤ 0.5: met"):
        assert f"| {ours}" in text, ours
    for name in ("Mesa llvmpipe", "ci-box", "fractal", "512²", "16²", "vertex-depth",
                 "512×512 px", "SGI Power Challenge"):
        assert name in text, name
    for name in ALL_PLOTS:
        assert f"]({name})" in text, name
    assert "measured on 8 evenly spaced frames and scaled to all 40 frames" in text
    assert PAPER["speedup"] == 12.32


def test_no_sampling_note_when_full_not_sampled(results: dict, tmp_path: Path) -> None:
    results["full_sampled"] = False
    text = write_report(results, tmp_path, []).read_text(encoding="utf-8")
    assert "evenly spaced" not in text
    assert "Not produced in this run" in text


def test_missing_optional_sections_are_skipped(results: dict, tmp_path: Path) -> None:
    for key in ("fig10", "fig11"):
        del results[key]
    results["images"] = {"fig14": results["images"]["fig14"]}  # no fig13 key
    results["images"]["fig14"]["full"] = "no_such_file.png"  # a missing panel stays blank
    plots = write_plots(results, tmp_path)
    names = {p.name for p in plots}
    assert names == set(ALL_PLOTS) - {
        "fig10_keyframes_vs_frames.png", "fig11_keyframes_vs_epsilon.png", "fig13.png"}
    text = write_report(results, tmp_path, plots).read_text(encoding="utf-8")
    assert "fig10_keyframes_vs_frames.png" not in text
    assert "## Fig. 10" not in text and "## Fig. 12" in text


def test_nan_none_and_inf_render_as_dash(results: dict, tmp_path: Path) -> None:
    results.update(rmse_ratio=float("nan"), psnr_mean="inf", speedup=None,
                   mean_ms_sprite=math.inf)
    results["per_frame"]["error_px"][3] = float("nan")
    results["fig12"]["speedup"][0] = "inf"
    del results["images"]  # not about NaN; keeps the test fast
    # through JSON, as the runner stores it: NaN -> null, inf -> "inf"
    write_json(tmp_path / "results.json", results)
    loaded = json.loads((tmp_path / "results.json").read_text())
    report = write_report(loaded, tmp_path, write_plots(loaded, tmp_path))
    rows = {line.split("|")[1].strip(): line for line in report.read_text().splitlines()
            if line.startswith("| ")}
    for quantity in ("RMSE ratio, LOD-sprite ÷ plain LOD", "PSNR, LOD-sprite vs ref (dB, mean)",
                     "speedup, full ÷ LOD-sprite (×)", "mean time, spriteframe (ms)"):
        assert rows[quantity].split("|")[2].strip() == "—", rows[quantity]
    assert "| 0.5 | 0.20 | — |" in report.read_text()
    assert "nan" not in report.read_text().lower()


def test_figure_14_names_and_shows_the_keyframe_drawn_from(
        produced: tuple[Path, list[Path], str], tmp_path: Path) -> None:
    out_dir, _, text = produced
    assert "Frame 23 (keyframe 3, rendered at frame 20 from a viewpoint ahead of the viewer)" \
        in text
    assert "Frame 17:" in text  # no keyframe recorded for Fig. 13: the frame alone
    # The keyframe panel (f) takes the free cell of the second row: the same layout with it
    # left out draws one panel fewer, so the images differ.
    results = _results(tmp_path)
    del results["images"]["fig14"]["keyframe_image"]
    without = _plot_panels_png(results, tmp_path)
    with Image.open(out_dir / "fig14.png") as a, Image.open(without) as b:
        assert a.size == b.size
        assert np.abs(np.asarray(a.convert("L"), int) - np.asarray(b.convert("L"), int)).sum() > 0


def _plot_panels_png(results: dict, out_dir: Path) -> Path:
    plots = write_plots({"images": results["images"], "grid": 512, "lod": 16}, out_dir)
    return next(p for p in plots if p.name == "fig14.png")
