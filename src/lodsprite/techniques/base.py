"""The one technique interface: :class:`Technique`, its frame record :class:`Frame` and
its live-adjustable :class:`Param`.

A technique turns a viewpoint into a frame on a renderer (a GL surface: context, size,
field of view, framebuffer, and the scene it draws).  The viewer and the batch harness
(:func:`lodsprite.harness.run_path`) drive every technique through these methods alone:

* :meth:`Technique.warm_up` — untimed work before the first timed frame, the same
  contract for every technique: afterwards its shaders are compiled and the first view's
  data resident (the harness times it apart, as ``first_frame_ms``);
* :meth:`Technique.frame` — render one frame (the harness times it, ``ctx.finish()``
  included) and say what it was (:class:`Frame`);
* :meth:`Technique.decision` — what the last frame decided (which keyframe it showed, from
  where), cheap to record inside a timed run;
* :meth:`Technique.replay` — draw a recorded decision again, untimed, to the same image
  (quality against a reference is measured in that replay, never in the timed run;
  :meth:`Technique.plan_replay` says beforehand which frames will be replayed);
* :meth:`Technique.summary` — the technique's own keys for ``summary.json``;
* :meth:`Technique.reference` and :meth:`Technique.outputs` — the batch driver's
  (:func:`lodsprite.run.drive`): the ground truth a run is judged against, and the
  technique's own columns and files after a run;
* :meth:`Technique.draw_to`, :meth:`Technique.read_image`, :meth:`Technique.params`,
  :meth:`Technique.key_view`, :meth:`Technique.coarse_level`, :meth:`Technique.status`,
  :meth:`Technique.release` — the window's side.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lodsprite.errors import InputError
from lodsprite.record import Frame

if TYPE_CHECKING:  # moderngl only under gl/ at run time
    from contextlib import AbstractContextManager

    import moderngl

    from lodsprite.camera import Projection, Viewpoint
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.terrain_gl import TerrainGL
    from lodsprite.paths import CameraPath
    from lodsprite.record import Reference, RunResult
    from lodsprite.scene import Scene

FALLBACK_TINT = (1.0, 0.0, 1.0, 0.45)


class SpriteLike(Protocol):
    """What a technique reads of a LOD-sprite renderer it drives
    (:class:`lodsprite.api.LodSprite`): a protocol, so the techniques name no facade."""

    epsilon_px: float
    engine: Any
    sprite: Any

    @property
    def keyframes(self) -> list: ...
    def frame(self, viewpoint: Viewpoint) -> Any: ...
    def read_image(self) -> np.ndarray: ...
    def key_view(self) -> tuple[Viewpoint, Projection] | None: ...
    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None: ...
    def release(self) -> None: ...


class RendererLike(Protocol):
    """What a technique reads of the renderer it is given (:class:`lodsprite.api.
    Renderer`, the only one): its scene, size and field of view, GL context, terrain
    drawer and drawing calls.  A protocol, so the techniques, which the facade's
    renderer creates, do not name it."""

    scene: Scene
    size: tuple[int, int]
    fov_y_deg: float

    @property
    def gl(self) -> GLContext: ...
    @property
    def terrain_gl(self) -> TerrainGL: ...
    def render(self, viewpoint: Viewpoint, lod: int | None = None) -> Frame: ...
    def read_color(self) -> np.ndarray: ...
    def projection(self, viewpoint: Viewpoint) -> Projection: ...
    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None: ...
    def present(self, texture: moderngl.Texture, uv: tuple[float, float, float, float],
                *args: Any, **kwargs: Any) -> None: ...
    def sprite(self, *args: Any, **kwargs: Any) -> SpriteLike: ...


@dataclass(frozen=True)
class Param:
    """A live-adjustable parameter: value, bounds and the factor one key press applies
    (``step > 1``: multiply or divide, e.g. 2 for a level, 1.25 for ε)."""

    name: str
    value: float
    lo: float
    hi: float
    step: float
    unit: str = ""
    integer: bool = False

    def stepped(self, up: bool) -> Param:
        """The parameter one key press up or down, clamped to its bounds."""
        v = self.value * self.step if up else self.value / self.step
        v = min(max(v, self.lo), self.hi)
        return replace(self, value=float(round(v)) if self.integer else v)


#: The name the viewer's frame record had; the same type now.
FrameInfo = Frame


class Technique:
    """Base of every technique (see the module docstring).  A subclass sets :attr:`name`
    and implements :meth:`frame`; the rest has defaults that suit a technique whose frame
    depends on its viewpoint alone."""

    name = "technique"
    #: How a terrain is coloured (terrain techniques set the resolved choice,
    #: ``texture`` or ``heights``); the default reference colours its terrain the same.
    shading = "auto"
    #: Whether :meth:`replay` can draw recorded frames again (False: the harness refuses
    #: quality, saved frames and video for this technique).
    replays = True
    #: Whether a run played in time (:func:`lodsprite.playback.run_played`) can judge it:
    #: False where a frame depends on the frame count, not on the viewpoint and clock
    #: (the ``scene`` technique's world advances one step a frame).
    plays_in_time = True

    def __init__(self, renderer: RendererLike) -> None:
        self.renderer = renderer

    # ------------------------------------------------------------ batch and window
    def frame(self, viewpoint: Viewpoint) -> Frame:
        raise NotImplementedError

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Untimed work before the first timed frame, the one contract of every
        technique: when it returns, every shader the first frame at ``viewpoint`` uses is
        compiled and the data that view needs is resident (streamed tiles uploaded,
        decoded nodes, a first keyframe drawn or received), so that the first timed frame
        at ``viewpoint`` compiles nothing and streams nothing in.  Never a cold start in
        one technique's timed run that another's has not.  The harness times it on its
        own (``first_frame_ms``), outside the run's figures.  Default: one frame at
        ``viewpoint``, its record dropped (right when a frame needs nothing streamed)."""
        self.frame(viewpoint)

    def decision(self) -> dict[str, Any]:
        """What the last frame decided, enough for :meth:`replay` to draw it again
        (called after each timed frame: keep it cheap, no GPU reads).  Default: nothing
        (the frame depends on its viewpoint alone)."""
        return {}

    def plan_replay(self, frames: set[int]) -> None:
        """The frames (indices along the path) the harness will replay after the timed
        run, told before it (a technique whose decisions are costly to redo may keep what
        it needs of those frames alone).  Default: nothing to do."""

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        """Draw a recorded frame again, untimed; its image ``(h, w, 3) uint8``.  Default:
        render ``viewpoint`` again (right for a technique without state)."""
        self.frame(viewpoint)
        return self.read_image()

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        """The technique's own keys for ``summary.json`` (after a run's timed frames)."""
        return {}

    def quality_extra(self, viewpoint: Viewpoint, decision: dict[str, Any],
                      truth: np.ndarray) -> dict[str, float]:
        """Extra per-frame quality columns of the replay (e.g. a baseline's RMSE against
        the same reference ``truth``); none by default."""
        return {}

    def reference(self, path: CameraPath) -> AbstractContextManager[Reference] | None:
        """The ground truth of a run along ``path``: a context manager giving
        ``viewpoint -> (h, w, 3) uint8`` from a code path independent of this technique
        (its GPU objects released on leaving).  None, the default: the scene's terrain's
        level 0 band-limited (4x4 samples a pixel, its own drawing path), coloured by
        :attr:`shading` (:func:`lodsprite.harness.scene_reference`).  A technique whose
        scene holds more than terrain gives its own (the object drawn directly, the
        full-detail scene)."""
        return None

    def outputs(self, result: RunResult, path: CameraPath) -> dict[str, Any]:
        """After a run (untimed): add the technique's own columns to ``result.rows`` (and
        their names to ``result.columns``) and return the files to write beside
        ``frames.csv``, name -> JSON data (e.g. ``keyframes.json``).  Default: none."""
        return {}

    # ------------------------------------------------------------ window
    def params(self) -> dict[str, Param]:
        """Live-adjustable parameters by name (none by default)."""
        return {}

    def set_param(self, name: str, value: float) -> None:
        raise InputError(f"{self.name} has no parameter {name!r}")

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
        """Draw the last frame over ``framebuffer``'s viewport (default: the bound one)."""
        self.renderer.draw_to(framebuffer)

    def read_image(self) -> np.ndarray:
        """The last frame, ``(h, w, 3) uint8``, row 0 at the top."""
        return self.renderer.read_color()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        """The viewpoint and projection of the keyframe shown, for the frustum overlay."""
        return None

    def coarse_level(self) -> int | None:
        """The coarse level drawn (quads per side), for the wireframe overlay."""
        return None

    def set_fallback_tint(self, on: bool) -> None:
        """Tint where a spriteframe fell back to the terrain texture (if it draws any)."""

    def status(self) -> str:
        """One line for the HUD (empty: nothing to add)."""
        return ""

    def outside_mb(self) -> float:
        """Peak memory (MB) the technique holds outside this process (a reader process's),
        added to the process's own peak in a run's ``peak_rss_mb``; 0 by default."""
        return 0.0

    def release(self) -> None:
        """Release what the technique made (never the renderer)."""


TechniqueFactory = Callable[["RendererLike"], Technique]
