"""One timed run of ``reproduce large`` in a process of its own, through the library.

``python -m lodsprite.experiments.large.child OUT_DIR CONFIG_JSON`` renders
``RenderConfig(**CONFIG_JSON)`` with :func:`lodsprite.run.render_path` into ``OUT_DIR``
(``frames.csv``, ``summary.json``, PNG frames with ``save_frames``).  A process per run
gives each run its own peak resident memory and time to first frame.  A user error
exits with code 2 and its message as the one line on stderr.

``CONFIG_JSON`` ``{"probe": "scene", "terrain": STORE}`` measures instead what loading
the scene of a store (the in-memory working grid ``render`` makes of it) adds to the
process's peak resident memory (:func:`scene_probe`).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def render_in_child(config: dict, out: Path) -> dict:
    """Run :func:`lodsprite.run.render_path` on ``RenderConfig(**config)`` in a fresh
    Python process writing to ``out``; return its summary (``summary.json``).  ``config``
    holds JSON values (``size`` as ``[w, h]``).  Raises RuntimeError with the child's
    error when it fails."""
    cmd = [sys.executable, "-m", "lodsprite.experiments.large.child", str(out),
           json.dumps(config)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"render {json.dumps(config)} failed: {r.stderr.strip()}")
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


def run(out: Path, config: dict) -> dict:
    """The child's work: one :func:`~lodsprite.run.render_path` run; returns its summary."""
    from lodsprite.run import RenderConfig, render_path

    if config.get("probe") == "scene":
        return scene_probe(out, config["terrain"])
    kw = dict(config)
    if "size" in kw:
        kw["size"] = tuple(kw["size"])
    return render_path(RenderConfig(**kw), Path(out))


def main(argv: list[str]) -> int:
    from lodsprite.errors import LodspriteError

    try:
        run(Path(argv[0]), json.loads(argv[1]))
    except LodspriteError as exc:
        sys.stderr.write(f"{exc}\n")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
