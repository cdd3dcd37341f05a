"""A worked example: a new technique in one class and its spec (one line per option), run
through the harness like every built-in one.  In this process :func:`register` adds it; a
package of its own names ``SPEC`` by an entry point instead, and the technique is then in
``render --mode``, ``view``, scene files and ``lodsprite info``, its option ``--period`` on
the command line (docs/api/technique.md, "Writing a technique plug-in"):

    [project.entry-points."lodsprite.techniques"]
    every-other = "custom_technique:SPEC"

The technique draws every other frame at full resolution and repeats the last image in
between (a toy frame-skipper).  It records which frame each image came from, so the
harness's untimed quality replay draws the same images.

    >>> import lodsprite as ls
    >>> from lodsprite import techniques
    >>> from lodsprite.harness import run_path
    >>> spec = register()
    >>> scene = ls.load_scene("fractal:32", grid=32)
    >>> path = ls.get_path("chen1999", scene.hf, 6)
    >>> with ls.Renderer(scene, (32, 32)) as renderer:
    ...     technique = techniques.create("every-other", renderer, period=2)
    ...     result = run_path(technique, path, ground_truth=True)
    ...     technique.release()
    >>> [f.kind for f in result.frames]
    ['full', 'repeat', 'full', 'repeat', 'full', 'repeat']
    >>> result.columns[:6]
    ['frame', 'kind', 'ms', 'triangles', 'error_px', 'source']
    >>> result.rows[0]["rmse"] > 0  # one sample a pixel against the band-limited reference
    True
    >>> sorted(k for k in result.summary if k.endswith("_mean"))[:4]
    ['flicker_mean', 'psnr_mean', 'rmse_mean', 'ssim_mean']
    >>> techniques.create("every-other", renderer, period=0)
    Traceback (most recent call last):
    lodsprite.errors.InputError: option --period: got 0, allowed: >= 1
    >>> techniques.unregister("every-other")
"""

from __future__ import annotations

import numpy as np

from lodsprite.techniques import Frame, Option, Technique, TechniqueSpec
from lodsprite.techniques import register as add


class EveryOther(Technique):
    """Full resolution every ``period`` frames; the last image repeated in between."""

    name = "every-other"

    def __init__(self, renderer, period: int = 2) -> None:
        super().__init__(renderer)
        self.period, self.index, self.source = int(period), 0, 0
        self.source_vp = None  # the viewpoint of the image shown
        self._replayed: int | None = None
        self._image: np.ndarray | None = None

    def frame(self, viewpoint) -> Frame:
        kind = "repeat"
        if self.index % self.period == 0:
            self.renderer.render(viewpoint)
            self.source, self.source_vp, kind = self.index, viewpoint, "full"
        self.index += 1
        return Frame(kind, 0.0, 0, extra={"source": self.source})

    def warm_up(self, viewpoint) -> None:
        self.renderer.render(viewpoint)  # shaders compiled; the run starts at frame 0

    def decision(self) -> dict:
        """Which frame's image is shown, and its viewpoint (kept in memory, no GPU read)."""
        return {"source": self.source, "viewpoint": self.source_vp}

    def replay(self, viewpoint, decision) -> np.ndarray:
        """The image of a recorded frame: its source frame drawn again."""
        if decision["source"] != self._replayed:
            self.renderer.render(decision["viewpoint"])
            self._replayed, self._image = decision["source"], self.renderer.read_color()
        return self._image


SPEC = TechniqueSpec("every-other", EveryOther,
                    (Option("period", int, 2, "frames per full-resolution draw", min=1),),
                    ("terrain",), "a toy frame-skipper")


def register():
    """Add the example to the registry in this process and return its spec."""
    return add(SPEC, replace=True)
