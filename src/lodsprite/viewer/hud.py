"""The viewer's heads-up display: what it says (GL-free) and its text panel (Pillow).

:class:`HudState` keeps a rolling window of frame times and the last frame's facts;
:meth:`HudState.lines` turns them into the lines shown; :func:`text_panel` rasterises
lines into an RGBA image that :class:`~lodsprite.gl.overlay.HudLayer` draws.  The panel
is remade at most ``PANEL_HZ`` times a second, so text costs nothing on most frames.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from PIL import Image, ImageDraw, ImageFont

GRAPH_FRAMES = 240
PANEL_HZ = 4.0


@dataclass
class HudState:
    """What the HUD shows: mode, frame facts, a rolling window of frame times (ms)."""

    renderer: str = ""
    mode: str = ""
    params: str = ""
    toggles: str = ""
    status: str = ""
    frame_type: str = ""
    error_px: float = math.nan
    keyframes: int = 0
    triangles: int = 0
    frame_ms: deque = field(default_factory=lambda: deque(maxlen=GRAPH_FRAMES))
    interval_ms: deque = field(default_factory=lambda: deque(maxlen=GRAPH_FRAMES))

    def record(self, frame_ms: float, interval_ms: float) -> None:
        """Add one frame's time (its own work) and the interval since the previous one."""
        self.frame_ms.append(frame_ms)
        if interval_ms > 0:
            self.interval_ms.append(interval_ms)

    @property
    def fps(self) -> float:
        """Frames per second over the rolling window (0 before two frames)."""
        if not self.interval_ms:
            return 0.0
        return 1e3 / float(np.mean(self.interval_ms))

    def lines(self) -> list[str]:
        """The HUD's text, one string per line."""
        ms = np.asarray(self.frame_ms, dtype=np.float64)
        med = float(np.median(ms)) if len(ms) else math.nan
        p99 = float(np.percentile(ms, 99)) if len(ms) else math.nan
        err = "-" if math.isnan(self.error_px) else f"{self.error_px:.2f} px"
        out = [f"{self.fps:6.1f} fps   frame {med:.2f} ms median, {p99:.2f} ms p99",
               f"mode {self.mode}  {self.params}".rstrip(),
               f"frame {self.frame_type}   error {err}   keyframes {self.keyframes}",
               f"triangles {self.triangles:,}",
               f"GL {self.renderer}"]
        if self.toggles:
            out.append(self.toggles)
        if self.status:
            out.append(self.status)
        return out


def text_panel(lines: list[str], scale: int = 1) -> np.ndarray:
    """``lines`` as white text on a translucent dark panel, ``(h, w, 4) uint8``, row 0 at
    the top; ``scale`` enlarges it for HiDPI framebuffers."""
    font = ImageFont.load_default(size=13 * scale)
    pad, step = 6 * scale, 16 * scale
    width = max((int(font.getlength(s)) for s in lines), default=0) + 2 * pad
    height = step * len(lines) + 2 * pad
    img = Image.new("RGBA", (max(width, 1), height), (10, 14, 20, 170))
    draw = ImageDraw.Draw(img)
    for i, s in enumerate(lines):
        draw.text((pad, pad + i * step), s, fill=(235, 240, 245, 255), font=font)
    return np.asarray(img)
