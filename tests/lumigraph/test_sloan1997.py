"""``reproduce sloan1997 --quick`` end to end: every measurement the issue asks for lands
in results.json, the plots and report.md."""

from __future__ import annotations

import json

import numpy as np

from lodsprite import experiments
from lodsprite.experiments.sloan1997.report import write_outputs
from lodsprite.experiments.sloan1997.run import SloanConfig, reproduce_sloan1997


def test_quick_reproduction_writes_results_plots_and_report(tmp_path):
    cfg = SloanConfig.quick()
    r = reproduce_sloan1997(cfg, tmp_path)
    report = write_outputs(r, tmp_path)
    saved = json.loads((tmp_path / "results.json").read_text())
    for key in ("capture_s", "psnr_full", "psnr_no_depth_correction"):
        assert np.isfinite(saved[key])
    assert 0.0 < saved["full"]["flip_mean"] < 1.0
    assert set(saved["fill_rate"]) == {"full", "subsample", "fixed", "arbitrary", "progressive",
                                       "line", "projective"}
    # strips are drawn twice and every st triangle of the sub-sampled grid three times,
    # wherever the st plane is seen (the interiors of the strips and triangles)
    assert abs(saved["fill_rate"]["line"] - 2.0) < 0.05
    assert abs(saved["fill_rate"]["subsample"] - 3.0) < 0.05
    assert abs(saved["fill_rate"]["full"] - 3.0) < 0.05
    assert saved["table1"]["full"]["locality_db"] == 0.0
    assert set(saved["critical"]) == set(cfg.critical_profiles())
    for prof in saved["critical"].values():
        for key in ("target_ms", "mean_ms", "p99_ms", "images_per_frame_mean", "psnr_mean"):
            assert np.isfinite(prof[key]), key
        assert 1 <= prof["images_per_frame_mean"] <= prof["texture_layers"]
    assert len(saved["critical_frames"]["re2_small_memory"]["ms"]) == cfg.critical_frames
    assert [q["texture_mb"] for q in saved["quality_vs_texture_mb"]] == list(cfg.texture_mbs)
    for name in ("table1_fill_rate.png", "fig05_06_critical_time.png",
                 "quality_vs_budget.png"):
        assert (tmp_path / name).stat().st_size > 5000
    text = report.read_text()
    assert "Table 1" in text and "6x²−3x+3" in text and "fig05_06_critical_time.png" in text
    # The table the command line prints: Table 1's fill rates beside the paper's.
    table = experiments.get("sloan1997").summary(r)
    fill = {row[0]: row for row in table.rows if row[0].startswith("fill rate ")}
    assert set(fill) == {f"fill rate {name}" for name in saved["table1"]}
    assert fill["fill rate line"][1:] == (f"{saved['table1']['line']['fill_rate']:.2f}", "2.0")
