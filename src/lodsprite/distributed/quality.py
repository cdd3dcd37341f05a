"""Image error of a distributed run: the error metric of the frames the client showed.

A timed run must not read its frames back: that would change the times it measures.
The client logs every keyframe it showed (:attr:`~lodsprite.distributed.client.LodClient.
shown`: slot, sequence number, viewpoint; ``local: true`` for the client's own) and its
technique records, per frame, which of them it showed (its decision).  A keyframe is a
function of its viewpoint (the server, and the client for its own, render the
full-resolution terrain through the renderer's projection for that viewpoint, with no
guard band) and every client frame is a spriteframe drawn from the keyframe it shows, so
after the timed run the harness replays the recorded frames untimed, as for every other
technique (:func:`lodsprite.harness.run_path`): RMSE, PSNR and SSIM against the one
reference (level 0 band-limited, :mod:`lodsprite.gl.reference`: of a store, or the full
grid of an in-memory field) on every ``quality_stride``-th frame, beside the plain
coarse level's (``rmse_lod`` ...).

Beside it, :func:`error_summary` gathers the LOD-sprite error metric (Chen, Swan &
Kaufman 1999, Eq. 2: ``sqrt(mean θ²) / β``, pixels) of every frame against the keyframe
it showed (:meth:`~lodsprite.distributed.technique.DistributedTechnique.replayed_errors`
for a client, the engine's own ``error_px`` for the inline algorithm): how far, and how
often, the keyframes that prediction placed left the viewer past ε.  A frame whose error
cannot be measured (no coarse square in view: ``inf``) counts as at or above ε; means and
percentiles are over the measured ones; frames that showed no keyframe (NaN) are left out.
"""

from __future__ import annotations

import numpy as np

DEFAULT_STRIDE = 10


def error_summary(errors: np.ndarray, epsilon: float) -> dict:
    """The error metric's figures of a run: ``errors (frames,)`` pixels, NaN for frames
    left out, ``inf`` where nothing was measurable; ``epsilon`` the threshold, pixels.
    Keys: ``replayed_frames``, ``unmeasurable_frames``, ``per_frame_error_px`` (None for
    frames left out), ``over_epsilon`` (share at or above ε), ``error_px_mean``,
    ``error_px_p95``, ``error_px_p99``, ``error_px_max``."""
    errors = np.asarray(errors, dtype=np.float64)
    done = errors[~np.isnan(errors)]
    finite = done[np.isfinite(done)]
    out: dict = {"replayed_frames": int(done.size),
                 "unmeasurable_frames": int(done.size - finite.size),
                 "per_frame_error_px": [None if np.isnan(e) else float(e) for e in errors]}
    if done.size:
        out["over_epsilon"] = float(np.mean(~(done < epsilon)))
    if finite.size:
        out.update(error_px_mean=float(finite.mean()),
                   error_px_p95=float(np.percentile(finite, 95)),
                   error_px_p99=float(np.percentile(finite, 99)),
                   error_px_max=float(finite.max()))
    return out


#: The summary keys of a run's image quality that a reproduction gathers beside the
#: error metric (the harness's names).
QUALITY_KEYS = ("quality_frames", "rmse_mean", "psnr_mean", "ssim_mean", "rmse_lod_mean",
                "psnr_lod_mean", "ssim_lod_mean", "rmse_lod_border_mean", "rmse_ratio")
