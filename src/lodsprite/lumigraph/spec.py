"""The lumigraph techniques' specs (entry points ``lumigraph-METHOD`` of the group
``lodsprite.techniques``), one per reconstruction method (Sloan, Cohen & Gortler 1997).
The factory imports the technique when called."""

from __future__ import annotations

from typing import Any

from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import TechniqueSpec

OPTIONS = (
    Option("folder", str, "", "lumigraph: the folder (default: the scene's)",
           command_line=False),  # the command names the scene (--scene, an argument)
    Option("depth_correction", bool, True, "lumigraph: depth-correct with the proxy"),
    Option("nodes", int, 16, "lumigraph: nodes per frame (arbitrary, projective)", min=1),
    Option("level", int, 1, "lumigraph subsample: mip level of the node images", min=0),
    Option("reuse", int, 6, "lumigraph projective: frames a reconstruction is reused", min=1),
    Option("fade", int, 8, "lumigraph progressive: frames of a fade", min=1),
    Option("target_fps", float, 30.0, "lumigraph critical: the frame-rate target", min=0,
           above=True, unit="fps"),
    Option("texture_mb", float, 4.0, "lumigraph critical: texture memory", min=0,
           above=True, unit="MB"),
    Option("per_component", bool, True, "lumigraph critical: one budget factor per "
           "component (off: a single factor, the paper's spikes)"))


def create(renderer: Any, **options: Any) -> Any:
    from lodsprite.lumigraph.technique import create as make

    return make(renderer, **options)


def _spec(method: str, text: str, order: int) -> TechniqueSpec:
    return TechniqueSpec(f"lumigraph-{method}", create, OPTIONS, ("lightfield",), text,
                         mode=method, fixed={"method": method}, order=order)


CRITICAL = _spec("critical", "time-critical reconstruction (Sloan, Cohen & Gortler 1997)",
                 200)
FULL = _spec("full", "every node of the lumigraph", 210)
ARBITRARY = _spec("arbitrary", "nearest nodes, any count", 220)
FIXED = _spec("fixed", "a fixed node set", 230)
LINE = _spec("line", "nodes on a line", 240)
PROJECTIVE = _spec("projective", "projective texture reuse", 250)
PROGRESSIVE = _spec("progressive", "progressive refinement", 260)
SUBSAMPLE = _spec("subsample", "a subsampled lumigraph", 270)
