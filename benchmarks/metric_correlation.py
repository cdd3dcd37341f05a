"""Benchmark: does the error metric predict the measured error?  The 1999 warp metric
(Chen, Swan & Kaufman, Eq. 1-2) beside the metric with the resampling term
(:mod:`lodsprite.sprite.resampling`), issue 22 must-have 3.

For each terrain (Jacksboro and a fractal store, built here in a temporary folder) and path
(chen1999, flyover, bank) LOD-sprite runs once through the harness
(:func:`lodsprite.run.run_technique`), keyframes decided by ``--decide`` (default warp), with
the untimed replay measuring RMSE and FLIP of every ``--stride``-th frame against full
resolution.  Then, untimed, for the same keyframe/frame pairs both metrics' predicted errors
are computed (each keyframe's ``C'`` with its widened projection and image size).  Frames
that show a keyframe as it is (error 0 by construction, RMSE 0) are left out, as are frames
whose predicted error is not finite.  Printed per terrain and path: Pearson and Spearman
correlation of each metric with RMSE and with FLIP, warp beside resample.  Written: a CSV of
every measured frame (with diagnostics: the RMS blur and alias parts of the resampling term
over the square centres in view, and the mean anisotropy ``s1/s2``) and a scatter plot PNG.

    python benchmarks/metric_correlation.py [--frames N] [--size WxH] [--stride K]
        [--terrains jacksboro,store] [--paths chen1999,flyover,bank] [--decide warp|resample]
        [--store fractal:1024:7] [--out DIR]

Timings are not what this measures; correlations do not depend on the machine's load.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np
from scipy import stats

from lodsprite.api import Renderer
from lodsprite.camera import widened
from lodsprite.run import RenderConfig, field_of_view, parse_size, prepare, run_technique
from lodsprite.sprite.depth_metric import DepthEstimate
from lodsprite.sprite.metric import ErrorMetric, in_view
from lodsprite.sprite.policy import KEYFRAME, KeyframePolicy, keyframe_error_px
from lodsprite.sprite.raycast import coarse_normals
from lodsprite.sprite.resampling import singular_values, texel_jacobian
from lodsprite.terrain.store import build_store

METRICS = ("warp", "resample")
JUDGED = (*METRICS, "depth", "contrast", "decided")  # the depth estimate (plain, weighted
# by the keyframe's contrast), the deciding metric's own figure
MEASURES = ("rmse", "flip")


def predicted(renderer: Renderer, config: RenderConfig, path, log, rows,
              estimates: dict) -> list[dict]:
    """Each metric's error (px) of each measured spriteframe of ``rows`` against the
    keyframe it showed (``log``: the engine's keyframes; ``estimates``: the depth estimate
    of each, by its viewpoint's id), with its RMSE and FLIP."""
    tr = renderer.terrain_gl.drawer
    hf = tr.geometry.full  # what the engine's metric was built on
    w, h = config.size
    g = config.guard_px
    metrics = {m: ErrorMetric.for_level(hf, config.lod, m == "resample") for m in METRICS}
    cps: dict[tuple[str, int], np.ndarray] = {}
    out = []
    for i, row in enumerate(rows):
        k = row["keyframe"]
        if "rmse" not in row or (row["kind"] == KEYFRAME and not log[k].predicted):
            continue
        vp, key = path.viewpoints[i], log[k]
        key_vp_proj = widened(key.projection, w, h, g).matrix() @ key.viewpoint.view_matrix()
        rec = {"frame": i, "kind": row["kind"], "keyframe": k,
               **{m: row.get(m, float("nan")) for m in MEASURES}}
        for name, metric in metrics.items():
            if (name, k) not in cps:
                cps[name, k] = metric.reproject(key.viewpoint.o, key_vp_proj,
                                                (w + 2 * g, h + 2 * g))
            rec[f"{name}_px"] = keyframe_error_px(metric, cps[name, k], vp, tr.projection(vp),
                                                  h)
        proj = tr.projection(vp)
        for name, est in zip(("depth", "contrast"), estimates.get(id(key.viewpoint),
                                                              (None, None)), strict=True):
            rec[f"{name}_px"] = (float("nan") if est is None else est.error_px(
                vp.o, proj.matrix() @ vp.view_matrix(), proj.pixel_angle_rad(h), (w, h)))
        rec.update(terms(metrics["resample"], cps["resample", k], vp, tr.projection(vp),
                         config.size))
        out.append(rec)
    return out


def terms(metric: ErrorMetric, cp, vp, projection, size) -> dict[str, float]:
    """Diagnostics: the RMS over the square centres in view (hits) of the resampling term's
    two parts, ``blur = max(1/s2 - 1, 0)`` and ``alias = max(1 - 1/s1, 0)`` px, and the mean
    anisotropy ``s1 / s2`` (the fallback sample is not included)."""
    view_proj = projection.matrix() @ vp.view_matrix()
    c = metric.squares.centres
    vis = in_view(np.c_[c, np.ones(len(c))], view_proj)
    pts = np.asarray(cp)[vis & ~cp.missed]
    if len(pts) == 0:
        return {"blur_px": float("nan"), "alias_px": float("nan"), "aniso": float("nan")}
    j, ok = texel_jacobian(pts, coarse_normals(metric.squares, pts), cp.key_view_proj,
                           cp.key_size, view_proj, size)
    s1, s2 = singular_values(j[ok])
    blur = np.maximum(1 / np.maximum(s2, 1e-9) - 1, 0)
    alias = np.maximum(1 - 1 / np.maximum(s1, 1e-9), 0)
    return {"blur_px": float(np.sqrt(np.mean(blur ** 2))),
            "alias_px": float(np.sqrt(np.mean(alias ** 2))),
            "aniso": float(np.mean(s1 / np.maximum(s2, 1e-9)))}


def run_case(terrain: str, path_spec: str, args) -> list[dict]:
    extra = {k: v for k, v in (("proxy", args.proxy), ("key_scale", args.key_scale))
             if v is not None}
    config = RenderConfig(terrain=terrain, path=path_spec, mode="sprite",
                          size=parse_size(args.size), frames=args.frames,
                          epsilon=args.epsilon, ground_truth=True, flip=True,
                          quality_stride=args.stride, metric=args.decide, lod=args.lod,
                          **extra)
    scene, path = prepare(config)
    log: list = []
    opts = config.technique_options()
    estimates = capture_depth(opts.get("depth_stride") or 8, opts.get("key_scale") or 1.0)
    try:
        with Renderer(scene, config.size, field_of_view(config, path)) as renderer:
            result = run_technique(renderer, path, config, keyframes=log)
            recs = predicted(renderer, config, path, log, result.rows, estimates)
    finally:
        KeyframePolicy.keyframe_drawn = KEYFRAME_DRAWN
    decided = {r["frame"]: r["error_px"] for r in
               ({"frame": i, **row} for i, row in enumerate(result.rows))}
    for r in recs:  # the deciding metric's own figure, as logged in the timed run
        r["decided_px"] = decided[r["frame"]]
    print(f"  {terrain} {path_spec}: {len(log)} keyframes, {len(recs)} spriteframes measured")
    return recs


KEYFRAME_DRAWN = KeyframePolicy.keyframe_drawn


def capture_depth(stride: int, key_scale: float) -> dict:
    """Every keyframe's depth estimate (:mod:`lodsprite.sprite.depth_metric`), plain and
    weighted by the keyframe's contrast, by its viewpoint's id, whatever metric decides:
    each keyframe's depth and colour are read back once drawn (a cost in its frame; this
    benchmark times nothing)."""
    out: dict = {}

    def drawn(policy, depth, key, projection, color=None):
        z = depth()
        plain = DepthEstimate(z, key, projection, stride, key_scale)
        weighted = DepthEstimate(z, key, projection, stride, key_scale)
        weighted.weigh_by(depth.__self__.keyframe_image())
        out[id(key)] = (plain, weighted)
        KEYFRAME_DRAWN(policy, depth, key, projection, color)

    KeyframePolicy.keyframe_drawn = drawn
    return out


def correlations(recs: list[dict]) -> dict[str, float]:
    out: dict[str, float] = {"n": 0}
    for m in JUDGED:
        for q in MEASURES:
            x = np.array([r[f"{m}_px"] for r in recs])
            y = np.array([r[q] for r in recs])
            ok = np.isfinite(x) & np.isfinite(y)
            out["n"] = max(out["n"], int(ok.sum()))
            if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
                out[f"pearson_{m}_{q}"] = out[f"spearman_{m}_{q}"] = float("nan")
                continue
            out[f"pearson_{m}_{q}"] = float(np.corrcoef(x[ok], y[ok])[0, 1])
            out[f"spearman_{m}_{q}"] = float(stats.spearmanr(x[ok], y[ok])[0])
    return out


def print_table(results: dict[tuple[str, str], dict[str, float]]) -> None:
    head = "  ".join(f"{c:>15}" for c in
                     [f"{k} {q} {m}" for q in MEASURES for k in ("r", "rho") for m in
                      ("warp", "res", "depth", "con", "dec")])
    print(f"{'terrain':>10} {'path':>9} {'n':>4}  {head}")
    for (terrain, path), c in results.items():
        vals = "  ".join(f"{c[f'{k}_{m}_{q}']:>15.3f}" for q in MEASURES
                         for k in ("pearson", "spearman") for m in JUDGED)
        print(f"{terrain[-10:]:>10} {path:>9} {c['n']:>4}  {vals}")


def scatter(recs: list[dict], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 5, figsize=(24, 8))
    cases = sorted({(r["terrain"], r["path"]) for r in recs})
    for (a, q), ax in zip([(m, q) for q in MEASURES for m in JUDGED], axes.ravel(),
                          strict=True):
        for case in cases:
            sel = [r for r in recs if (r["terrain"], r["path"]) == case]
            ax.scatter([r[f"{a}_px"] for r in sel], [r[q] for r in sel], s=6,
                       label=f"{Path(case[0]).stem} {case[1]}")
        ax.set_xlabel(f"predicted error, {a} metric (px)")
        ax.set_ylabel(f"measured {q.upper()}")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=230)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--epsilon", type=float, default=1.0)
    ap.add_argument("--lod", type=int, default=16)
    ap.add_argument("--terrains", default="jacksboro,store")
    ap.add_argument("--paths", default="chen1999,flyover,bank")
    ap.add_argument("--decide", choices=(*METRICS, "depth"), default="warp",
                    help="the metric the run decides keyframes by (its own figure is "
                         "the decided column; depth needs --proxy depth)")
    ap.add_argument("--proxy", choices=("geometry", "depth"), default=None)
    ap.add_argument("--key-scale", type=float, default=None)
    ap.add_argument("--store", default="fractal:1024:7", help="the store's source")
    ap.add_argument("--out", type=Path, default=Path("out/metric_correlation"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    recs, results = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for terrain in args.terrains.split(","):
            spec = terrain
            if terrain == "store":
                spec = str(Path(tmp) / "store.zarr")
                build_store(args.store, spec, tile=256, chunk=64)
            for p in args.paths.split(","):
                case = run_case(spec, p, args)
                name = args.store if terrain == "store" else terrain
                for r in case:
                    r.update(terrain=name, path=p)
                recs += case
                results[name, p] = correlations(case)
    cols = ["terrain", "path", "frame", "kind", "keyframe", "decided_px", "warp_px",
            "resample_px", "depth_px", "contrast_px", "blur_px", "alias_px", "aniso",
            "rmse", "flip"]
    with open(args.out / "metric_correlation.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows({c: r[c] for c in cols} for r in recs)
    print(f"decided by the {args.decide} metric, ε = {args.epsilon} px, {args.size} px, "
          f"{args.frames} frames; r: Pearson, rho: Spearman")
    print_table(results)
    scatter(recs, args.out / "metric_correlation.png")
    print(f"wrote {args.out / 'metric_correlation.csv'}, {args.out / 'metric_correlation.png'}")


if __name__ == "__main__":
    main()
