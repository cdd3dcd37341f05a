"""Layering and the lean install (issue 12, items 9 and 10; issue 21, must-have 6; issue 31,
must-have 5: string imports count).

* The layers, read from the source (AST, :mod:`importgraph`), lazy imports counted: no
  module or package cycle; moderngl only under gl/ (elsewhere hints under
  ``TYPE_CHECKING``); gl/ knows no technique package; terrain/ knows neither gl/ nor the
  packages above it; only the command line (and the swan2002 reproduction of the
  distributed paper) reaches into the distributed layer, and nothing outside that layer
  loads it, nor Dask, when imported.
* Nothing of the core pulls Dask in when imported, not even through a third-party
  package (checked by importing each module in a fresh interpreter).
* The engine renders what the GL-free keyframe policy decides.
* Dask is the ``cluster`` extra: ``--scheduler`` without it is one line naming the extra.
"""

from __future__ import annotations

import functools
import json
import pkgutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

import importgraph
import lodsprite
from conftest import make_field
from lodsprite.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
DISTRIBUTED = "lodsprite.distributed"
#: The swan2002 reproduction drives the distributed layer: a front end of it, like cli/.
SWAN2002 = "lodsprite.experiments.swan2002"
SWAN_RUN = f"{SWAN2002}.run"
#: The notebook widgets are the web page's client in a cell: a front end of the distributed
#: layer (its hub, sessions and renderer pool), loaded only by ``lodsprite.widget``.
NOTEBOOK = "lodsprite.notebook"
DASK = ("dask", "distributed")  # the cluster extra's top-level names


# --- the layers, read from the source (AST): lazy imports count ---------------------------
# Every import statement anywhere in a module (inside functions too) is an edge; only those
# under ``if TYPE_CHECKING:`` never run and count for no cycle.

@functools.cache
def package_edges() -> list[importgraph.Import]:
    """The package's import edges, read once, when the first test asks (not while the
    suite collects, which every xdist worker does for every file)."""
    return importgraph.imports()

#: Packages of techniques, experiments and front ends: gl/ draws for them and knows none.
ABOVE_GL = {"sprite", "lumigraph", "manager", "profiles", "distributed", "adaptive", "viewer",
            "notebook",
            "cli", "experiments", "api", "run", "harness", "techniques", "technique", "scene",
            "report", "layered"}


def runtime_edges(source_unit: str | None = None):
    return [e for e in package_edges() if not e.type_only and e.target.startswith("lodsprite")
            and (source_unit is None or importgraph.unit(e.source) == source_unit)]


def describe(edges) -> list[str]:
    return sorted(f"{e.source}:{e.line} -> {e.target}{' (lazy)' if e.lazy else ''}"
                  for e in edges)


def test_no_module_imports_itself_round_a_cycle():
    """Type hints count: an import under ``TYPE_CHECKING`` is an edge as any other (a
    technique hints the renderer it is given by a protocol, not by the facade)."""
    assert importgraph.strongly_connected(importgraph.import_graph(package_edges())) == []


def test_no_package_imports_itself_round_a_cycle():
    graph = importgraph.import_graph(package_edges(), packages=True)
    assert importgraph.strongly_connected(graph) == []


def test_moderngl_is_imported_only_under_gl():
    bad = [e for e in package_edges() if e.target == "moderngl" and not e.type_only
           and importgraph.unit(e.source) != "gl"]
    assert describe(bad) == []


def test_gl_imports_no_technique_package():
    bad = [e for e in runtime_edges("gl") if importgraph.unit(e.target) in ABOVE_GL]
    assert describe(bad) == []


def test_terrain_imports_neither_gl_nor_the_front_ends():
    bad = [e for e in runtime_edges("terrain") if importgraph.unit(e.target) in ABOVE_GL | {"gl"}]
    assert describe(bad) == []


def test_the_scene_model_imports_no_rendering():
    """scene/ (the data model) reaches nothing of gl/ or moderngl, directly or through the
    modules it imports (runtime edges, lazy ones included)."""
    graph = importgraph.runtime_graph(package_edges())
    seen, todo = set(), [m for m in graph if importgraph.unit(m) == "scene"]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph.get(m, ()))
    assert sorted(m for m in seen if importgraph.unit(m) == "gl") == []
    assert not any(e.target == "moderngl" and e.source in seen and not e.type_only
                   for e in package_edges())


#: The shared helpers every level uses (atomic writers, mesh loading, the cluster extra's
#: check, worker processes): the bottom of the package, importing nothing of it but errors
#: (and the process lifecycle, which workers build on).
BASE = ("lodsprite.files", "lodsprite.meshes", "lodsprite.cluster", "lodsprite.workers",
        "lodsprite.procs", "lodsprite.errors")


def test_the_shared_helpers_sit_at_the_bottom():
    bad = [e for e in runtime_edges() if e.source in BASE
           and e.target not in ("lodsprite.errors", "lodsprite.procs")]
    assert describe(bad) == []
    assert {e.source for e in package_edges() if e.target in BASE} >= {
        "lodsprite.terrain.store", "lodsprite.profiles.generate", "lodsprite.harness",
        "lodsprite.manager.builtins", "lodsprite.lumigraph.store"}


def in_distributed_layer(module: str) -> bool:
    return module.startswith((DISTRIBUTED, SWAN_RUN, NOTEBOOK))


def test_only_the_command_line_reaches_into_the_distributed_layer():
    bad = [e for e in runtime_edges() if importgraph.unit(e.target) == "distributed"
           and importgraph.unit(e.source) not in ("distributed", "cli", "notebook")
           and not e.source.startswith(SWAN2002)]
    assert describe(bad) == []


def test_the_core_loads_neither_the_distributed_layer_nor_dask_when_imported():
    """Outside the distributed layer, the distributed layer and Dask are imported only
    inside functions (the command that needs them): importing any other module, and so
    every module its top level imports, loads neither."""
    bad = [e for e in package_edges() if not e.lazy and not e.type_only
           and not in_distributed_layer(e.source)
           and (in_distributed_layer(e.target) or e.target in DASK)]
    assert describe(bad) == []
    assert any(e.target == "dask" and e.lazy for e in package_edges())  # the rule sees them


def test_the_import_graph_sees_lazy_imports(tmp_path):
    """The analysis itself: a planted lazy import inside a function closes a cycle."""
    pkg = tmp_path / "src" / "lodsprite"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("_LAZY = {'Thing': 'lodsprite.a'}\n")
    (pkg / "a.py").write_text("from lodsprite.sub import b\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import moderngl\n"
        "def later():\n    from lodsprite import Thing\n    return Thing\n")
    edges = importgraph.imports(tmp_path / "src")
    assert importgraph.strongly_connected(importgraph.runtime_graph(edges)) == [
        ["lodsprite.a", "lodsprite.sub.b"]]
    assert importgraph.strongly_connected(importgraph.runtime_graph(edges, packages=True)) == [
        ["a", "sub"]]
    (lazy,) = [e for e in edges if e.source == "lodsprite.sub.b" and e.target == "lodsprite.a"]
    assert lazy.lazy and not lazy.type_only
    (hint,) = [e for e in edges if e.target == "moderngl"]
    assert hint.type_only


# --- importing: what third-party packages pull in -----------------------------------------

def core_modules() -> list[str]:
    """Every module of the package outside :mod:`lodsprite.distributed`, found on disk
    (without importing anything)."""
    found = []

    def walk(path: list[str], prefix: str) -> None:
        for info in pkgutil.iter_modules(path, prefix):
            if in_distributed_layer(info.name) or info.name.endswith(".__main__"):
                continue
            found.append(info.name)
            if info.ispkg:
                walk([str(Path(path[0]) / info.name.rpartition(".")[2])], info.name + ".")

    walk(list(lodsprite.__path__), "lodsprite.")
    return sorted(found)


CHECK = """
import importlib, json, sys
forbidden = tuple(sys.argv[2].split(","))
bad = {}
for name in sys.argv[1].split(","):
    importlib.import_module(name)
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in forbidden)
    if loaded:
        bad[name] = loaded
        break  # what came in stays in: later modules would be blamed for it
print(json.dumps(bad))
"""


def test_no_core_module_pulls_dask_in_when_imported():
    """The AST rule above sees lodsprite's own imports; this sees what third-party packages
    (zarr, numcodecs, ...) import in turn."""
    modules = core_modules()
    for name in ("lodsprite.run", "lodsprite.sprite.engine", "lodsprite.sprite.policy",
                 "lodsprite.gl.terrain_gl", "lodsprite.experiments.chen1999.report",
                 "lodsprite.experiments.swan2002.report", "lodsprite.profiles.generate",
                 "lodsprite.cli", "lodsprite.progress"):
        assert name in modules
    proc = subprocess.run([sys.executable, "-c", CHECK, ",".join(modules), ",".join(DASK)],
                          capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {}


def test_the_policy_module_needs_no_gl():
    code = ("import sys, lodsprite.sprite.policy; "
            "print(sorted(m for m in sys.modules if m.startswith(('moderngl', 'lodsprite.gl'))))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_the_engine_renders_what_the_policy_decides(gl):
    """The GL driver and a policy built from pure camera math alone agree frame by frame:
    the same frame types, keyframes at the same viewpoints (ahead of the viewer too)."""
    from lodsprite.camera import look_at
    from lodsprite.gl.sprite import SpriteDrawer
    from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
    from lodsprite.sprite.engine import LodSpriteEngine
    from lodsprite.sprite.policy import KeyframePolicy
    from lodsprite.terrain import make_texture

    hf = make_field(64, kind="ridges", relief=150.0)
    geometry = TerrainGeometry(gl, hf, make_texture("terrain", hf))
    renderer = TerrainDrawer(gl, geometry, 64, 64)
    sprite = SpriteDrawer(renderer, 8, guard_px=4)
    try:
        path = [look_at((2600 * np.sin(a), -2600 * np.cos(a), 1300.0), (0.0, 0.0, 0.0))
                for a in np.linspace(0.0, np.pi / 2, 40)]
        engine = LodSpriteEngine(sprite, 0.05)
        frames = [engine.frame(vp) for vp in path]
        policy = KeyframePolicy.for_terrain(hf, 8, 0.05, (64, 64), guard_px=4)
        decisions = [policy.decide(vp) for vp in path]
        assert [f.type for f in frames] == [d.type for d in decisions]
        keys = [d.key.viewpoint.o for d in decisions if d.key is not None]
        assert len(engine.keyframes) == len(keys) > 3
        for key, o in zip(engine.keyframes, keys, strict=True):
            np.testing.assert_allclose(key.viewpoint.o, o)
        assert engine.predicted_keyframes == policy.predicted_keyframes > 0
        assert [f.error_px for f in frames] == pytest.approx([d.error_px for d in decisions])
    finally:
        sprite.release()
        renderer.release()
        geometry.release()


# --- the cluster extra -----------------------------------------------------------------------

def without_dask(monkeypatch) -> None:
    """Make ``import dask.distributed`` fail as it does where the extra is not installed."""
    for name in ("distributed", "dask.distributed"):
        monkeypatch.setitem(sys.modules, name, None)


def test_require_dask_names_the_extra_when_dask_is_missing(monkeypatch):
    from lodsprite.cluster import require_dask

    without_dask(monkeypatch)
    with pytest.raises(InputError, match=r"lodsprite\[cluster\]") as exc:
        require_dask()
    assert "\n" not in str(exc.value)


def test_a_scheduler_without_dask_fails_before_any_work(monkeypatch):
    from lodsprite.profiles.generate import generate_profile

    without_dask(monkeypatch)
    # No chain at all: the check comes first.
    with pytest.raises(InputError, match=r"--scheduler.*lodsprite\[cluster\]"):
        generate_profile(None, scheduler="tcp://127.0.0.1:9")


def test_profile_scheduler_without_dask_is_one_line_and_exit_2(tmp_path):
    code = ("import sys; sys.modules['distributed'] = sys.modules['dask.distributed'] = None; "
            "from lodsprite.cli import main; main()")
    out = tmp_path / "t.npz"
    proc = subprocess.run([sys.executable, "-c", code, "profile", "sphere", "--scheduler",
                           "tcp://127.0.0.1:9", "--out", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "lodsprite[cluster]" in lines[0], proc.stderr
    assert not out.exists()


def test_dask_is_an_extra_that_the_test_install_pulls_in():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not any(d.startswith(("dask", "distributed")) for d in project["dependencies"])
    extras = project["optional-dependencies"]
    assert any(d.startswith("dask[distributed]") for d in extras["cluster"])
    assert "lodsprite[cluster]" in extras["test"]


# --- the ray extra ---------------------------------------------------------------------------

RAY_MODULES = ("lodsprite.distributed.pool.ray_pool", "lodsprite.distributed.pool.ray_actor")


def test_ray_is_imported_lazily_and_only_by_the_ray_pool():
    """``import ray`` sits inside functions of the Ray pool and its actor, nowhere else."""
    edges = [e for e in package_edges() if e.target.split(".")[0] == "ray"]
    assert edges, "the rule sees the Ray pool's imports"
    assert describe([e for e in edges if not e.lazy or e.source not in RAY_MODULES]) == []


def test_the_distributed_layer_and_the_local_web_pool_load_no_ray():
    """Importing every module of the distributed layer (the Ray pool's too) and making the
    web server's embedded pool loads nothing of Ray: only ``--ray`` does."""
    names = sorted(m.name for m in pkgutil.walk_packages(
        [str(ROOT / "src" / "lodsprite" / "distributed")], f"{DISTRIBUTED}.")
        if not m.name.endswith("__main__"))
    assert set(RAY_MODULES) <= set(names)
    code = textwrap.dedent("""
        import importlib, sys
        for name in sys.argv[1].split(","):
            importlib.import_module(name)
        from lodsprite.distributed.web.server import WebConfig, make_pool
        make_pool(WebConfig(renderers=1)).close()
        print(sorted(m for m in sys.modules if m.split(".")[0] == "ray"))
    """)
    proc = subprocess.run([sys.executable, "-c", code, ",".join(names)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"


def test_serve_web_runs_without_ray_and_stops_cleanly():
    """Ray made unimportable (as where the extra is not installed): ``serve --web`` starts
    its local renderers, prints the page's URL and exits 0 on SIGTERM."""
    import queue
    import signal
    import threading

    from lodsprite.distributed.run import free_ports

    code = "import sys; sys.modules['ray'] = None; from lodsprite.cli import main; main()"
    proc = subprocess.Popen([sys.executable, "-c", code, "serve", "--bind",
                             f"127.0.0.1:{free_ports()}", "--web", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        line = lines.get(timeout=60)  # printed once serving ("" if it exited first)
        assert line.startswith("web page: http://127.0.0.1:"), line
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err


def test_serve_ray_without_ray_is_one_line_and_exit_2():
    code = "import sys; sys.modules['ray'] = None; from lodsprite.cli import main; main()"
    proc = subprocess.run([sys.executable, "-c", code, "serve", "--web", "0", "--ray", "auto"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "lodsprite[ray]" in lines[0], proc.stderr


def test_ray_is_an_extra_that_the_test_install_pulls_in():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not any(d.startswith("ray") for d in project["dependencies"])
    extras = project["optional-dependencies"]
    assert any(d.startswith("ray") for d in extras["ray"])
    assert "lodsprite[ray]" in extras["test"]


# --- the command line picks the distributed mode ---------------------------------------------

def lodsprite_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()",
                           *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(("args", "fragment"), [
    (["--mode", "warp"], "distributed"),
    (["--mode", "distributed", "--pace", "sometimes"], "--pace"),
    (["--mode", "distributed", "--max-error", "wide"], "--max-error"),
    (["--mode", "distributed", "--epsilon", "0"], "epsilon"),
])
def test_render_mode_errors_name_the_distributed_mode(tmp_path, cli, args, fragment):
    out = tmp_path / "never"   # (in this process: refused before any work)
    proc = cli("render", "--terrain", "fractal:64:1", "--size", "64x64", *args,
               "--out", str(out))
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and fragment in lines[0], proc.stderr
    assert not out.exists()


def test_render_config_has_no_distributed_fields():
    from dataclasses import fields

    from lodsprite.run import MODES, RenderConfig

    assert "distributed" not in MODES
    assert "pace" not in {f.name for f in fields(RenderConfig)}
    with pytest.raises(InputError, match="mode"):
        RenderConfig(mode="distributed").validate()


def test_test_module_names_are_unique():
    """The test folders have no ``__init__.py``: two test files with one basename make
    pytest refuse to collect the second (as tests/lumigraph/test_cli.py once did)."""
    names = [p.name for p in (ROOT / "tests").rglob("test_*.py")]
    assert sorted(n for n in set(names) if names.count(n) > 1) == []


def test_the_import_graph_sees_string_imports(tmp_path):
    """A module found by its dotted name in a string (a factory, an opener) is an edge:
    planted, such a string closes a cycle that no import statement shows."""
    pkg = tmp_path / "src" / "lodsprite"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("import lodsprite.b\n")
    (pkg / "b.py").write_text("OPENERS = ['lodsprite.a:open']\nNAME = f'lodsprite.b:{1}'\n")
    edges = importgraph.imports(tmp_path / "src")
    assert importgraph.strongly_connected(importgraph.runtime_graph(edges)) == [
        ["lodsprite.a", "lodsprite.b"]]
    (hidden,) = [e for e in edges if e.string]
    assert (hidden.source, hidden.target, hidden.lazy) == ("lodsprite.b", "lodsprite.a", True)


def test_the_distributed_layer_imports_no_batch_module():
    """The distributed layer starts from what a run renders (:mod:`lodsprite.runconfig`),
    never from the batch driver (:mod:`lodsprite.run`), which the command line and the
    experiments drive."""
    bad = [e for e in runtime_edges("distributed") if e.target == "lodsprite.run"]
    assert describe(bad) == []


def test_only_the_lazy_widget_entry_reaches_the_notebook_front_end():
    """``import lodsprite`` must not pull in the notebook widgets (and through them the
    distributed layer, anywidget and jupyter_rfb): every edge into them from outside is lazy."""
    inward = [e for e in runtime_edges() if e.target.startswith(NOTEBOOK)
              and not e.source.startswith(NOTEBOOK)]
    assert describe([e for e in inward if not e.lazy]) == []
    assert any(e.source == "lodsprite" for e in inward)  # the rule sees lodsprite.widget
