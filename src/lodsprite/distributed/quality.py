"""Image error of a distributed run, measured afterwards by replaying what the client drew.

A timed run must not read its frames back: that would change the times it measures.
Instead the client records every keyframe it showed (``keyframes.json``: slot, sequence
number, viewpoint; ``local: true`` for the client's own, rendered in its frame loop)
and, for every frame, which of them it showed (``frames.csv``, column ``keyframe``).  A
keyframe is a function of its viewpoint: the server, and the client for its own, render
the full-resolution terrain through the renderer's projection for that viewpoint, as
:class:`~lodsprite.gl.sprite.SpriteRenderer` does with no guard band; and every client
frame is a spriteframe from the keyframe it shows.  So, untimed, every frame can be
drawn again as the client drew it and measured:

* the LOD-sprite error metric (Chen, Swan & Kaufman 1999, Eq. 2: ``sqrt(mean θ²) / β``,
  pixels) of every frame against the keyframe it showed: how far, and how often, the
  keyframes that prediction placed left the viewer past ε;
* RMSE, PSNR and SSIM against the full-resolution frame on every ``stride``-th frame,
  beside the plain coarse level's (:func:`lodsprite.run.frame_quality`).

Frames that name no keyframe (index -1, runs recorded before the client logged its own
keyframes) are left out.  A frame whose error cannot be measured (no coarse square in
view: ``inf``) counts as at or above ε; means and percentiles are over the measured ones.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.run import (
    RenderConfig,
    field_of_view,
    frame_quality,
    prepare,
    quality_summary,
    reference_images,
    sprite_frames,
)
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_error_px

DEFAULT_STRIDE = 10


def recorded_keyframes(run_dir: Path) -> tuple[list[Viewpoint], np.ndarray]:
    """Keyframe viewpoints a client took and, per frame, the index of the one it showed
    ``(frames,) int`` (-1: none) from a client's ``keyframes.json`` and ``frames.csv``."""
    run_dir = Path(run_dir)
    try:
        keys = json.loads((run_dir / "keyframes.json").read_text())["keyframes"]
        with (run_dir / "frames.csv").open() as f:
            shown = np.array([int(r["keyframe"]) for r in csv.DictReader(f)], dtype=np.int64)
        viewpoints = [Viewpoint.from_dict(k["viewpoint"]) for k in keys]
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{run_dir} holds no client run to replay: {exc}") from exc
    if shown.size and shown.max() >= len(viewpoints):
        raise InputError(f"{run_dir}: frames name keyframes that keyframes.json lacks")
    return viewpoints, shown


class Replayer:
    """Replays runs along one path: the full-resolution references are rendered once per
    measured frame and shared by every run replayed."""

    def __init__(self, config: RenderConfig, stride: int = DEFAULT_STRIDE) -> None:
        if stride < 1:
            raise InputError(f"stride must be >= 1, got {stride}")
        config = config.resolved(store=False)  # options not given: the 1999 algorithm's
        self.config, self.stride = config, stride
        scene, self.path = prepare(config, light=False)  # the grid the server draws
        self.paths = PathRenderer(scene, config.size, field_of_view(config, self.path))
        self.sprite = SpriteRenderer(self.paths.renderer, config.lod, config.visibility,
                                     border=config.border, guard_px=0)
        self.metric = ErrorMetric.for_level(scene.hf, config.lod)
        self._references: dict[int, tuple[np.ndarray, ...]] = {}
        self._key: Viewpoint | None = None  # the keyframe rendered last

    def replay(self, keys: list[Viewpoint], shown: np.ndarray) -> dict:
        """Error metric of every frame and image quality of every ``stride``-th frame;
        ``shown (frames,)`` indexes ``keys`` (-1: left out)."""
        views = self.path.viewpoints
        if len(shown) != len(views):
            raise InputError(f"the run has {len(shown)} frames, the path {len(views)}")
        renderer = self.paths.renderer
        c_primes: dict[int, np.ndarray] = {}
        errors = np.full(len(views), np.nan)
        rows = []
        for i, (vp, k) in enumerate(zip(views, shown, strict=True)):
            if k < 0:
                continue
            if k not in c_primes:
                c_primes[k] = self.metric.reproject(keys[k].o)
            errors[i] = keyframe_error_px(self.metric, c_primes[k], vp, renderer.projection(vp),
                                          renderer.target.height)
            if i % self.stride:
                continue
            rows.append(frame_quality(self.draw(keys[k], vp), self._reference(i, vp)))
        return _summary(errors, rows, self.config.epsilon)

    def draw(self, key: Viewpoint, viewpoint: Viewpoint) -> np.ndarray:
        """The frame a client drew at ``viewpoint`` from the keyframe (a server's or its
        own) at ``key``: ``(H, W, 3) uint8``, row 0 at the top."""
        if self._key is not key:
            self.sprite.render_keyframe(key, 0.0)
            self._key = key
        self.sprite.render_spriteframe(viewpoint)
        return self.sprite.target.read_color()

    def _reference(self, i: int, vp: Viewpoint) -> tuple[np.ndarray, ...]:
        if i not in self._references:
            self._references[i] = reference_images(self.paths, vp, self.config.lod)
        return self._references[i]

    def release(self) -> None:
        self.sprite.release()
        self.paths.release()
        self._references.clear()

    def __enter__(self) -> Replayer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _summary(errors: np.ndarray, rows: list[dict], epsilon: float) -> dict:
    """``errors (frames,)`` pixels, NaN for frames left out, inf where nothing was
    measurable; ``rows`` of frame_quality."""
    done = errors[~np.isnan(errors)]
    finite = done[np.isfinite(done)]
    out: dict = {"replayed_frames": int(done.size), "quality_frames": len(rows),
                 "unmeasurable_frames": int(done.size - finite.size),
                 "per_frame_error_px": [None if np.isnan(e) else float(e) for e in errors]}
    if done.size:
        out["over_epsilon"] = float(np.mean(~(done < epsilon)))
    if finite.size:
        out.update(error_px_mean=float(finite.mean()),
                   error_px_p95=float(np.percentile(finite, 95)),
                   error_px_p99=float(np.percentile(finite, 99)),
                   error_px_max=float(finite.max()))
    if rows:
        out.update(quality_summary(rows))
    return out


def inline_quality(config: RenderConfig, stride: int = DEFAULT_STRIDE) -> dict:
    """The same measures for the 1999 algorithm (keyframes in the frame loop), from an
    untimed run of it with ground truth; it draws the same frames as a timed run."""
    cfg = replace(config, mode="sprite", ground_truth=True, quality_stride=stride)
    scene, path = prepare(cfg)
    with PathRenderer(scene, cfg.size, field_of_view(cfg, path)) as pr:
        rows = sprite_frames(pr, path, cfg)
    errors = np.array([r["error_px"] for r in rows])
    # the harness's columns (rmse, psnr, ssim) under this comparison's names
    named = {"rmse": "rmse_sprite", "psnr": "psnr_sprite", "ssim": "ssim_sprite"}
    return _summary(errors, [{named.get(k, k): v for k, v in r.items()}
                             for r in rows if "rmse" in r], cfg.epsilon)
