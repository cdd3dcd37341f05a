"""Plots and a Markdown report for the Swan, Arango & Nakshatrala (2002) timing study.

Figures 8-12 of the paper drawn from :func:`lodsprite.distributed.reproduce.reproduce_swan2002`
results; every number comes from the results or :data:`PAPER_2002`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lodsprite.report.io import atomic_write_bytes, save_figure
from lodsprite.report.values import fmt_fixed

#: The paper's numbers (§4; 600 frames, 512² height field, two SGI Onyx over 10BASE-T).
PAPER_2002 = {
    "separate": {"client_ms_mean": 61.9, "client_ms_std": 14.8, "sprites_per_keyframe": 34.3,
                 "delta_t_ms_mean": 8940, "production_ms_mean": 2140,
                 "transmission_ms_mean": 2320, "render_ms_mean": 517,
                 "queue_insert_ms_mean": 1590, "viewpoint_wait_ms_mean": 0.06,
                 "queue_retrieve_ms_mean": 25},
    "same_cores": {"client_ms_mean": 256, "client_ms_std": 225},
}
LABELS = {"inline": "inline (1999, keyframes in the frame loop)",
          "same_cores": "client and server on the same cores",
          "separate": "client and server on separate cores",
          "two_servers": "client and two servers on the same cores",
          "separate_10mbit": "two hosts, 10 Mbit/s link",
          "separate_100mbit": "two hosts, 100 Mbit/s link",
          "separate_unlimited": "two hosts, unlimited link"}




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


def write_plots(results: dict, out_dir: Path) -> list[Path]:
    out_dir = Path(out_dir)
    made = [
        _client_plot(results, ["separate"], out_dir / "fig08_client.png",
                     "Fig. 8 — distributed client time per frame (dots: keyframe received)"),
        _client_plot(results, ["inline", "same_cores", "separate"],
                     out_dir / "fig09_setups.png", "Fig. 9 — client time per frame by set-up"),
        _client_plot(results, ["separate_10mbit", "separate_100mbit", "separate_unlimited"],
                     out_dir / "fig10_links.png", "Client time per frame by link speed"),
        _server_plot(results, ["production", "viewpoint_wait", "render", "queue_insert"],
                     out_dir / "fig11_renderer.png", "Fig. 11 — KEYFRAME-RENDERER timings"),
        _server_plot(results, ["delta_t", "production", "queue_retrieve", "transmission"],
                     out_dir / "fig12_transmitter.png",
                     "Fig. 12 — KEYFRAME-TRANSMITTER timings"),
    ]
    return [p for p in made if p is not None]


ROWS = [("client ms, mean", "client_ms_mean"), ("client ms, σ", "client_ms_std"),
        ("client ms, median", "client_ms_median"), ("client ms, p99", "client_ms_p99"),
        ("keyframes received", "keyframes"), ("keyframes per second", "keyframe_rate_hz"),
        ("spriteframes per keyframe", "sprites_per_keyframe"),
        ("δt ms", "delta_t_ms_mean"), ("keyframe production ms", "production_ms_mean"),
        ("keyframe render ms", "render_ms_mean"), ("queue insert ms", "queue_insert_ms_mean"),
        ("transmission ms", "transmission_ms_mean")]


def write_report(results: dict, out_dir: Path, plots: list[Path]) -> Path:
    out_dir = Path(out_dir)
    cfg = results.get("config", {})
    present = [s for s in ALL_SETUPS if s in results and "skipped" not in results[s]]
    lines = ["# Swan, Arango & Nakshatrala (2002) distributed LOD-sprite — swan2002", "",
             f"`{cfg.get('terrain')}` terrain, swan2002 path, {cfg.get('frames')} frames at "
             f"{cfg.get('size')}² px, {cfg.get('lod')}² coarse level, predictor "
             f"`{cfg.get('predictor')}`, {results.get('cpus')} CPU cores. Server and client "
             "are separate processes on this machine talking over loopback TCP.", "",
             "| quantity | " + " | ".join(s.replace("_", " ") for s in present)
             + " | paper distributed | paper non-distributed |",
             "|---" * (len(present) + 3) + "|"]
    for title, key in ROWS:
        cells = [fmt_fixed(results[s].get(key), 2) for s in present]
        paper = [fmt_fixed(PAPER_2002[s].get(key), 2) for s in ("separate", "same_cores")]
        lines.append(f"| {title} | " + " | ".join(cells + paper) + " |")
    for s in ALL_SETUPS:
        if "skipped" in results.get(s, {}):
            lines += ["", f"- `{s}` skipped: {results[s]['skipped']}."]
    sep, same = results.get("separate", {}), results.get("same_cores", {})
    if sep.get("client_ms_std") and same.get("client_ms_std"):
        lines += ["", f"Frame-time σ, separate ÷ same cores: "
                      f"{sep['client_ms_std'] / same['client_ms_std']:.3f} (target ≤ 0.2); "
                      f"p99 ÷ median, separate: "
                      f"{sep['client_ms_p99'] / sep['client_ms_median']:.2f} (target ≤ 2)."]
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


ALL_SETUPS = ("inline", "same_cores", "separate", "two_servers", "separate_10mbit",
              "separate_100mbit", "separate_unlimited")
