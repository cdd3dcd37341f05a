"""The ``distributed`` technique's spec (entry point ``distributed`` of the group
``lodsprite.techniques``): the LOD-sprite client whose keyframes come from a LOD server
(Swan et al. 2002).  Its factory imports the client when called."""

from __future__ import annotations

from typing import Any

from lodsprite.techniques.builtin import EPSILON, LOD, with_terrain_defaults
from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import TechniqueSpec

SERVER = Option("server", str, "", "distributed: the LOD server, HOST:PORT")
MAX_ERROR = Option("max_error", float, 4.0, "distributed: the client renders its own "
                   "keyframe when the shown one's error reaches this", min=0, above=True,
                   unit="px")


def create(renderer: Any, **options: Any) -> Any:
    from lodsprite.distributed.technique import create as make

    return make(renderer, **with_terrain_defaults(renderer, options))


DISTRIBUTED = TechniqueSpec(
    "distributed", create, (SERVER, LOD, EPSILON, MAX_ERROR), ("terrain",),
    "LOD-sprite client, keyframes from a LOD server (Swan et al. 2002)", order=60,
    batch=False,
    summary=("keyframes received: {keyframes_received}, σ {std_ms:.2f} ms, p99 {p99_ms:.2f} "
             "ms; server δt {delta_t_ms_mean:.0f} ms, keyframe render {render_ms_mean:.0f} "
             "ms",))
