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
* RMSE, PSNR and SSIM against the reference frame on every ``stride``-th frame, beside
  the plain coarse level's (:func:`frame_quality`).  The reference is the one of every
  quality figure: over a terrain store, level 0 through the full-resolution renderer
  (:func:`lodsprite.harness.level_zero_reference`), never the working grid the server
  draws; over an in-memory field, its full-resolution grid (level 0 of the field).

Frames that name no keyframe (index -1, runs recorded before the client logged its own
keyframes) are left out.  A frame whose error cannot be measured (no coarse square in
view: ``inf``) counts as at or above ε; means and percentiles are over the measured ones.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.harness import level_zero_reference
from lodsprite.run import RenderConfig, field_of_view, prepare, sprite_frames
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_error_px

DEFAULT_STRIDE = 10


def reference_images(pr: PathRenderer, viewpoint, lod: int,
                     truth: Callable | None = None) -> tuple[np.ndarray, ...]:
    """What a frame is compared with (untimed): the reference frame (``truth(viewpoint)``,
    default ``pr``'s full-resolution terrain), the plain coarse level, and the coarse level
    with the border ribbons; ``(H, W, 3) uint8`` each."""
    r = pr.renderer
    if truth is None:
        r.render(viewpoint, None)
    truth = r.target.read_color() if truth is None else truth(viewpoint)
    r.render(viewpoint, lod)
    plain = r.target.read_color()
    r.render_proxy(viewpoint, lod, border=True)
    return truth, plain, r.target.read_color()


def frame_quality(image: np.ndarray, references: tuple[np.ndarray, ...]) -> dict:
    """RMSE, PSNR and SSIM of ``image`` and of the plain coarse level against the full
    resolution (:func:`reference_images`), and RMSE of the coarse level with ribbons."""
    from lodsprite.metrics import psnr, rmse, ssim

    truth, lod, lod_border = references
    return {"rmse_sprite": rmse(image, truth), "psnr_sprite": psnr(image, truth),
            "ssim_sprite": ssim(image, truth), "rmse_lod": rmse(lod, truth),
            "psnr_lod": psnr(lod, truth), "ssim_lod": ssim(lod, truth),
            "rmse_lod_border": rmse(lod_border, truth)}


def quality_summary(rows: list[dict]) -> dict:
    """Mean RMSE / SSIM over frames; PSNR from the mean squared error over frames (a
    keyframe equals its ground truth, whose per-frame PSNR would be infinite)."""
    out = {}
    for kind in ("sprite", "lod"):
        r = np.array([row[f"rmse_{kind}"] for row in rows])
        mse = float(np.mean(r**2))
        out[f"rmse_{kind}_mean"] = float(r.mean())
        out[f"psnr_{kind}_mean"] = float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)
        out[f"ssim_{kind}_mean"] = float(np.mean([row[f"ssim_{kind}"] for row in rows]))
    out["rmse_ratio"] = (out["rmse_sprite_mean"] / out["rmse_lod_mean"]
                         if out["rmse_lod_mean"] > 0 else float("nan"))
    # The plain coarse level with the border ribbons LOD-sprite draws (an ablation: how much
    # of LOD-sprite's gain is the ribbons' alone).
    out["rmse_lod_border_mean"] = float(np.mean([row["rmse_lod_border"] for row in rows]))
    return out


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
        fov = field_of_view(config, self.path)
        self.paths = PathRenderer(scene, config.size, fov)
        # a store's frames are judged against its level 0, never the working grid
        self.level0 = level_zero_reference(self.paths.ctx, scene, config.size, fov,
                                           config.shading)
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
            self._references[i] = reference_images(
                self.paths, vp, self.config.lod, self.level0 and self.level0.image)
        return self._references[i]

    def release(self) -> None:
        if self.level0 is not None:
            self.level0.release()
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
