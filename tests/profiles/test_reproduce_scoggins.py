"""The scoggins2000 reproduction end to end on tiny settings, and the profile command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from lodsprite import experiments
from lodsprite.cli import main
from lodsprite.experiments.scoggins2000.report import write_outputs
from lodsprite.experiments.scoggins2000.run import ScogginsConfig, reproduce_scoggins2000
from lodsprite.profiles.generate import ProfileSettings
from lodsprite.profiles.table import ProfileTable

KEYS = ("profile_s_sphere", "profile_s_mountain", "snowflake_triangles_full",
        "snowflake_triangles_far_csf", "snowflake_triangles_far_nocsf", "triangles",
        "rmse_profile", "rmse_sse", "flip_profile", "flip_sse", "ssim_profile", "ssim_sse")


@pytest.fixture(scope="module")
def results():
    cfg = ScogginsConfig.quick(
        size=128, profile=ProfileSettings(image_size=64, phi_step_deg=180.0,
                                          theta_step_deg=90.0),
        sphere_levels=5, sphere_max_faces=3000, flakes=3, sweep_frames=6, compare_frames=2,
        workers=1)
    return reproduce_scoggins2000(cfg)


def test_results_have_the_issue_keys(results, tmp_path):
    report, plots = write_outputs(results, tmp_path)
    data = json.loads((tmp_path / "results.json").read_text())
    for key in KEYS:
        assert key in data and data[key] is not None, key
    assert data["snowflake_triangles_full"] == 10 * data["sphere"]["faces"][-1]
    # Farther flakes never need more triangles (the profile's errors fall with distance).
    assert np.all(np.diff(data["spiral"]["triangles_csf"]) <= 0)
    # Equal-triangle comparison: screen-space selection never over the profile's budget.
    for c in data["comparison"].values():
        assert c["triangles_sse"] <= c["triangles_profile"] <= c["triangles_full"]
    assert {p.name for p in plots} >= {"fig05_snowflake_triangles.png",
                                       "fig06a_mean_error.png", "fig07_spiral.png",
                                       "fig06b_mountain_triangles.png", "fig08_mountain.png"}
    assert "17 min" in report.read_text()
    table = ProfileTable.load(tmp_path / "profile_mountain.npz")
    assert table.levels == 8


def test_the_summary_table_gives_the_paper_beside_the_run(results):
    table = experiments.get("scoggins2000").summary(results)
    rows = {row[0]: row for row in table.rows}
    assert rows["profile s, mountain"] == ("profile s, mountain",
                                           f"{results['profile_s_mountain']:.1f}", "6000")
    assert rows["sphereflake triangles, full"][2] == "9,451,008"


def test_profile_command_on_a_mesh_file(tmp_path, capsys):
    mesh = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "ball.ply"
    mesh.export(path)
    out = tmp_path / "ball.npz"
    with pytest.raises(SystemExit) as exc:
        main(["profile", str(path), "--faces", "80,320", "--image", "64", "--phi-step", "180",
              "--theta-step", "90", "--workers", "1", "--out", str(out)])
    assert exc.value.code == 0
    t = ProfileTable.load(out)
    assert list(t.faces) == [80, 320, 1280] and np.all(t.error[-1] == 0)


@pytest.mark.parametrize("content", [b"", b"garbage \x00\x01 not a mesh", b"v 0 0 0\nv 1 0 0\n"])
def test_profile_command_rejects_bad_meshes(tmp_path, capsys, content):
    path = tmp_path / "bad.obj"
    path.write_bytes(content)
    out = tmp_path / "t.npz"
    with pytest.raises(SystemExit) as exc:
        main(["profile", str(path), "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lodsprite: error:") and len(err.splitlines()) == 1
    assert not out.exists()


def test_profile_command_refuses_a_folder_as_output_before_working(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["profile", "sphere", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "is a folder" in capsys.readouterr().err


@pytest.mark.parametrize("size", [0, -5, 100_000])
def test_reproduction_rejects_impossible_image_sizes(size):
    from lodsprite.errors import InputError

    with pytest.raises(InputError, match="image size"):
        ScogginsConfig(size=size)
