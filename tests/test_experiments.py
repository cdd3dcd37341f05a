"""The experiments' registry: one lookup a reproduction, each with its default output
folder, its options, and the table the command line prints."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lodsprite import experiments
from lodsprite.errors import InputError
from lodsprite.experiments import Experiment, Options, Summary


def test_every_reproduction_is_registered_under_its_name():
    assert experiments.names() == ("chen1999", "swan2002", "scoggins2000", "sloan1997",
                                   "gumbau", "large", "battlefield", "timecritical")
    for name in experiments.names():
        e = experiments.get(name)
        assert e.name == name and e.default_out == Path("out") / name


def test_an_unknown_name_is_one_input_error_naming_the_available_ones():
    with pytest.raises(InputError, match="nobody2000.*chen1999, swan2002") as exc:
        experiments.get("nobody2000")
    assert "\n" not in str(exc.value)


def test_looking_up_swan2002_does_not_load_the_distributed_layer():
    code = ("import sys; from lodsprite import experiments; experiments.get('swan2002'); "
            "print(sorted(m for m in sys.modules if m.startswith('lodsprite.distributed')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_options_become_each_experiments_config():
    chen = experiments.get("chen1999").configure(Options(quick=True, lod=8, epsilon=0.5))
    assert (chen.size, chen.frames, chen.lod, chen.epsilon) == (256, 115, 8, 0.5)
    assert experiments.get("chen1999").configure(Options(size=384)).size == 384
    large = experiments.get("large").configure(Options(terrain="dem.tif", huge=True))
    assert large.terrains == ("dem.tif",) and large.huge
    assert experiments.get("large").configure(Options()).terrains == ()
    with pytest.raises(InputError, match="epsilon"):
        experiments.get("swan2002").configure(Options(epsilon=0.0))
    swan = experiments.get("swan2002").configure
    assert swan(Options(quick=True)).size == 256  # --quick's own size unless --size given
    assert swan(Options(quick=True, size=64, size_given=True)).size == 64


def test_reproduce_runs_into_the_default_folder_and_attaches_the_report(tmp_path,
                                                                         monkeypatch):
    seen = {}

    def run(cfg, out_dir, progress):
        seen["out"], seen["cfg"] = out_dir, cfg
        progress("step", 1, 1)
        return {"x": 2}, out_dir / "report.md"

    e = Experiment("toy", "a toy", lambda o: o.size, run,
                   lambda r: Summary("toy", ("", "x"), [("x", str(r["x"]))]))
    monkeypatch.chdir(tmp_path)
    steps = []
    results, s = e.reproduce(Options(size=64), progress=lambda *a: steps.append(a))
    assert seen == {"out": Path("out/toy"), "cfg": 64} and steps == [("step", 1, 1)]
    assert results == {"x": 2} and s.rows == [("x", "2")]
    assert s.report == Path("out/toy/report.md")


def test_the_large_table_has_a_row_a_store_and_path_in_size_order():
    ad = {"median_ms": 2.0, "rmse": 3.0, "peak_rss_mb": 300.0, "first_frame_s": 0.5,
          "first_frame_ms": 412.3}
    v = {"chen1999": {"adaptive": ad, "whole": [{"median_ms": 1.0, "rmse": 4.0}]}}
    best = {"best": {"speedup": 2.5, "variant": "whole", "epsilon": 0.5}}
    ee = {"chen1999": best}
    r = {"sizes": {"2048": v, "512": v}, "terrains": {"dem.tif": v},
         "equal_error_speedup": {"2048": ee, "512": ee, "dem.tif": {"chen1999": {"best": None}}},
         "frontier_speedup": {"512": {"chen1999": {"1px": 3.2, "2px": None, "4px": 1.1}}}}
    s = experiments.get("large").summary(r)
    assert [row[0] for row in s.rows] == ["512", "2048", "dem.tif"]
    assert s.rows[0][1:] == ("chen1999", "2.0", "1.0", "3.00 / 4.00", "300", "412", "0.50",
                             "2.50× (whole ε 0.5)", "3.20× / — / 1.10×")
    assert s.rows[2][-2:] == ("none", "— / — / —")  # no frontier run: no speedup


def test_the_demo_is_chen1999_on_the_papers_set_up_without_the_epsilon_sweeps():
    from lodsprite.experiments.chen1999 import DEMO, EXPERIMENT

    demo, full = DEMO.configure(Options()), EXPERIMENT.configure(Options())
    paper = ("jacksboro", 512, 460, 16, 1.0)
    assert (demo.terrain, demo.size, demo.frames, demo.lod, demo.epsilon) == paper
    assert (full.terrain, full.size, full.frames, full.lod, full.epsilon) == paper
    assert demo.fig11_epsilon == () and len(full.fig11_epsilon) == 5
    assert demo.sweeps and demo.fig10_frames[-1] == demo.frames  # Fig. 10 up to the path
    assert DEMO.run is EXPERIMENT.run and DEMO.summary is EXPERIMENT.summary
    quick = DEMO.configure(Options(quick=True))
    assert (quick.size, quick.frames, quick.fig11_epsilon) == (256, 115, ())


def test_demo_writes_figs_8_to_10_and_13_14_and_a_report_without_the_sweeps(
        tmp_path, cli, monkeypatch):
    from lodsprite.experiments.chen1999.run import ReproduceConfig

    # The command in this process, its demo set-up shrunk for the suite.
    demo = ReproduceConfig.demo
    monkeypatch.setattr(ReproduceConfig, "demo", classmethod(lambda cls, **kw: demo(
        **{**kw, "terrain": "fractal:64:1", "size": 64, "frames": 60,
           "fig10_frames": (30, 60), "full_sample": 46, "quality_stride": 4})))
    out = tmp_path / "d"
    proc = cli("demo", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    r = json.loads((out / "results.json").read_text())
    assert "fig11" not in r and "fig12" not in r
    # Fig. 10's point at the path's length is the main run itself.
    assert r["fig10"]["frames"] == [30, 60] and r["fig10"]["keyframes"][-1] == r["keyframes"]
    assert r["full_sample_frames"] == 46 and r["quality_frames"] == 15
    for png in ("fig08_error.png", "fig09_time.png", "fig10_keyframes_vs_frames.png",
                "fig13.png", "fig14.png"):
        assert (out / png).stat().st_size > 1000
    report = (out / "report.md").read_text()
    assert "Not produced in this run (no data): Fig. 11, Fig. 12." in report
    assert "speedup" in proc.stdout and "RMSE ratio" in proc.stdout
