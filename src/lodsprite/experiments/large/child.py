"""One timed run of ``reproduce large`` in a process of its own, through the library.

:func:`render_in_child` renders ``RenderConfig(**config)`` with
:func:`lodsprite.run.render_path` into ``out`` (``frames.csv``, ``summary.json``, PNG
frames with ``save_frames``) in a fresh process (:func:`lodsprite.procs.call_in_child`:
multiprocessing's spawn, a new interpreter), so that each run has its own peak resident
memory and time to first frame.  A user error comes back as itself (an
:class:`~lodsprite.errors.InputError`); a process that dies without an answer (the
out-of-memory killer) as :class:`~lodsprite.procs.WorkerDied`.

``config`` ``{"probe": "scene", "terrain": STORE}`` measures instead what loading the
scene of a store (the in-memory working grid ``render`` makes of it) adds to the
process's peak resident memory (:func:`scene_probe`).
"""

from __future__ import annotations

import json
from pathlib import Path


def render_in_child(config: dict, out: Path) -> dict:
    """Run :func:`lodsprite.run.render_path` on ``RenderConfig(**config)`` in a fresh
    Python process writing to ``out``; return its summary (``summary.json``).  ``config``
    holds JSON values (``size`` as ``[w, h]``).  Raises the child's error (a
    :class:`~lodsprite.procs.WorkerError`, which is a RuntimeError, when it died or its
    error could not travel)."""
    from lodsprite.procs import call_in_child

    call_in_child(run, Path(out), dict(config), name="lodsprite-large-run")
    return json.loads((Path(out) / "summary.json").read_text())


def scene_probe(out: Path, terrain: str) -> dict:
    """Peak resident memory (MB) of this process before and after
    :func:`lodsprite.load_scene` of ``terrain``, after the library's imports: what the
    in-memory working grid costs a run that never draws it (``summary.json``)."""
    import lodsprite.run  # noqa: F401 - the imports every run has
    from lodsprite import load_scene
    from lodsprite.files import write_json
    from lodsprite.workers import peak_rss_mb

    before = peak_rss_mb()
    scene = load_scene(terrain, light=True)  # what a timed run over a store loads
    s = {"peak_rss_mb_imports": before, "peak_rss_mb_scene": peak_rss_mb(),
         "grid": scene.hf.quads}
    s["scene_load_mb"] = s["peak_rss_mb_scene"] - before
    write_json(Path(out) / "summary.json", s)
    return s


def run(out: Path, config: dict) -> None:
    """The child's work: one :func:`~lodsprite.run.render_path` run (its summary written
    to ``out``)."""
    from lodsprite.run import RenderConfig, render_path

    if config.get("probe") == "scene":
        scene_probe(out, config["terrain"])
        return
    kw = dict(config)
    if "size" in kw:
        kw["size"] = tuple(kw["size"])
    render_path(RenderConfig(**kw), Path(out))
