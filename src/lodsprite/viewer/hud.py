"""The viewer's heads-up display: what it says, and how its text is laid out (GL-free).

:class:`HudState` keeps a rolling window of frame times and the last frame's facts;
:meth:`HudState.lines` turns them into the lines shown.  Text is drawn from a glyph atlas
(:func:`glyph_atlas`, rasterised once with Pillow): :func:`layout_text` turns lines into
one textured quad per character, a few hundred vertices that
:class:`~lodsprite.gl.overlay.HudLayer` draws in one call.  Rasterising the panel with
Pillow each time cost 4 ms, a spike every refresh; the layout costs a tenth of that.  The
text is laid out again at most ``PANEL_HZ`` times a second.
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
    cursor: str = ""       # the point under the cursor, in the dataset's CRS
    attribution: str = ""  # the imagery's licence and attribution line
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
        ms = np.fromiter(self.frame_ms, np.float64, len(self.frame_ms))
        med, p99 = (float(v) for v in np.quantile(ms, (0.5, 0.99))) if len(ms) else (
            math.nan, math.nan)
        err = "-" if math.isnan(self.error_px) else f"{self.error_px:.2f} px"
        out = [f"{self.fps:6.1f} fps   frame {med:.2f} ms median, {p99:.2f} ms p99",
               f"mode {self.mode}  {self.params}".rstrip(),
               f"frame {self.frame_type}   error {err}   keyframes {self.keyframes}",
               f"triangles {self.triangles:,}",
               f"GL {self.renderer}"]
        if self.cursor:
            out.append(self.cursor)
        if self.attribution:
            out.append(f"imagery {self.attribution}"[:120])
        if self.toggles:
            out.append(self.toggles)
        if self.status:
            out.append(self.status)
        return out


FIRST_GLYPH, LAST_GLYPH = 32, 126   # printable ASCII; anything else shows as "?"
ATLAS_COLUMNS = 16


@dataclass(frozen=True)
class GlyphAtlas:
    """Glyphs of one font in a grid: ``alpha (H, W) uint8`` (row 0 at the top), cell size
    ``(w, h)`` pixels, ``advance (95,) float32`` pixels per glyph from ``FIRST_GLYPH``;
    the last cell (index 95) is solid, for panel backgrounds."""

    alpha: np.ndarray
    cell: tuple[int, int]
    advance: np.ndarray


def glyph_atlas(size_px: int = 13) -> GlyphAtlas:
    """Rasterise printable ASCII with Pillow's default font at ``size_px`` pixels."""
    font = ImageFont.load_default(size=size_px)
    chars = [chr(c) for c in range(FIRST_GLYPH, LAST_GLYPH + 1)]
    advance = np.array([font.getlength(c) for c in chars], dtype=np.float32)
    cw, ch = int(np.ceil(advance.max())) + 2, int(size_px * 1.3) + 2
    rows = -(-(len(chars) + 1) // ATLAS_COLUMNS)
    img = Image.new("L", (cw * ATLAS_COLUMNS, ch * rows), 0)
    draw = ImageDraw.Draw(img)
    for i, c in enumerate(chars):
        draw.text(((i % ATLAS_COLUMNS) * cw + 1, (i // ATLAS_COLUMNS) * ch + 1), c, fill=255,
                  font=font)
    solid = len(chars)
    x, y = (solid % ATLAS_COLUMNS) * cw, (solid // ATLAS_COLUMNS) * ch
    draw.rectangle((x, y, x + cw - 1, y + ch - 1), fill=255)
    return GlyphAtlas(np.asarray(img), (cw, ch), advance)


def _quads(x0, y0, x1, y1, u0, v0, u1, v1) -> np.ndarray:
    """Two triangles per rectangle: ``(n*6, 4)`` vertices ``x, y, u, v``."""
    corners = [(x0, y0, u0, v0), (x1, y0, u1, v0), (x0, y1, u0, v1),
               (x1, y0, u1, v0), (x1, y1, u1, v1), (x0, y1, u0, v1)]
    return np.stack([np.stack(c, axis=-1) for c in corners], axis=1).reshape(-1, 4)


def layout_text(lines: list[str], atlas: GlyphAtlas, origin: tuple[float, float] = (0, 0),
                pad: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Quads for ``lines`` from ``origin`` (pixels from the top-left of the window):
    ``(background (6, 4), glyphs (n*6, 4)) float32`` vertices ``x, y`` (pixels, y down)
    and ``u, v`` (atlas texture coordinates, v down; the background samples the solid
    cell)."""
    cw, ch = atlas.cell
    aw, ah = cw * ATLAS_COLUMNS, atlas.alpha.shape[0]
    codes, xs, ys = [], [], []
    width = 0.0
    for row, text in enumerate(lines):
        c = np.frombuffer(text.encode("ascii", "replace"), np.uint8).astype(np.intp)
        c = np.where((c < FIRST_GLYPH) | (c > LAST_GLYPH), ord("?"), c) - FIRST_GLYPH
        adv = atlas.advance[c]
        width = max(width, float(adv.sum()))
        xs.append(np.concatenate([[0.0], np.cumsum(adv)[:-1]]))
        ys.append(np.full(len(c), row * ch, np.float32))
        codes.append(c)
    c = np.concatenate(codes) if codes else np.zeros(0, np.intp)
    x = origin[0] + pad + (np.concatenate(xs) if xs else np.zeros(0))
    y = origin[1] + pad + (np.concatenate(ys) if ys else np.zeros(0))
    u0, v0 = (c % ATLAS_COLUMNS) * cw / aw, (c // ATLAS_COLUMNS) * ch / ah
    glyphs = _quads(x, y, x + cw, y + ch, u0, v0, u0 + cw / aw, v0 + ch / ah)
    solid = LAST_GLYPH - FIRST_GLYPH + 1
    su, sv = (solid % ATLAS_COLUMNS + 0.5) * cw / aw, (solid // ATLAS_COLUMNS + 0.5) * ch / ah
    bg = _quads(*(np.array([v], np.float64) for v in (
        origin[0], origin[1], origin[0] + width + 2 * pad, origin[1] + len(lines) * ch
        + 2 * pad, su, sv, su, sv)))
    return bg.astype(np.float32), glyphs.astype(np.float32)
