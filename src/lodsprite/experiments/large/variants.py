"""The LOD-sprite variants ``reproduce large`` runs, the rows it keeps of each run, and
the comparison with the adaptive renderer at equal error (issue 22, must-have 8).

A variant is a set of technique options (:data:`VARIANTS`); one whose options the
``sprite-adaptive`` technique or :class:`~lodsprite.run.RenderConfig` does not know is
skipped with the reason (:func:`unavailable`), so the experiment runs on a branch that
has not got them and picks them up once they are there.

Equal error (:func:`equal_error`): among every LOD-sprite row of every variant and ε,
those whose RMSE *and* FLIP are at most adaptive's at 1 px; the best is the one with the
highest speedup in total time (``total_s``: adaptive's over the row's, the whole path
each).  Which rows are within is judged on the *chosen* half of the sampled frames
(``rmse_chosen``, ``flip_chosen``); every figure reported (``rmse``, ``flip``,
``within_reported``) is of the other half
(:func:`~lodsprite.experiments.base.split_sampled`), so that the best row's reported
error is not the noise that picked it.  Every row is reported with its speedup and
whether it is within both bounds on each half.
"""

from __future__ import annotations

from typing import Any

#: The LOD-sprite variants: name -> the technique options that make it.  Every option a
#: variant differs in is given, so none takes the store defaults of
#: :mod:`lodsprite.techniques.defaults` (which the reproduction sets); all draw their
#: spriteframes on the view-dependent proxy at ``PROXY_SSE`` px and measure their error
#: with the resampling metric (``METRIC``: on a store's long flights the warp alone kept
#: one keyframe for a whole 90-frame flyover at 4k², RMSE 9.8 against adaptive's 7.6).
PROXY_SSE = 8.0
METRIC = "resample"
VARIANTS: dict[str, dict[str, Any]] = {
    "whole": {"tiles": 1, "cache_mb": 0.0, "proxy_sse": PROXY_SSE, "metric": METRIC},
    "tiled": {"tiles": 4, "cache_mb": 0.0, "proxy_sse": PROXY_SSE, "metric": METRIC},
    "tiled+cache": {"tiles": 4, "cache_mb": 64.0, "proxy_sse": PROXY_SSE, "metric": METRIC},
    # the worker's spriteframes on the coarse level (the view-dependent proxy is inline's)
    "worker": {"tiles": 1, "cache_mb": 0.0, "metric": METRIC, "keyframes": "worker"},
    "worker+tiled": {"tiles": 4, "cache_mb": 0.0, "metric": METRIC, "keyframes": "worker"},
}
#: Variants whose keyframes come from the worker process: run with the path played in
#: time (:mod:`lodsprite.playback`) at the path's own rate, judged at display time.
PLAYED = frozenset(k for k, v in VARIANTS.items() if v.get("keyframes") == "worker")
TIME_KEY = "total_s"  # what the speedups compare: the whole path's time
#: What a row keeps of a run's summary.json, where the run has it.
ROW_KEYS = ("median_ms", "p99_ms", "total_s", "first_frame_ms", "first_frame_s",
            "peak_rss_mb", "tiles_loaded", "tiles_bad", "reader_restarts", "cache_hits")


def unavailable(options: dict[str, Any]) -> str | None:
    """Why a LOD-sprite run with ``options`` cannot be made here (an option the
    ``sprite-adaptive`` technique does not declare yet; RenderConfig takes every option a
    technique declares), or None."""
    from lodsprite import techniques

    known = set(techniques.get("sprite-adaptive").defaults())
    missing = sorted(k for k in options if k not in known)
    if missing:
        return (f"the sprite-adaptive technique takes no option {', '.join(missing)} on "
                "this build")
    return None


def row(summary: dict, quality: tuple[float, float], epsilon: float | None = None,
        tiles: int = 1, chosen: tuple[float, float] | None = None,
        key_sse: float | None = None) -> dict:
    """One row of results.json from a run's ``summary``, its ``(rmse, flip)`` on the
    reported frames and ``chosen`` (the same on the frames rows are chosen on; default:
    ``quality``): ``median_ms, p99_ms, rmse, flip, rmse_chosen, flip_chosen, epsilon,
    key_sse, keyframes, tiles_rendered`` and the :data:`ROW_KEYS` the run has
    (``first_frame_ms``:
    its untimed warm-up).  ``tiles_rendered`` where the run does not count it: its
    keyframes times ``tiles`` squared (a whole keyframe is every tile)."""
    keyframes = summary.get("keyframes")
    rendered = summary.get("tiles_rendered")
    if rendered is None and keyframes is not None:
        rendered = int(keyframes) * tiles * tiles
    out = {"epsilon": epsilon, "key_sse": key_sse, "keyframes": keyframes,
           "tiles_rendered": rendered, "rmse": quality[0], "flip": quality[1]}
    chosen = quality if chosen is None else chosen
    out["rmse_chosen"], out["flip_chosen"] = chosen
    out.update({k: summary[k] for k in ROW_KEYS if k in summary})
    return out


def sprite_rows(per_path: dict) -> list[tuple[str, dict]]:
    """``(variant, row)`` for every LOD-sprite row of one side and path."""
    return [(name, r) for name in VARIANTS for r in per_path.get(name, [])]


def _within(r: dict, ad: dict, half: str) -> bool:
    """``r``'s RMSE and FLIP both at most adaptive's ``ad`` on one half of the sampled
    frames (``half``: ``"_chosen"`` or ``""``, the reported)."""
    return r[f"rmse{half}"] <= ad[f"rmse{half}"] and r[f"flip{half}"] <= ad[f"flip{half}"]


def equal_error(per_path: dict) -> dict:
    """The comparison at equal error of one side and path (``per_path``: ``adaptive`` and
    the variants' rows): every row with its speedup over adaptive (:data:`TIME_KEY`), its
    RMSE and FLIP on the reported frames, ``within`` (RMSE and FLIP both at most
    adaptive's on the chosen frames) and ``within_reported`` (the same on the reported
    frames); ``best``: the fastest row within on the chosen frames, or None when no row
    is (module docstring)."""
    ad = per_path["adaptive"]
    rows = [{"variant": name, "epsilon": r["epsilon"], "key_sse": r.get("key_sse"),
             "rmse": r["rmse"], "flip": r["flip"],
             "rmse_chosen": r["rmse_chosen"], "flip_chosen": r["flip_chosen"],
             "speedup": ad[TIME_KEY] / r[TIME_KEY], "within": _within(r, ad, "_chosen"),
             "within_reported": _within(r, ad, "")}
            for name, r in sprite_rows(per_path)]
    ok = [r for r in rows if r["within"]]
    return {"time": TIME_KEY, "adaptive_rmse": ad["rmse"], "adaptive_flip": ad["flip"],
            "adaptive_rmse_chosen": ad["rmse_chosen"],
            "adaptive_flip_chosen": ad["flip_chosen"],
            "best": max(ok, key=lambda r: r["speedup"]) if ok else None, "rows": rows}


def patrol_block(without: dict, cached: dict, cache_mb: float) -> dict:
    """The patrol comparison from its two rows (``cache_mb`` 0 and ``cache_mb``):
    keyframe work (keyframes and tiles rendered) and speed with and without the cache,
    how many times less keyframe work the cache does, the cached run's RMSE and FLIP over
    the uncached one's (``rmse_ratio``, ``flip_ratio``) and ``equal_error`` (both at most
    the uncached run's, on the reported frames)."""
    work = "tiles_rendered" if without.get("tiles_rendered") else "keyframes"
    cut = (without[work] / cached[work]) if cached.get(work) else None
    ratio = {f"{k}_ratio": (cached[k] / without[k] if without[k] else None)
             for k in ("rmse", "flip")}
    return {"cache_mb": cache_mb, "without_cache": without, "with_cache": cached,
            "work": work, "keyframe_work_cut": cut,
            "speedup": without[TIME_KEY] / cached[TIME_KEY], **ratio,
            "equal_error": cached["rmse"] <= without["rmse"]
            and cached["flip"] <= without["flip"]}
