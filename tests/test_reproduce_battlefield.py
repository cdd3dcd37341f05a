"""``reproduce battlefield`` (issue 23, must-have 5): results.json's keys, the pooled
figures being the runs' own, the profile/linear match, the extraction counts of the crowd
engine with and without the manager, the report and plots, and the options."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lodsprite.experiments.base import Options

RUN_KEYS = {"target_ms", "median_ms", "p99_ms", "std_ms", "rmse", "flip"}
PVL_KEYS = {"rmse_profile", "rmse_linear", "flip_profile", "flip_linear",
            "triangles_profile", "triangles_linear"}


@pytest.fixture(scope="module")
def battlefield(tmp_path_factory):
    from lodsprite.experiments.battlefield.report import write_outputs
    from lodsprite.experiments.battlefield.run import BattlefieldConfig, reproduce_battlefield

    out = tmp_path_factory.mktemp("battlefield")
    cfg = BattlefieldConfig.quick(paths=("weave",), instances=60, trees=0, frames=6,
                                  sample_every=3, match_steps=2)
    with pytest.MonkeyPatch.context() as mp:  # the built-ins' profiles: built here
        mp.setenv("LODSPRITE_CACHE", str(tmp_path_factory.mktemp("profiles")))
        r = reproduce_battlefield(cfg, out)
    report = write_outputs(r, out)
    return out, json.loads((out / "results.json").read_text()), report


def test_results_hold_the_issues_keys_and_the_runs_own_figures(battlefield):
    out, r, _ = battlefield
    for name in ("scheduler", "reuse", "independent"):
        assert RUN_KEYS <= set(r[name]), name
        run = r["paths"]["weave"][name]
        ms = np.array(run["columns"]["ms"])
        assert len(ms) == 6 and r[name]["frames"] == 6
        # the harness's frame clock encloses the layers' own clocks (two code paths):
        # every frame, and so the median and p99, at least the sum of its layers' ms
        layers = _layer_ms(run["columns"])
        assert (ms >= layers - 1e-6).all(), (ms, layers)
        assert r[name]["median_ms"] >= np.median(layers) - 1e-6
        assert r[name]["p99_ms"] >= np.percentile(layers, 99) - 1e-6
        fps = r["config"]["reuse_fps" if name == "reuse" else "target_fps"]
        assert r[name]["target_ms"] == pytest.approx(1e3 / fps)
        assert run["quality_frames"] == 2  # frames 0 and 3 against the full-detail scene
        # the reduced-detail run scores worse than the full-detail scene does against the
        # same reference (which scores it as the same image: see the test below)
        assert r[name]["rmse"] > FULL_DETAIL_RMSE and r[name]["flip"] > 0
        # the flicker of frame 1 against frame 0 (the reported half), and of 4 against 3
        assert run["flicker"] is not None and run["flicker_chosen"] is not None
        assert run["flicker"] >= 0 and r[name]["flicker"] >= 0
        for layer in ("terrain", "objects", "lightfields"):  # every layer drew every frame
            assert len(run["columns"][f"ms_{layer}"]) == 6
    assert PVL_KEYS <= set(r["profile_vs_linear"])
    assert r["sample_frames"] == [0, 3] and r["instances"] == 60
    assert r["chosen_frames"] == [3] and r["reported_frames"] == [0]
    assert len(r["lightfields"]) == 2 and (out / "battlefield.toml").is_file()
    assert r["terrain"]["tiled"] and (out / "stores").is_dir()


def _layer_ms(columns: dict) -> np.ndarray:
    """The per-frame sum of the layers' own times ``(frames,)`` float64 ms."""
    return np.sum([columns[f"ms_{la}"] for la in ("terrain", "objects", "lightfields")], 0)


#: grey levels: the full-detail scene at one sample a pixel against its band-limited
#: reference stays under this (its aliasing; measured 3.09 and 2.21 on the two sampled
#: frames at 128², deterministic); every reduced-detail run scores above it (4.7 and more)
FULL_DETAIL_RMSE = 3.5


def test_the_reference_scores_the_full_detail_scene_as_the_same_image(battlefield, tmp_path,
                                                                       monkeypatch):
    """The battlefield's reference (rendered once per path, matched to each sampled
    frame's viewpoint and time, band-limited) against the full-detail technique run along
    the same path at one sample a pixel: every sampled frame off by its aliasing only."""
    from lodsprite.api import Renderer
    from lodsprite.experiments.battlefield.run import BattlefieldConfig, PathRuns
    from lodsprite.harness import run_path
    from lodsprite.layered.technique import LayeredTechnique
    from lodsprite.scene.world import load_scene_file

    out, r, _ = battlefield
    cfg = BattlefieldConfig(**{**r["config"], "paths": tuple(r["config"]["paths"])})
    monkeypatch.setenv("LODSPRITE_CACHE", str(tmp_path))  # built here if needed
    world = load_scene_file(out / "battlefield.toml")
    cam = world.path("weave", cfg.frames)
    with Renderer(world, (cfg.image, cfg.image), cam.fov_y_deg) as renderer:
        images = PathRuns(renderer, world, cam, cfg).images
        t = LayeredTechnique(renderer, world, ground_truth=True)
        try:
            result = run_path(t, cam, ground_truth=True, quality_stride=cfg.sample_every,
                              flip=True, reference=lambda vp: images[id(vp)])
        finally:
            t.release()
    q = [row for row in result.rows if "rmse" in row]
    assert [row["frame"] for row in q] == r["sample_frames"]
    assert all(0 < row["rmse"] < FULL_DETAIL_RMSE and row["flip"] < 0.03 for row in q), q


def test_extractions_are_the_crowd_engines_with_and_without_sharing(battlefield):
    _, r, _ = battlefield
    p = r["paths"]["weave"]
    assert r["extractions_with_manager"] == sum(p["manager"]["columns"]["extractions"])
    assert r["extractions_without_manager"] == sum(p["no_manager"]["columns"]["extractions"])
    # every object extracting its own LODs does more of them than objects sharing them
    assert r["extractions_without_manager"] > r["extractions_with_manager"] >= 0


def test_the_linear_run_kept_is_the_closest_to_the_profile_runs_triangles(battlefield):
    _, r, _ = battlefield
    x = r["paths"]["weave"]["profile_vs_linear"]
    # matched on the chosen frame (3), the objects' triangles (the same terrain)
    goal = x["profile"]["triangles_objects_chosen"]
    assert goal == x["profile"]["columns"]["triangles_objects"][1]  # sampled run: 0, 3
    best = min(abs(t - goal) for t in x["triangles_tried"])
    assert abs(x["linear"]["triangles_objects_chosen"] - goal) == pytest.approx(best)
    # and reported on the other frame (0): its quality and triangles, not frame 3's
    for side in ("profile", "linear"):
        col = x[side]["columns"]
        assert x[side]["rmse"] == pytest.approx(col["rmse"][0])
        assert x[side]["rmse_chosen"] == pytest.approx(col["rmse"][1])
        assert x[side]["triangles_objects_reported"] == col["triangles_objects"][0]
    # the sampled runs draw the reference's full-resolution terrain: the same in both
    prof, lin = x["profile"]["columns"], x["linear"]["columns"]
    assert prof["triangles_terrain"] == lin["triangles_terrain"]
    assert x["linear_exponent"] in x["exponents_tried"]
    assert r["profile_vs_linear"]["triangles_profile_chosen"] == pytest.approx(goal)
    # the profile run drew with the profile LOD hook, the linear runs without it
    assert x["profile"]["profile_lod"] and not x["linear"]["profile_lod"]
    assert r["profile_vs_linear"]["profile_lod_available"]


def test_report_names_the_measured_figures_beside_the_targets(battlefield):
    out, r, report = battlefield
    text = report.read_text()
    assert f"{r['scheduler']['median_ms']:.1f}" in text
    assert f"{r['independent']['p99_ms']:.1f}" in text
    assert "target within 5 %" in text and "at most 1.25×" in text
    assert f"{r['extractions_without_manager']:,}" in text
    assert (out / "frame_times.png").stat().st_size > 0
    assert (out / "profile_vs_linear.png").stat().st_size > 0
    # issue 32: reuse beside the scheduler, with the frontier plot of the three runs
    assert "## Reused static layers" in text and f"{r['reuse']['median_ms']:.1f}" in text
    assert "| flicker |" in text and f"flicker {r['reuse']['flicker']:.2f}" in text
    assert (out / "frontier_0.png").stat().st_size > 0 and "frontier_0.png" in text
    assert r["paths"]["weave"]["reuse"]["keyframes_rendered"] >= 1


def test_next_exponent_coarsens_when_there_are_too_many_triangles():
    from lodsprite.experiments.battlefield.run import MATCH_KEY, _next_exponent

    assert _next_exponent([(1.0, {MATCH_KEY: 2000.0})], 1000.0) > 1.0
    assert _next_exponent([(1.0, {MATCH_KEY: 500.0})], 1000.0) < 1.0
    # a secant on log triangles: exact when triangles fall as exp(-e)
    tried = [(e, {MATCH_KEY: 1e5 * np.exp(-e)}) for e in (1.0, 2.0)]
    assert _next_exponent(tried, 1e5 * np.exp(-1.5)) == pytest.approx(1.5)


def test_options_choose_the_terrain_and_size_only_when_given():
    from lodsprite.experiments import get

    exp = get("battlefield")
    cfg = exp.configure(Options(quick=True))
    assert cfg.terrain == "fractal:256:1" and cfg.image == 64
    cfg = exp.configure(Options(terrain="jacksboro", terrain_given=True, size=96,
                                size_given=True))
    assert cfg.terrain == "jacksboro" and cfg.image == 96 and cfg.instances == 3000


def test_every_run_reports_its_warm_up_apart_and_the_real_config_samples_twenty_frames(
        battlefield):
    from lodsprite.experiments.base import MIN_QUALITY_FRAMES
    from lodsprite.experiments.battlefield.run import BattlefieldConfig

    out, r, report = battlefield
    p = r["paths"]["weave"]
    for name in ("scheduler", "independent", "manager", "no_manager"):
        assert p[name]["first_frame_ms"] > 0, name
    assert "first frame ms (warm-up)" in report.read_text()
    cfg = BattlefieldConfig()
    assert len(cfg.sample_frames) >= MIN_QUALITY_FRAMES
    assert sorted(cfg.chosen_frames + cfg.reported_frames) == cfg.sample_frames
