"""The one batch driver's core: :func:`drive` runs a technique made already along a
camera path through the harness (:func:`lodsprite.harness.run_path`: one untimed
warm-up, per-frame time with ``ctx.finish()`` inside the clock, nothing read back in the
timed loop), then its untimed replay for what :class:`Measure` asks (quality against the
technique's :meth:`~lodsprite.techniques.Technique.reference`, by default the scene's
terrain's level 0 band-limited; saved frames, a video, kept images), then the technique's
own columns and files (:meth:`~lodsprite.techniques.Technique.outputs`), and writes
``frames.csv``, ``summary.json`` and those files.

Every batch run goes through it: :func:`lodsprite.run.run_scene` (any registered
technique on any scene: ``lodsprite render`` and its shortcuts ``render --scene FILE``,
``crowd``, ``lumigraph render``) and the distributed client's run
(:func:`lodsprite.distributed.run.run_client`, a technique on the client's own GL
context), which is why it lives apart from :mod:`lodsprite.run`.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite import vdp
from lodsprite.errors import InputError
from lodsprite.files import write_json, write_png
from lodsprite.harness import (
    ImageCallback,
    RunResult,
    run_path,
    technique_reference,
    write_run,
)

if TYPE_CHECKING:
    from lodsprite.paths import CameraPath
    from lodsprite.progress import Progress
    from lodsprite.runconfig import RenderConfig
    from lodsprite.techniques.base import Technique


@dataclass(frozen=True)
class Measure:
    """What a run measures and keeps beside its timings (never inside them).

    ``ground_truth``: quality (RMSE, PSNR, SSIM; FLIP with ``flip``) every
    ``quality_stride``-th frame of the untimed replay; ``save_frames``: PNG frames
    (``frames/frame_NNNNN.png``, every ``save_every``-th; with ``ground_truth`` the
    reference beside each, ``frames/ref_NNNNN.png``); ``video``: an MP4 of the frames
    shown (with ``ground_truth``: reference | technique | difference); ``keep``: frames
    whose images come back in :attr:`RunResult.images`; ``played``: the path played in
    time (:func:`lodsprite.playback.run_played`: frames as often as the technique draws
    them, or at ``display_rate`` a second, each judged at its display time's viewpoint)
    instead of frame after frame; ``vdp_seconds``: a played run's ColorVideoVDP over that
    much of it (:mod:`lodsprite.vdp`)."""

    ground_truth: bool = False
    quality_stride: int = 1
    flip: bool = False
    save_frames: bool = False
    save_every: int = 1
    video: Path | None = None
    keep: tuple[int, ...] = ()
    played: bool = False
    display_rate: float | None = None
    vdp_seconds: float | None = None

    @classmethod
    def of(cls, config: RenderConfig, video: Path | None = None) -> Measure:
        """The measurement a :class:`RenderConfig` asks for."""
        return cls(config.ground_truth, config.quality_stride, config.flip,
                   config.save_frames, config.save_every, video, played=config.played,
                   display_rate=config.display_fps, vdp_seconds=config.vdp_seconds)

    def check(self) -> None:
        if self.quality_stride < 1:
            raise InputError(f"quality stride must be >= 1, got {self.quality_stride}")
        if self.save_every < 1:
            raise InputError(f"save_every must be >= 1, got {self.save_every}")
        if self.played and (self.save_frames or self.video is not None or self.keep):
            raise InputError("a run played in time keeps no images yet: no saved frames, "
                             "video or kept frames")
        vdp.check_request(self.vdp_seconds, self.played, self.ground_truth)


def _image_sink(measure: Measure, n: int, out_dir: Path | None, stack: ExitStack,
                reference: Callable | None, images: dict[int, np.ndarray],
                path: CameraPath) -> tuple[Callable | None, Collection[int] | None]:
    """The replay's ``on_image`` for saved frames, the video and kept images, and the
    frames it wants (None: all)."""
    from lodsprite.report.video import VideoWriter, side_by_side

    writer = stack.enter_context(VideoWriter(measure.video)) if measure.video else None
    save = measure.save_frames and out_dir is not None
    if not (save or writer or measure.keep):
        return None, None
    keep = set(measure.keep)
    saved = range(0, n, measure.save_every) if save else range(0)

    def on_image(i: int, image: np.ndarray, truth: np.ndarray | None) -> None:
        if i in saved:
            write_png(out_dir / "frames" / f"frame_{i:05d}.png", image)
            if measure.ground_truth:  # the reference beside it
                if truth is None:
                    truth = reference(path.viewpoints[i])
                write_png(out_dir / "frames" / f"ref_{i:05d}.png", truth)
        if i in keep:
            images[i] = image
        if writer is not None:
            if measure.ground_truth:
                if truth is None:
                    truth = reference(path.viewpoints[i])
                image = side_by_side(truth, image)
            writer.append(image)

    if writer is not None:
        return on_image, None
    return on_image, sorted(set(saved) | keep)


def drive(technique: Technique, path: CameraPath, out_dir: Path | None = None,
          measure: Measure = Measure(), *, reference: Callable | None = None,
          progress: Progress | None = None, summary: Mapping[str, Any] | None = None,
          finish: Callable[[], None] | None = None, gl_renderer: str = "",
          on_image: ImageCallback | None = None,
          image_frames: Collection[int] | None = None) -> RunResult:
    """Run ``technique`` along ``path`` (module doc) and, with ``out_dir``, write
    ``frames.csv``, ``summary.json`` (the run's, then ``summary``'s keys) and the
    technique's files.  ``reference``: ``viewpoint -> image`` (default: the technique's
    :meth:`~lodsprite.techniques.Technique.reference`, else the scene's terrain at full
    resolution); ``finish``/``gl_renderer``: as :func:`~lodsprite.harness.run_path`;
    ``on_image`` (for the frames ``image_frames``, default all): the caller's own use of
    the replayed images, instead of ``measure``'s saved frames, video and kept images.
    Returns the result, its summary merged and kept images in ``images``."""
    from lodsprite.report.video import check_video_path

    measure.check()
    if measure.video is not None:
        check_video_path(measure.video)
    images: dict[int, np.ndarray] = {}
    with ExitStack() as stack:
        if measure.ground_truth and reference is None:
            reference = stack.enter_context(technique_reference(technique, path))
        if measure.played:
            from lodsprite.playback import run_played

            result = run_played(technique, path, rate=measure.display_rate, finish=finish,
                                gl_renderer=gl_renderer, progress=progress,
                                ground_truth=measure.ground_truth, reference=reference,
                                quality_stride=measure.quality_stride, flip=measure.flip,
                                vdp_seconds=measure.vdp_seconds)
        else:
            if on_image is None:
                on_image, image_frames = _image_sink(
                    measure, len(path.viewpoints),
                    None if out_dir is None else Path(out_dir), stack, reference, images,
                    path)
            result = run_path(technique, path, finish=finish, gl_renderer=gl_renderer,
                              progress=progress, ground_truth=measure.ground_truth,
                              reference=reference, quality_stride=measure.quality_stride,
                              flip=measure.flip, on_image=on_image,
                              image_frames=image_frames)
    files = technique.outputs(result, path)
    result.summary.update(summary or {})
    result.images = images
    if out_dir is not None:
        write_run(Path(out_dir), result)
        for name, data in files.items():
            write_json(Path(out_dir) / name, data)
    return result


__all__ = ["Measure", "drive"]
