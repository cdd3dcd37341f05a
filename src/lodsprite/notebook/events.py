"""The streaming widget's input events from the page, checked before anything uses them.

jupyter_rfb's front end sends pointer, wheel, key and resize events as plain JSON; the
page is untrusted (any script in it, or a hand-made comm message, can send anything).
:func:`check_event` accepts an event only when each field jupyter_rfb or the widget
reads is of its type and in range; :func:`number` and :func:`key` read one field.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["MAX_COORD", "MAX_KEYS", "check_event", "key", "number"]

MAX_KEYS = 8
"""Keys held at once; a key down beyond them is dropped."""
MAX_COORD = 1e6
"""Largest magnitude of an event's coordinate, size (pixels) or wheel step accepted."""
MAX_TIME = 1e12
"""Largest event timestamp accepted (seconds)."""
NUMBERS = ("x", "y", "dx", "dy", "width", "height", "pwidth", "pheight", "ratio",
           "pixel_ratio", "button")
"""The numeric fields jupyter_rfb's events carry."""


def number(event: dict, name: str, default: float = 0.0, limit: float = MAX_COORD) -> float:
    """``event[name]`` as a finite float within +-``limit``; ValueError otherwise."""
    value = event.get(name, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} is not a number")
    value = float(value)
    if not math.isfinite(value) or abs(value) > limit:
        raise ValueError(f"{name} out of range")
    return value


def key(event: dict) -> str:
    """The event's key name, lower case; ValueError for anything but a short string."""
    name = event.get("key", "")
    if not isinstance(name, str) or len(name) > 16:
        raise ValueError("not a key name")
    return name.lower()


def check_event(content: Any) -> bool:
    """Whether ``content`` is an event jupyter_rfb may handle: a dict with a short string
    ``type``, its numeric fields finite and in range (sizes positive), ``buttons`` and
    ``modifiers`` short lists of small numbers and short strings."""
    if not isinstance(content, dict):
        return False
    kind = content.get("type", content.get("event_type"))
    if not isinstance(kind, str) or len(kind) > 32:
        return False
    try:
        for name in NUMBERS:
            if name in content:
                number(content, name)
        if "timestamp" in content:
            number(content, "timestamp", limit=MAX_TIME)
        if kind == "resize" and min(number(content, n) for n in ("width", "height")) <= 0:
            return False
    except ValueError:
        return False
    buttons, modifiers = content.get("buttons", ()), content.get("modifiers", ())
    return (isinstance(buttons, list | tuple) and len(buttons) <= 8
            and all(isinstance(b, int) and not isinstance(b, bool) and 0 <= b < 32
                    for b in buttons)
            and isinstance(modifiers, list | tuple) and len(modifiers) <= 8
            and all(isinstance(m, str) and len(m) <= 16 for m in modifiers))
