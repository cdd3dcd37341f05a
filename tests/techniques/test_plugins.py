"""Techniques are plug-ins: an out-of-tree package (tests/plugins/lodsprite_plugin_example)
installed into a folder as pip lays a distribution out (its module and a ``*.dist-info``
with ``entry_points.txt``) appears in ``render --mode``, ``render``/``view --help`` with its
option as ``--OPTION``, scene files and ``lodsprite info``; its option reaches the
technique; a broken plug-in is one warning line.  The built-in specs are the entry points
``pyproject.toml`` declares, so the two cannot drift apart."""

import csv
import json
import os
import shutil
import subprocess
import sys
import textwrap
import tomllib
from importlib import import_module
from pathlib import Path

import pytest

from lodsprite.errors import InputError
from lodsprite.techniques import GROUP, Option, TechniqueSpec

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "tests" / "plugins" / "lodsprite_plugin_example"


def install(site: Path, name: str, module: Path | None, entry_points: dict[str, str]) -> None:
    """``name`` installed into ``site``: ``module`` copied, a dist-info naming
    ``entry_points`` in the group."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    lines = "".join(f"{k} = {v}\n" for k, v in entry_points.items())
    (info / "entry_points.txt").write_text(f"[{GROUP}]\n{lines}")
    if module is not None:
        shutil.copy(module, site)


SCRIPT = textwrap.dedent("""
    import contextlib, io, json, sys
    from lodsprite.cli import main

    def call(*args):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main(list(args))
                code = 0
            except SystemExit as exc:
                code = exc.code
        return [code, out.getvalue(), err.getvalue()]

    print(json.dumps([call(*a) for a in json.loads(sys.argv[1])]))
""")


def test_an_installed_plugin_is_a_technique_of_every_front_end(tmp_path):
    site = tmp_path / "site"
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())
    install(site, project["project"]["name"], PLUGIN / "lodsprite_plugin_example.py",
            project["project"]["entry-points"][GROUP])
    install(site, "lodsprite-broken", None, {"broken": "lodsprite_plugin_missing:SPEC"})
    good = tmp_path / "good.toml"
    good.write_text('[terrain]\nsource = "fractal:32:2"\nmode = "striped"\n'
                    '[terrain.options]\nstripes = 2\n[view]\npath = "flyover"\n')
    bad = tmp_path / "bad.toml"
    bad.write_text('[terrain]\nsource = "fractal:32:2"\nmode = "striped"\n'
                   '[terrain.options]\nstripes = 12\n')
    small = ["--terrain", "fractal:32:2", "--size", "32x32", "--frames", "2"]
    calls = [["render", "--help"], ["view", "--help"], ["info"],
             ["render", *small, "--mode", "striped", "--stripes", "3",
              "--out", str(tmp_path / "run")],
             ["render", *small, "--mode", "striped", "--stripes", "9",
              "--out", str(tmp_path / "never")],
             ["scene", "check", str(good)], ["scene", "check", str(bad)],
             ["render", "--scene", str(good), "--size", "32x32", "--frames", "2",
              "--out", str(tmp_path / "scene")]]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(site), *filter(None, [os.environ.get("PYTHONPATH")])]), "COLUMNS": "200"}
    proc = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(calls)], env=env,
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    # the broken plug-in: one warning line, and everything else works
    warnings = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(warnings) == 1 and "broken" in warnings[0] and "left out" in warnings[0]
    r_help, v_help, info, run, refused, checked, bad_file, scene = json.loads(proc.stdout)
    assert r_help[0] == 0 and "--stripes" in r_help[1]
    assert v_help[0] == 0 and "--stripes" in v_help[1]
    assert info[0] == 0 and "striped" in info[1] and "--stripes" in info[1]
    assert run[0] == 0, run[2]
    rows = list(csv.DictReader((tmp_path / "run" / "frames.csv").open()))
    assert [r["stripes"] for r in rows] == ["3", "3"]  # the option reached the technique
    assert refused[0] == 2 and not (tmp_path / "never").exists()
    lines = [ln for ln in refused[2].splitlines() if ln.strip()]
    assert len(lines) == 1 and "--stripes" in lines[0] and "1..8" in lines[0]
    assert checked[0] == 0, checked[2]
    lines = [ln for ln in bad_file[2].splitlines() if ln.strip()]
    assert bad_file[0] == 2 and len(lines) == 1 and "terrain.options.stripes" in lines[0]
    assert scene[0] == 0, scene[2]
    summary = json.loads((tmp_path / "scene" / "summary.json").read_text())
    assert summary["terrain_mode"] == "striped"  # the file's [terrain] mode drew it


def test_the_built_in_specs_are_the_entry_points_pyproject_declares():
    from lodsprite import techniques

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())[
        "project"]["entry-points"][GROUP]
    modules = set()
    for name, value in declared.items():
        module, _, attr = value.partition(":")
        spec = getattr(import_module(module), attr)
        assert isinstance(spec, TechniqueSpec) and spec.name == name
        assert callable(spec.factory)  # the class or a function, never a dotted string
        modules.add(module)
    named = {v.partition(":")[2] for v in declared.values()}
    for module in modules:  # no spec in a spec module without its entry point
        specs = {k for k, v in vars(import_module(module)).items()
                 if isinstance(v, TechniqueSpec)}
        assert specs <= named, specs - named
    # the installed metadata is pyproject's (stale after a change: pip install -e .)
    assert set(declared) <= set(techniques.names())


def test_an_option_parses_and_checks_with_one_line_naming_it_and_its_range():
    o = Option("tile_budget_ms", float, 8.0, "tile work per frame", min=0, unit="ms")
    assert o.parse("2.5") == 2.5 and o.check(3) == 3.0 and o.cli == "--tile-budget-ms"
    with pytest.raises(InputError, match=r"option --tile-budget-ms: got -1\.0, allowed: >= 0 ms"):
        o.parse("-1")
    with pytest.raises(InputError, match="got 'x'"):
        o.parse("x")
    with pytest.raises(InputError, match="got nan"):
        o.check(float("nan"))
    c = Option("policy", str, "lru", choices=("lru", "benefit"))
    with pytest.raises(InputError, match="allowed: lru | benefit"):
        c.parse("fifo")
    b = Option("border", bool, True)
    assert b.parse("off") is False and b.parse("yes") is True
    with pytest.raises(InputError, match="border"):
        b.check(1)
    n = Option("key_sse", float, None, min=0, above=True)
    assert n.check(None) is None and n.parse("none") is None
    with pytest.raises(InputError, match="> 0"):
        n.check(0.0)


def test_the_python_api_checks_options_through_the_same_declarations():
    from lodsprite import techniques

    with pytest.raises(InputError, match="option --epsilon: got -1.0"):
        techniques.create("sprite", renderer=None, epsilon=-1.0)
    with pytest.raises(InputError, match="takes no option"):
        techniques.create("sprite", renderer=None, no_such=1)


def test_the_command_line_imports_no_gl():
    code = ("import sys; from lodsprite.cli import app; import typer.main as m; "
            "m.get_command(app); print('moderngl' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "False", proc.stderr
