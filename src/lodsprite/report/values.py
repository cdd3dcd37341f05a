"""Formatting and lookup helpers shared by the report writers.

Missing or non-finite values (``None``, NaN, ``"inf"``) format as :data:`DASH`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

DASH = "—"


def num(v: Any) -> float | None:
    """``v`` as a finite float; None for None, NaN, ±inf, "inf"/"nan" strings, non-numbers."""
    if v is None or isinstance(v, bool):
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def fmt_fixed(v: Any, decimals: int) -> str:
    """Fixed-point with ``decimals``; values too small to show that way get 2 significant digits."""
    f = num(v)
    if f is None:
        return DASH
    if f != 0 and abs(f) < 10.0 ** (1 - decimals):
        return f"{f:#.2g}"
    return f"{f:.{decimals}f}"


def fmt_int(v: Any) -> str:
    f = num(v)
    return DASH if f is None else f"{f:.0f}"


def fmt_g(v: Any) -> str:
    f = num(v)
    return DASH if f is None else f"{f:g}"


def fmt_text(v: Any) -> str:
    """A free-text field (renderer, machine, path...) as one line; missing -> "—"."""
    if v is None or v == "":
        return DASH
    if isinstance(v, dict):
        return ", ".join(f"{k}: {fmt_text(x)}" for k, x in v.items())
    if isinstance(v, list | tuple):
        return ", ".join(fmt_text(x) for x in v)
    return " ".join(str(v).split())


def fmt_square(v: Any) -> str:
    """Grid size as ``512²`` (an int, or ``[n, n]``) or ``w×h``."""
    if isinstance(v, list | tuple):
        if len(v) == 2 and v[0] == v[1]:
            return f"{v[0]}²"
        return "×".join(str(x) for x in v) if v else DASH
    return DASH if v is None else f"{v}²"


def fmt_size(v: Any) -> str:
    if isinstance(v, list | tuple) and len(v) == 2:
        return f"{v[0]}×{v[1]} px"
    return fmt_text(v)


def ratio(a: Any, b: Any) -> float | None:
    fa, fb = num(a), num(b)
    return None if fa is None or not fb else fa / fb


def arr(values: Any) -> np.ndarray:
    """A list of numbers as a float array, NaN where a value is missing or not finite."""
    vals = [] if values is None else list(values)
    return np.array([np.nan if num(x) is None else float(x) for x in vals], dtype=float)


def per_frame(results: dict) -> dict:
    pf = results.get("per_frame")
    return pf if isinstance(pf, dict) else {}


def type_mask(results: dict, frame_type: str, n: int) -> np.ndarray:
    types = list(per_frame(results).get("type") or [])[:n]
    return np.array([t == frame_type for t in types] + [False] * (n - len(types)), dtype=bool)


def count_type(results: dict, frame_type: str) -> int | None:
    types = per_frame(results).get("type")
    return None if types is None else sum(t == frame_type for t in types)


def section(results: dict, key: str) -> dict | None:
    sec = results.get(key)
    return sec if isinstance(sec, dict) and sec else None
