"""Progress callbacks, one type for every long-running call in the package.

Library code reports progress only through these callbacks; the command line turns
them into progress bars.
"""

from __future__ import annotations

from collections.abc import Callable

#: ``progress(done, total)``: ``done`` of ``total`` steps (frames, views, set-ups) finished.
Progress = Callable[[int, int], None]

#: ``progress(stage, done, total)``: the same for a run of several named stages, each
#: with its own count (one progress bar per stage).
StageProgress = Callable[[str, int, int], None]

__all__ = ["Progress", "StageProgress"]
