"""``lodsprite reproduce swan2002 --quick``: every set-up as real processes (its own file:
the longest test, run beside the other distributed tests by the suite's second worker)."""

import json

from lodsprite.distributed.client import DEFAULT_MAX_ERROR
from lodsprite.experiments.swan2002.run import LINK_SETUPS, SETUPS, SwanConfig


def test_reproduce_swan2002_quick_writes_all_setups(tmp_path, cli, monkeypatch):
    # The command in this process (its set-ups' clients and servers are processes of their
    # own), its --quick shortened for the suite: 20 frames.
    quick = SwanConfig.quick
    monkeypatch.setattr(SwanConfig, "quick", classmethod(lambda cls, **kw: quick(
        **{"frames": 20, **kw})))
    out = tmp_path / "s"
    proc = cli("reproduce", "swan2002", "--quick", "--size", "64", "--terrain",
               "fractal:64:2", "--no-links", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    results = json.loads((out / "results.json").read_text())
    assert results["config"]["size"] == 64 and results["config"]["frames"] == 20
    for setup in SETUPS:
        r = results[setup]
        if "skipped" in r:
            assert setup in LINK_SETUPS and "--no-links" in r["skipped"]
            continue
        for key in ("client_ms_mean", "client_ms_std", "client_ms_p99", "client_ms_median",
                    "sprites_per_keyframe"):
            assert key in r
        if setup != "inline":
            assert r["production_ms_mean"] > 0
        if setup == "two_servers":
            assert r["servers"] == 2
    assert "linear" in results["prediction"] and "kalman" in results["prediction"]
    for setup in ("inline", "separate"):
        image = results[setup]["image"]
        assert image["replayed_frames"] > 0 and image["rmse_mean"] > 0 < image["rmse_lod_mean"]
        assert image["quality_frames"] > 0  # from the run's own untimed replay
    # Both client policies side by side; the bounded one's frames all replayed (its own
    # keyframes logged), none at or above its bound.
    pairs = {p["setup"]: p for p in results["policies"]}
    assert set(pairs) == {"separate", "same_cores"}
    bounded = results["separate_bounded"]
    assert bounded["max_error"] == DEFAULT_MAX_ERROR and bounded["rejected_keyframes"] == 0
    assert bounded["image"]["replayed_frames"] == len(bounded["per_frame_ms"])
    assert bounded["image"]["error_px_max"] < DEFAULT_MAX_ERROR
    assert pairs["separate"]["paper"]["client_ms_std"] == results["separate"]["client_ms_std"]
    report = (out / "report.md").read_text()
    assert report.count("61.9") >= 1 and "`separate` ÷ `same_cores`" in report
    assert "## Image error, replayed" in report and (out / "image_error.png").exists()
    assert "## The client's policies" in report and (out / "policies.png").exists()
