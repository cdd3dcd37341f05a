"""Shared fixtures.  As in moderngl's own test suite: one standalone context for the
whole session, a GL error check after every test that used it, and GL state reset
between tests."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

# llvmpipe rasterizes on the drawing thread (a user's setting wins).  The suite runs two
# xdist workers on two cores; llvmpipe's own rasterizer threads (one per core in each
# process) would oversubscribe them: tests/gl, tests/sprite and tests/terrain took 70.8 s
# with them and 62.4 s without (one run each, idle 2-core machine).  Draws still release
# the GIL where the project draws unlocked: the tests of that hold either way.
os.environ.setdefault("LP_NUM_THREADS", "0")
# Bytecode caches kept (an environment may forbid them, PYTHONDONTWRITEBYTECODE=1): else
# every xdist worker rewrites every test module's asserts again (collection 19.6 s against
# 10.9 s with the cache) and every process the tests start (renderers, readers, the CLI)
# compiles lodsprite from source again.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from lodsprite.terrain.heightfield import HeightField  # noqa: E402


def needs(*modules: str, reason: str) -> pytest.MarkDecorator:
    """A skip mark for a module whose tests need ``modules`` not installed, checked by
    name only (``importlib.util.find_spec``): ``pytest.importorskip`` at a module's top
    imports them while collecting, on every xdist worker (jupyterlab and nbclient cost
    3 s of each worker's collection); the tests import them where they run."""
    from importlib.util import find_spec

    def absent(name: str) -> bool:
        try:
            return find_spec(name) is None
        except ModuleNotFoundError:  # a dotted name whose parent is missing
            return True

    return pytest.mark.skipif(any(absent(m) for m in modules), reason=reason)


#: The files that take longest (their tests' setup, call and teardown summed from
#: ``--durations=0`` of the whole suite under ``-n 2 --dist loadfile``, 2026-12-05: every
#: file of 4 s or more, longest first), collected first so that the two xdist workers
#: (``--dist loadfile``) start on them and end together, the short files filling in
#: last (longest processing time first); only the order changes, and within a file none.
HEAVY_FIRST = (
    "tests/distributed/pool/test_ray_pool.py",
    "tests/distributed/web/test_browser.py",
    "tests/distributed/test_reproduce_swan2002.py",
    "tests/distributed/test_end_to_end.py",
    "tests/viewer/test_window.py",
    "tests/distributed/pool/test_pool.py",
    "tests/notebook/test_jupyterlab.py",
    "tests/terrain/test_storefield_nonblocking.py",
    "tests/distributed/test_client.py",
    "tests/notebook/test_example_notebook.py",
    "tests/test_reproduce_large.py",
    "tests/test_cli.py",
    "tests/test_reproduce_timecritical.py",
    "tests/test_readme.py",
    "tests/distributed/test_fuzz.py",
    "tests/terrain/test_pyramid_store.py",
    "tests/terrain/test_imagery.py",
    "tests/terrain/test_remote.py",
    "tests/distributed/test_long_renders.py",
    "tests/test_harness.py",
    "tests/distributed/web/test_web_server.py",
    "tests/test_reproduce_battlefield.py",
    "tests/test_layering.py",
    "tests/terrain/test_adaptive.py",
    "tests/gl/test_terrain_render.py",
    "tests/sprite/test_worker_engine.py",
    "tests/test_same_images.py",
    "tests/distributed/web/test_web_shutdown.py",
    "tests/techniques/test_worker_store.py",
    "tests/techniques/test_worker_store_tiles.py",
    "tests/notebook/test_kernel.py",
    "tests/test_warm_up.py",
    "tests/manager/test_crowd_cli.py",
    "tests/lumigraph/test_sloan1997.py",
    "tests/test_honest_reference.py",
    "tests/profiles/test_generate.py",
    "tests/distributed/test_server.py",
    "tests/test_driver.py",
    "tests/profiles/test_reproduce_scoggins.py",
    "tests/sprite/test_metric.py",
    "tests/gl/test_sprite_tiles.py",
    "tests/scene/test_scene_reuse.py",
    "tests/scene/test_layered.py",
)
_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config: pytest.Config) -> None:
    """Keep :data:`HEAVY_FIRST`'s order under ``--dist loadfile``: pytest-xdist otherwise
    hands out the files by their number of tests, most first (``--loadscope-reorder``, on
    by default), which sent the one-test files last, the swan2002 reproduction (the
    longest file) and test_honest_reference among them, so that one worker ran them alone
    at the end while the other had finished."""
    if getattr(config.option, "loadscopereorder", False):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The :data:`HEAVY_FIRST` files first (longest processing time first), every other
    file after them in its collected order; a stable sort, so no file's own order moves."""
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}

    def key(item: pytest.Item) -> int:
        try:
            name = item.path.resolve().relative_to(_ROOT).as_posix()
        except ValueError:
            return len(rank)
        return rank.get(name, len(rank))

    items.sort(key=key)


@pytest.fixture(scope="session")
def gl_session():
    from lodsprite.gl.context import GLContext

    ctx = GLContext()
    yield ctx
    ctx.release()


@pytest.fixture
def gl(gl_session):
    """The session's GL context; fails the test if it leaves a GL error behind."""
    import moderngl

    mgl = gl_session.mgl
    # Make the session's context current: tests of other components (the distributed
    # client) create contexts of their own on this thread.
    with mgl:
        _ = mgl.error  # clear any stale flag
        yield gl_session
        gl_session.check_error("test")
        mgl.disable(moderngl.DEPTH_TEST | moderngl.BLEND | moderngl.CULL_FACE)
        gl_session.default_fbo.use()


T = TypeVar("T")


def imported_by(code: str, modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh Python process has imported after running ``code``
    (sorted); fails the test if the process fails."""
    import subprocess
    import sys

    probe = f"{code}\nimport sys\nprint(','.join(m for m in {modules!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return sorted(m for m in out.stdout.strip().split(",") if m)


def wait_until(pred: Callable[[], T], timeout_s: float, what: str,
               interval_s: float = 0.01) -> T:
    """Call ``pred`` until it returns something truthy, and return that; fail the test
    with "``what`` did not happen within ``timeout_s`` s" once the deadline passes.  The
    deadline only guards against a hang: it is never a measure of speed.  ``pred`` is
    called at least once, and once more at the deadline."""
    deadline = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() >= deadline:
            got = pred()
            if got:
                return got
            pytest.fail(f"{what} did not happen within {timeout_s:g} s", pytrace=False)
        time.sleep(interval_s)


def gone(pid: int) -> bool:
    """The process ``pid`` is not running (absent, or a zombie waiting to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] in ("Z", "X")
    except OSError:
        return True


@pytest.fixture
def cli(capsys):
    """``cli(*args)`` runs ``lodsprite ARGS`` in this process, as the console script does
    (``lodsprite.cli.main``), and returns a :class:`subprocess.CompletedProcess` with its
    exit code and what it printed.  For the CLI's refusals, which happen before any work:
    a process of its own costs ~2 s of start-up each (tests that need a real process, or
    a real run, keep one)."""
    import subprocess

    from lodsprite.cli import main

    def run(*args: str) -> subprocess.CompletedProcess:
        capsys.readouterr()
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(["lodsprite", *args], code, out, err)

    return run


def run_cli(*args: str, cwd=None):
    """``lodsprite ARGS`` run in this process (``lodsprite.cli.main``, stdout and stderr
    captured), as a :class:`subprocess.CompletedProcess`: a real run without a process's
    ~2 s of start-up.  ``cwd``: the folder to run in."""
    import contextlib
    import io
    import subprocess

    from lodsprite.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        if cwd is not None:
            stack.enter_context(contextlib.chdir(cwd))
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        try:
            main([str(a) for a in args])
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return subprocess.CompletedProcess(["lodsprite", *args], code, out.getvalue(),
                                       err.getvalue())


def make_field(n: int = 64, relief: float = 200.0, spacing: float = 30.0,
               kind: str = "bump") -> HeightField:
    """Synthetic working field of ``(n+1)^2`` samples: flat, a central bump, or ridges."""
    r, c = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1), indexing="ij")
    if kind == "flat":
        h = np.zeros_like(r)
    elif kind == "bump":
        h = relief * np.exp(-(r**2 + c**2) / 0.1)
    elif kind == "ridges":
        h = relief * (0.5 + 0.5 * np.sin(9 * np.pi * c) * np.cos(7 * np.pi * r))
    else:
        raise ValueError(kind)
    return HeightField(h.astype(np.float32), spacing, spacing, kind)


@pytest.fixture
def bump_field() -> HeightField:
    return make_field()


@pytest.fixture(scope="session")
def store512(tmp_path_factory) -> str:
    """A small terrain store (a 512² fractal, built once): its level 0 is more than the
    roots, so a view's tiles stream in after its first frame."""
    from lodsprite.terrain.store import build_store

    out = tmp_path_factory.mktemp("store") / "f512.zarr"
    build_store("fractal:512:1", out)
    return str(out)
