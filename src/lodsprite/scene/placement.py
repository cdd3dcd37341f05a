"""Where a scene's instances stand: seeded scatter, points files, groups, the ground.

World coordinates are the terrain's (:mod:`lodsprite.terrain.heightfield`): metres, ``+x``
east, ``+y`` north, the terrain's centre at the origin, so its extent is
``[-width/2, width/2] x [-depth/2, depth/2]``.  The ground under ``(x, y)`` is the bilinear
interpolation of the scene's working height field between its four nearest samples
(:meth:`~lodsprite.terrain.heightfield.HeightField.height_at`; sample ``(r, c)`` lies at
``x = c dx - width/2``, ``y = depth/2 - r dy``), so an instance stands exactly on the
triangulated surface the full-resolution mesh draws.

* :func:`scatter` - ``count`` anchors uniform over the extent (inset by the group's
  radius), with uniform headings, from ``numpy.random.default_rng(seed)``: the same seed
  gives the same scene.
* :func:`read_points` - a points file: one ``x,y`` (world metres) or ``x,y,yaw_deg`` (the
  heading, degrees counter-clockwise from east; seeded when absent) a line; blank lines,
  ``#`` comments and an ``x,y`` header skipped; at most
  :data:`~lodsprite.scene.file.MAX_POINTS_ROWS` rows.
* :func:`expand` - every member of a group at every anchor, turned by the anchor's heading.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lodsprite.errors import SceneFileError
from lodsprite.scene.file import MAX_POINTS_ROWS
from lodsprite.scene.objects import Group
from lodsprite.terrain.heightfield import HeightField


def extent(hf: HeightField) -> tuple[np.ndarray, np.ndarray]:
    """The terrain's horizontal extent: ``lo (2,)``, ``hi (2,)`` float64 world metres."""
    return (np.array([-hf.width / 2, -hf.depth / 2]), np.array([hf.width / 2, hf.depth / 2]))


def ground(hf: HeightField, xy: np.ndarray) -> np.ndarray:
    """Ground heights ``(k,) float64`` metres under world points ``xy (k, 2)`` (bilinear)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return np.asarray(hf.height_at(xy[:, 0], xy[:, 1]), dtype=np.float64)


def scatter(count: int, seed: int, lo: np.ndarray, hi: np.ndarray,
            inset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``count`` anchors ``xy (count, 2)`` uniform in ``[lo + inset, hi - inset]`` and
    headings ``(count,)`` uniform in ``[-pi, pi)`` radians, reproducible by ``seed``."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(lo + inset, hi - inset, size=(count, 2))
    return xy, rng.uniform(-np.pi, np.pi, size=count)


def headings(count: int, seed: int) -> np.ndarray:
    """``count`` headings for anchors that come with no heading (a points file)."""
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, size=count)


def read_points(path: str | Path, field: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A points file's ``xy (k, 2) float64`` metres, headings ``(k,) float64`` radians (NaN
    where a row gives none) and the line number of each row ``(k,)``.  Raises
    :class:`SceneFileError` naming ``field`` (and the line) for anything malformed."""
    p = Path(path)
    rows, lines = [], []
    with p.open(encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            cells = text.split(",")
            try:
                if len(cells) not in (2, 3):
                    raise ValueError
                rows.append((float(cells[0]), float(cells[1]),
                             np.radians(float(cells[2])) if len(cells) == 3 else np.nan))
            except ValueError:
                if not rows and number == 1 and cells[0].strip().lower() == "x":
                    continue  # an "x,y" header
                raise SceneFileError(f"{field}: {p.name} line {number}: expected x,y or "
                                     f"x,y,yaw_deg (numbers), got {text[:40]!r}") from None
            lines.append(number)
            if len(rows) > MAX_POINTS_ROWS:
                raise SceneFileError(f"{field}: {p.name} has more than {MAX_POINTS_ROWS} rows")
    if not rows:
        raise SceneFileError(f"{field}: {p.name} holds no points")
    table = np.asarray(rows, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(table[:, :2]).all(axis=1) | np.isinf(table[:, 2]))
    if len(bad):
        raise SceneFileError(f"{field}: {p.name} line {lines[bad[0]]}: not finite")
    return table[:, :2], table[:, 2], np.asarray(lines)


def check_inside(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray, field: str,
                 where: list[str] | None = None, region: str = "the terrain") -> None:
    """Raise :class:`SceneFileError` naming ``field`` (and ``where[i]`` of the first point
    out, e.g. its line) when a point of ``xy (k, 2)`` lies outside ``[lo, hi]``
    (``region``, as the message calls it)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    tol = 1e-9 * float(np.max(hi - lo))
    out = np.flatnonzero(((xy < lo - tol) | (xy > hi + tol)).any(axis=1))
    if len(out):
        i = int(out[0])
        at = f"{where[i]}: " if where is not None else ""
        raise SceneFileError(
            f"{field}: {at}({xy[i, 0]:g}, {xy[i, 1]:g}) is outside {region} "
            f"(x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g} m)")


def expand(group: Group, anchors: np.ndarray, yaws: np.ndarray
           ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """For each type of ``group``: ``(xy (k, 2), yaw (k,), anchor (k,))`` of its members at
    every anchor ``anchors (a, 2)`` turned by ``yaws (a,)`` (members in anchor order)."""
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    out = []
    for t in range(len(group.types)):
        members = np.flatnonzero(group.member_type == t)
        off = group.offsets[members]                      # (m, 2)
        x = anchors[:, :1] + c * off[None, :, 0] - s * off[None, :, 1]
        y = anchors[:, 1:] + s * off[None, :, 0] + c * off[None, :, 1]
        yaw = np.angle(np.exp(1j * (yaws[:, None] + group.yaws[members][None, :])))
        index = np.repeat(np.arange(len(anchors)), len(members))
        out.append((np.stack([x.ravel(), y.ravel()], axis=1), yaw.ravel(), index))
    return out


def group_radius(group: Group) -> float:
    """How far a group's members stand from its anchor (metres; 0 for one mesh)."""
    return float(np.linalg.norm(group.offsets, axis=1).max()) if len(group.offsets) else 0.0
