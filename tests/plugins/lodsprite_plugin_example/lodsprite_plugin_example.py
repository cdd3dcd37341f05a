"""An out-of-tree technique plug-in, as a package of its own would ship it: one class, its
spec with one option line, and one entry point (``pyproject.toml`` beside this file).

``striped`` draws the full-resolution terrain and reports the ``stripes`` it was given in
a column of its own, so that a test sees the option reach the technique."""

from __future__ import annotations

from lodsprite.techniques import Frame, Option, Technique, TechniqueSpec


class Striped(Technique):
    """The full-resolution terrain; ``stripes`` goes to the ``stripes`` column."""

    name = "striped"

    def __init__(self, renderer, stripes: int = 1) -> None:
        super().__init__(renderer)
        self.stripes = stripes

    def frame(self, viewpoint) -> Frame:
        stats = self.renderer.render(viewpoint)
        return Frame("full", 0.0, int(stats.triangles), extra={"stripes": self.stripes})


SPEC = TechniqueSpec("striped", Striped,
                     (Option("stripes", int, 1, "stripes to draw", min=1, max=8),),
                     ("terrain",), "a test plug-in: the full terrain, striped")
