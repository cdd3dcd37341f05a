"""Plots and a Markdown report for the Swan, Arango & Nakshatrala (2002) timing study.

Figures 8-12 of the paper drawn from :func:`lodsprite.experiments.swan2002.run.reproduce_swan2002`
results; every number comes from the results or :data:`PAPER_2002`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lodsprite.experiments.paper_numbers import PAPER_2002
from lodsprite.files import atomic_write_bytes, save_figure
from lodsprite.report.values import fmt_fixed, fmt_int

LABELS = {"inline": "inline (1999, keyframes in the frame loop)",
          "same_cores": "client and server on one core",
          "separate": "client and server on separate cores",
          "same_all_cores": "client and server sharing all cores",
          "same_cores_continuous": "one core, server rendering back to back",
          "separate_continuous": "separate cores, server rendering back to back",
          "two_servers": "client and two servers sharing all cores",
          "separate_10mbit": "two hosts, 10 Mbit/s link",
          "separate_100mbit": "two hosts, 100 Mbit/s link",
          "separate_unlimited": "two hosts, unlimited link",
          "separate_10mbit_zlib": "two hosts, 10 Mbit/s link, zlib keyframes",
          "separate_bounded": "separate cores, client with --max-error",
          "same_cores_bounded": "one core, client with --max-error"}
#: σ ratios reported: (stable set-up, its shared counterpart).
RATIOS = (("separate", "same_cores"), ("separate", "same_all_cores"),
          ("separate_continuous", "same_cores_continuous"))


def setups_in(results: dict) -> list[str]:
    """The set-ups of a results object, in the order they ran."""
    return [k for k, v in results.items()
            if isinstance(v, dict) and ("client_ms_mean" in v or "skipped" in v)]


def _client_plot(results: dict, setups: list[str], path: Path, title: str) -> Path | None:
    present = [s for s in setups if "per_frame_ms" in results.get(s, {})]
    if not present:
        return None
    fig = Figure(figsize=(7.5, 4.2), dpi=110)
    ax = fig.add_subplot()
    for s in present:
        ms = np.array(results[s]["per_frame_ms"])
        ax.plot(ms, lw=0.8, label=f"{LABELS[s]} (mean {ms.mean():.1f}, σ {ms.std():.1f} ms)")
        types = np.array(results[s]["per_frame_type"])
        hit = np.flatnonzero(types == "keyframe")
        ax.plot(hit, ms[hit], "o", ms=3)
    ax.set(xlabel="frame", ylabel="client time per frame (ms)", title=title)
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def _server_plot(results: dict, keys: list[str], path: Path, title: str) -> Path | None:
    stats = (results.get("separate") or {}).get("server") or (
        results.get("same_cores") or {}).get("server")
    if not stats:
        return None
    fig = Figure(figsize=(7.5, 4.2), dpi=110)
    ax = fig.add_subplot()
    for k in keys:
        vals = stats.get(f"{k}_ms", [])
        if vals:
            ax.plot(vals, ".-", lw=0.8, label=f"{k.replace('_', ' ')} (mean {np.mean(vals):.1f})")
    ax.set(xlabel="keyframe", ylabel="ms", title=title)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def _error_plot(results: dict, setups: list[str], path: Path) -> Path | None:
    present = [s for s in setups if (results.get(s) or {}).get("image")]
    if not present:
        return None
    fig = Figure(figsize=(7.5, 4.2), dpi=110)
    ax = fig.add_subplot()
    for s in present:
        e = np.array([np.nan if v is None else v
                      for v in results[s]["image"]["per_frame_error_px"]], dtype=float)
        ax.plot(np.maximum(e, 1e-3), lw=0.8,
                label=f"{LABELS[s]} (≥ ε on {100 * results[s]['image']['over_epsilon']:.0f} %)")
    eps = (results.get("config") or {}).get("epsilon", 1.0)
    ax.axhline(eps, color="k", lw=0.8, ls="--", label=f"ε = {eps:g} px")
    ax.set(xlabel="frame", ylabel="error metric of the frame shown (px)",
           title="Image error per frame, replayed (Eq. 2 against the keyframe shown)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def _policy_plot(results: dict, path: Path) -> Path | None:
    """Frame time and replayed error per frame of the paper's client and the bounded one,
    for each policy pair that ran (one column each)."""
    pairs = [p for p in results.get("policies") or []
             if all((results.get(s) or {}).get("image") for s in (p["setup"],
                                                                   f"{p['setup']}_bounded"))]
    if not pairs:
        return None
    eps = (results.get("config") or {}).get("epsilon", 1.0)
    fig = Figure(figsize=(5.5 * len(pairs), 6.0), dpi=110)
    axes = fig.subplots(2, len(pairs), squeeze=False, sharex=True)
    for col, pair in enumerate(pairs):
        top, bottom = axes[0][col], axes[1][col]
        for name, label in ((pair["setup"], "no bound (paper)"),
                            (f"{pair['setup']}_bounded", f"--max-error {pair['max_error']:g}")):
            r = results[name]
            ms = np.array(r["per_frame_ms"])
            top.plot(ms, lw=0.8, label=f"{label}: σ {ms.std():.1f}, p99 "
                                       f"{np.percentile(ms, 99):.1f} ms")
            e = np.array([np.nan if v is None else v
                          for v in r["image"]["per_frame_error_px"]], dtype=float)
            bottom.plot(np.maximum(e, 1e-3), lw=0.8,
                        label=f"{label}: ≥ ε on {100 * r['image'].get('over_epsilon', 0):.1f} %")
        bottom.axhline(eps, color="k", lw=0.8, ls="--", label=f"ε = {eps:g} px")
        top.set(ylabel="client ms per frame", title=LABELS.get(pair["setup"], pair["setup"]))
        top.set_yscale("log")
        bottom.set(xlabel="frame", ylabel="replayed error of the frame shown (px)")
        bottom.set_yscale("log")
        for ax in (top, bottom):
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
    fig.suptitle("The client's two policies: the paper's, and bounding the shown error")
    return save_figure(fig, path)


def write_plots(results: dict, out_dir: Path) -> list[Path]:
    out_dir = Path(out_dir)
    made = [
        _client_plot(results, ["separate"], out_dir / "fig08_client.png",
                     "Fig. 8 — distributed client time per frame (dots: keyframe received)"),
        _client_plot(results, ["inline", "same_cores", "same_all_cores", "separate"],
                     out_dir / "fig09_setups.png", "Fig. 9 — client time per frame by set-up"),
        _client_plot(results, ["separate_10mbit", "separate_10mbit_zlib", "separate_100mbit",
                               "separate_unlimited"],
                     out_dir / "fig10_links.png", "Client time per frame by link speed"),
        _server_plot(results, ["production", "viewpoint_wait", "paced", "render", "queue_insert"],
                     out_dir / "fig11_renderer.png", "Fig. 11 — KEYFRAME-RENDERER timings"),
        _server_plot(results, ["delta_t", "production", "queue_retrieve", "transmission"],
                     out_dir / "fig12_transmitter.png",
                     "Fig. 12 — KEYFRAME-TRANSMITTER timings"),
        _error_plot(results, ["inline", "separate", "same_cores", "separate_10mbit"],
                    out_dir / "image_error.png"),
        _policy_plot(results, out_dir / "policies.png"),
    ]
    return [p for p in made if p is not None]


COLUMNS = [("client ms mean", "client_ms_mean"), ("σ", "client_ms_std"),
           ("median", "client_ms_median"), ("p99", "client_ms_p99"),
           ("jitter", "client_ms_jitter"),
           ("keyframes", "keyframes"), ("sprites per keyframe", "sprites_per_keyframe"),
           ("δt ms", "delta_t_ms_mean"), ("production ms", "production_ms_mean"),
           ("paced ms", "paced_ms_mean"),
           ("render ms", "render_ms_mean"), ("queue insert ms", "queue_insert_ms_mean"),
           ("transmission ms", "transmission_ms_mean")]


def stability_lines(results: dict) -> list[str]:
    """The targets: σ ratios of each stable set-up to its shared counterpart, p99/median."""
    lines = []
    for stable, shared in RATIOS:
        a, b = results.get(stable, {}), results.get(shared, {})
        if a.get("client_ms_std") and b.get("client_ms_std"):
            lines.append(f"- Frame-time σ, `{stable}` ÷ `{shared}`: "
                         f"{a['client_ms_std'] / b['client_ms_std']:.3f} (target ≤ 0.2); "
                         f"p99 ÷ median of `{stable}`: "
                         f"{a['client_ms_p99'] / a['client_ms_median']:.2f} (target ≤ 2); "
                         f"jitter ratio {a['client_ms_jitter'] / b['client_ms_jitter']:.3f}.")
    if lines:
        lines.append("- Jitter is the RMS change of the client's frame time from one frame to "
                     "the next: the stutter a viewer sees.  σ also counts the slow change of "
                     "the scene's cost along the path, which no set-up removes.")
    return lines


IMAGE_COLUMNS = [("error px mean", "error_px_mean"), ("p95", "error_px_p95"),
                 ("max", "error_px_max"), ("RMSE", "rmse_mean"),
                 ("SSIM", "ssim_mean")]


def image_error_lines(results: dict, setups: list[str]) -> list[str]:
    """The replayed image error of each set-up (each run's untimed replay,
    :mod:`lodsprite.distributed.quality`)."""
    rows = [s for s in setups if (results[s].get("image") or {}).get("replayed_frames")]
    if not rows:
        return []
    first = results[rows[0]]["image"]
    lines = ["", "## Image error, replayed after the timed frames", "",
             "Every frame drawn again, untimed, from the keyframe it showed: the 1999 error "
             "metric (Eq. 2, pixels) against that keyframe, and RMSE / SSIM against full "
             f"resolution on {first['quality_frames']} evenly spaced frames. The plain "
             f"{(results.get('config') or {}).get('lod')}² level has RMSE "
             f"{fmt_fixed(first.get('rmse_lod_mean'), 2)}.", "",
             "| set-up | " + " | ".join(t for t, _ in IMAGE_COLUMNS) + " | frames ≥ ε |",
             "|---" * (len(IMAGE_COLUMNS) + 2) + "|"]
    for s in rows:
        im = results[s]["image"]
        over = im.get("over_epsilon")
        lines.append(f"| {LABELS.get(s, s)} | "
                     + " | ".join(fmt_fixed(im.get(k), 2) for _, k in IMAGE_COLUMNS)
                     + f" | {'—' if over is None else f'{100 * over:.1f} %'} |")
    return lines


def policy_lines(results: dict) -> list[str]:
    """The two client policies side by side (``results["policies"]``): a Markdown table."""
    pairs = results.get("policies") or []
    if not pairs:
        return []
    eps = (results.get("config") or {}).get("epsilon", 1.0)
    lines = ["", "## The client's policies: the paper's, and a bound on the shown error", "",
             "The paper's client shows each server keyframe until a newer one arrives, "
             "however far the viewer has gone.  With `--max-error PX` the client renders its "
             "own keyframe (full resolution, in its frame loop, as the 1999 algorithm does) "
             "when the shown keyframe's error at the current viewpoint reaches PX and no "
             f"better one has arrived.  Errors are replayed (Eq. 2, pixels); ε = {eps:g} px.",
             "", "| set-up | client | σ ms | p99 ms | mean ms | error px mean | p99 | max "
                 "| frames ≥ ε | server keyframes | own keyframes |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for pair in pairs:
        for key, label in (("paper", "no bound (paper)"),
                           ("bounded", f"--max-error {pair['max_error']:g}")):
            m = pair[key]
            over = m.get("over_epsilon")
            lines.append(
                f"| {LABELS.get(pair['setup'], pair['setup'])} | {label} | "
                + " | ".join(fmt_fixed(m.get(k), 2) for k in (
                    "client_ms_std", "client_ms_p99", "client_ms_mean", "error_px_mean",
                    "error_px_p99", "error_px_max"))
                + f" | {'—' if over is None else f'{100 * over:.1f} %'} | "
                + f"{fmt_int(m.get('keyframes'))} | {fmt_int(m.get('local_keyframes'))} |")
    return lines


def _cells(row: dict) -> str:
    return " | ".join(fmt_int(row.get(k)) if k == "keyframes" else fmt_fixed(row.get(k), 2)
                      for _, k in COLUMNS)


def write_report(results: dict, out_dir: Path, plots: list[Path]) -> Path:
    out_dir = Path(out_dir)
    cfg = results.get("config", {})
    setups = setups_in(results)
    present = [s for s in setups if "skipped" not in results[s]]
    lines = ["# Swan, Arango & Nakshatrala (2002) distributed LOD-sprite — swan2002", "",
             f"`{cfg.get('terrain')}` terrain, swan2002 path, {cfg.get('frames')} frames at "
             f"{cfg.get('size')}² px, {cfg.get('lod')}² coarse level, predictor "
             f"`{cfg.get('predictor')}`, server pace `{cfg.get('pace')}`, "
             f"{results.get('cpus')} CPU cores. Server and client are separate processes on "
             "this machine talking over TCP.", "",
             "| set-up | " + " | ".join(t for t, _ in COLUMNS) + " |",
             "|---" * (len(COLUMNS) + 1) + "|"]
    for s in present:
        lines.append(f"| {LABELS.get(s, s)} | " + _cells(results[s]) + " |")
    for s, name in (("separate", "paper distributed"), ("same_cores", "paper non-distributed")):
        lines.append(f"| {name} | " + _cells(PAPER_2002[s]) + " |")
    for s in setups:
        if "skipped" in results[s]:
            lines += ["", f"- `{s}` skipped: {results[s]['skipped']}."]
    lines += ["", *stability_lines(results)]
    lines += image_error_lines(results, present)
    lines += policy_lines(results)
    pred = results.get("prediction") or {}
    if pred:
        lines += ["", f"## Viewpoint prediction, {pred['lead_frames']} frames ahead (δt)", "",
                  "| predictor | eye error m, mean | max | view error °, mean | max |",
                  "|---|---|---|---|---|"]
        for name in ("linear", "kalman"):
            e = pred.get(name, {})
            lines.append(f"| {name} | {fmt_fixed(e.get('eye_m_mean'), 1)} | "
                         f"{fmt_fixed(e.get('eye_m_max'), 1)} | "
                         f"{fmt_fixed(e.get('view_deg_mean'), 2)} | "
                         f"{fmt_fixed(e.get('view_deg_max'), 2)} |")
    lines += ["", "The paper's times are from 2002 SGI Onyx machines over 10BASE-T; ours are "
                  "measured in this run on this machine, so compare ratios and shapes.", ""]
    lines += [f"![{p.stem}]({p.name})" for p in plots]
    path = out_dir / "report.md"
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    return path
