"""The timed runs of ``reproduce large`` along one path of one store (:class:`PathRuns`):
adaptive at a tolerance, a LOD-sprite variant at an ε, a worker variant played in time,
full resolution on the sampled frames; each run in a process of its own
(:func:`~lodsprite.experiments.large.child.render_in_child`), measured against the
path's reference images."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.errors import InputError
from lodsprite.experiments.base import split_sampled
from lodsprite.experiments.large.child import render_in_child
from lodsprite.experiments.large.reference import errors, saved_frames
from lodsprite.experiments.large.variants import VARIANTS, row

if TYPE_CHECKING:
    from lodsprite.experiments.large.config import LargeConfig


def sprite_lod(side: int) -> int:
    """LOD-sprite's coarse level for a store ``side`` samples a side: squares of about
    128 samples (3.8 km at 30 m), 16 to 128 squares a side (16, the paper's, up to 2k²).
    A fixed 16² over 16k² has squares 30 km wide: a low flight sees one or two square
    centres, and the proxy stands far off the ground in view."""
    q = 16
    while q < 128 and q * 128 < side:
        q *= 2
    return q


def run_folder(variant: str, eps: float, key_sse: float | None = None,
               extra: dict | None = None) -> str:
    """The folder of a LOD-sprite run: ``VARIANT_epsE``, then ``_keyK`` for a keyframe
    tolerance other than the config's (``key_sse`` given) and ``_NAMEV`` for each option
    in ``extra`` that differs from the variant's own (the patrol's two cache settings), so
    that no two runs of one path share a folder."""
    name = f"{variant.replace('+', '-')}_eps{eps:g}"
    if key_sse is not None:
        name += f"_key{key_sse:g}"
    own = VARIANTS.get(variant, {})
    for k, v in sorted((extra or {}).items()):
        if own.get(k) != v:
            name += f"_{k.replace('_', '')}" + (f"{v:g}" if isinstance(v, int | float)
                                                else str(v))
    return name


class PathRuns:
    """The timed runs of one store along one path, each measured on the sampled frames
    against ``ref`` (frame index -> reference image)."""

    def __init__(self, store: Path, n: int, cfg: LargeConfig, spec: str, runs: Path,
                 ref: dict) -> None:
        self.store, self.n, self.cfg, self.runs, self.ref = store, n, cfg, runs, ref
        self.keep = sorted(ref)
        self.common = {"terrain": str(store), "path": spec, "frames": cfg.frames,
                       "size": [cfg.image, cfg.image], "save_frames": True,
                       "save_every": cfg.sample_every}

    def timed(self, folder: str, **config) -> tuple[dict, tuple[float, float],
                                                    tuple[float, float]]:
        """One timed run (its summary) and its (RMSE, FLIP) on the reported and on the
        chosen halves of the sampled frames (:func:`split_sampled`)."""
        s = render_in_child({**self.common, **config}, self.runs / folder)
        images = saved_frames(self.runs / folder, self.keep)
        chosen, reported = split_sampled(self.keep)
        return (s, errors({i: images[i] for i in reported}, self.ref),
                errors({i: images[i] for i in chosen}, self.ref))

    def adaptive(self, sse: float) -> dict:
        """The adaptive renderer at ``sse`` px (folder ``adaptive`` at the config's own)."""
        folder = "adaptive" if sse == self.cfg.sse else f"adaptive_sse{sse:g}"
        s, q, c = self.timed(folder, mode="adaptive", sse=sse)
        return {**row(s, q, chosen=c), "sse": sse, "tiles_evicted": s["tiles_evicted"],
                "gpu_cache_mb": s["gpu_cache_mb"],
                "first_frame_s_technique": s.get("first_frame_s_technique")}

    def sprite(self, variant: str, eps: float, key_sse: float | None = None,
               **extra) -> dict:
        """A LOD-sprite variant at ``eps`` with keyframes at ``key_sse`` (default the
        config's ``key_sse``)."""
        opts = {**VARIANTS[variant], **extra}
        key = self.cfg.key_sse if key_sse is None else key_sse
        folder = run_folder(variant, eps, None if key == self.cfg.key_sse else key, extra)
        s, q, c = self.timed(folder, mode="sprite", key_sse=key, lod=sprite_lod(self.n),
                             epsilon=eps, **opts)
        return row(s, q, eps, int(opts.get("tiles", 1)), chosen=c, key_sse=key)

    def played(self, variant: str, eps: float) -> dict:
        """A worker variant (:data:`~lodsprite.experiments.large.variants.PLAYED`) at
        ``eps``: the path played in time with a display at the path's own rate, the image
        on screen judged at pairs of display ticks every ``sample_every``-th tick against
        the band-limited level 0 at that instant's viewpoint, in the run's own replay
        (:mod:`lodsprite.display`), split into halves as the sampled frames."""
        from lodsprite.paths.core import NOMINAL_FPS

        opts = dict(VARIANTS[variant])
        s = render_in_child({**self.common, "save_frames": False, "mode": "sprite",
                             "key_sse": self.cfg.key_sse, "lod": sprite_lod(self.n),
                             "epsilon": eps, "ground_truth": True, "flip": True,
                             "quality_stride": self.cfg.sample_every,
                             "display_fps": NOMINAL_FPS, **opts,
                             **({} if self.cfg.vdp_seconds is None
                                else {"vdp_seconds": self.cfg.vdp_seconds})},
                            self.runs / run_folder(variant, eps))
        judged = played_quality(self.runs / run_folder(variant, eps))
        return {**row(s, judged[0], eps, chosen=judged[1], key_sse=self.cfg.key_sse),
                "played": True, **{k: s.get(k) for k in ("display_fps", "latency_ms_mean",
                                                           "truncated", "cvvdp_jod")}}

    def full(self, path) -> dict:
        """Full resolution timed on the sampled frames (a path file of them), or why not."""
        sampled = sampled_path(path, self.keep, self.runs / "sampled.json")
        try:
            s = render_in_child({"terrain": str(self.store), "mode": "full", "grid": self.n,
                                 "path": str(sampled), "frames": len(self.keep),
                                 "size": [self.cfg.image, self.cfg.image]},
                                self.runs / "full")
        except Exception as exc:  # noqa: BLE001 - the child's error or death: said, not fatal
            return {"skipped": f"{type(exc).__name__}: {exc}"}
        return {"median_ms": s["median_ms"], "p99_ms": s["p99_ms"], "total_s": s["total_s"],
                "first_frame_ms": s.get("first_frame_ms"),
                "frames": len(self.keep), "note": "timed on the sampled frames only"}


def sampled_path(path, keep: list[int], file: Path) -> Path:
    """The viewpoints ``keep`` of ``path`` as a path file."""
    from lodsprite.paths import CameraPath

    file.parent.mkdir(parents=True, exist_ok=True)
    CameraPath("sampled", tuple(path.viewpoints[i] for i in keep), path.fov_y_deg
               ).to_json(file)
    return file


def played_quality(folder: Path) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(reported, chosen)`` mean ``(rmse, flip)`` of a played run's judged display ticks
    (``ticks.csv`` rows with a ``flip``: each the image on screen then, against the
    reference there), in the halves of :func:`~lodsprite.experiments.base.split_sampled`
    over those ticks in order."""
    import csv

    with open(Path(folder) / "ticks.csv", newline="") as f:
        judged = [(float(r["rmse"]), float(r["flip"])) for r in csv.DictReader(f)
                  if r.get("flip")]
    chosen, reported = split_sampled(judged)
    if not chosen or not reported:
        raise InputError(f"a played run judged {len(judged)} ticks: too few to split")
    return (tuple(np.mean(reported, axis=0)), tuple(np.mean(chosen, axis=0)))
