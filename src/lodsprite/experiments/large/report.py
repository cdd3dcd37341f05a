"""Plots and a Markdown report for ``reproduce large``
(:func:`lodsprite.experiments.large.run.reproduce_large`): every ε row of every variant,
the comparison at equal error, the reference of each side, tiles that could not be read
and reader restarts, the patrol and the 512² jacksboro comparison."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from lodsprite.experiments.large.frontiers import LEVELS, SPRITE, curve
from lodsprite.experiments.large.frontiers import plot as plot_frontier
from lodsprite.experiments.large.variants import VARIANTS, equal_error
from lodsprite.files import atomic_write_bytes, save_figure, write_json
from lodsprite.report.frontier import time_at_error
from lodsprite.report.values import fmt_fixed

f = fmt_fixed


def _stores(r: dict) -> list[tuple[str, dict]]:
    return [*sorted(r["sizes"].items(), key=lambda kv: int(kv[0])),
            *sorted(r.get("terrains", {}).items())]


def _plot(r: dict, path: Path) -> Path:
    """Median ms and RMSE against side for adaptive and each variant at the first ε,
    and the adaptive run's peak memory; a line style a path."""
    fig = Figure(figsize=(13, 3.8), dpi=100)
    cost, err, mem = (fig.add_subplot(1, 3, i) for i in (1, 2, 3))
    sides = sorted(r["sizes"], key=int)
    n = [int(s) for s in sides]
    eps = r["config"]["eps"][0]
    for p, style in zip(r["config"]["paths"], ("-", "--", ":"), strict=False):
        series = {"adaptive": [r["sizes"][s][p]["adaptive"] for s in sides]}
        for name in VARIANTS:
            rows = [next((x for x in r["sizes"][s][p].get(name, []) if x["epsilon"] == eps),
                         None) for s in sides]
            if all(x is not None for x in rows) and rows:
                series[f"{name} ε {eps:g}"] = rows
        for label, rows in series.items():
            cost.plot(n, [x["median_ms"] for x in rows], "o" + style, label=f"{label} ({p})")
            err.plot(n, [x["rmse"] for x in rows], "o" + style, label=f"{label} ({p})")
        mem.plot(n, [x["peak_rss_mb"] for x in series["adaptive"]], "o" + style, label=p)
    cost.set(xscale="log", xlabel="terrain side (samples)", ylabel="median ms",
             title="frame cost against terrain size")
    err.set(xscale="log", xlabel="terrain side (samples)", ylabel="RMSE (grey levels)",
            title="image error against the reference")
    mem.set(xscale="log", xlabel="terrain side (samples)", ylabel="MB",
            title="peak resident memory (adaptive run)")
    for ax in (cost, err, mem):
        ax.legend(fontsize=6)
    fig.tight_layout()
    return save_figure(fig, path)


ROWS_HEAD = ["| side | run | ε | median / p99 ms | total s | RMSE / FLIP (reported) | "
             "RMSE / FLIP (chosen) | keyframes | tiles rendered | cache hits | speedup "
             "(total) | within adaptive's RMSE and FLIP (chosen / reported) | peak RSS MB | "
             "first frame ms (warm-up) | first frame s (process) | tiles loaded / bad | "
             "reader restarts |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]


def _cell(v, digits: int) -> str:
    return "—" if v is None else f(v, digits)


def _v(x: dict, key: str) -> str:
    return "—" if x.get(key) is None else str(x[key])


def _yes(v: bool) -> str:
    return "yes" if v else "no"


def _line(label: str, run: str, x: dict, ee: dict | None) -> str:
    speed = within = "—"
    if ee is not None:
        speed = f"{f(ee['speedup'], 2)}×"
        within = f"{_yes(ee['within'])} / {_yes(ee['within_reported'])}"
    eps = "—" if x.get("epsilon") is None else f"{x['epsilon']:g}"
    return (f"| {label} | {run} | {eps} | {_cell(x.get('median_ms'), 2)} / "
            f"{_cell(x.get('p99_ms'), 2)} | {_cell(x.get('total_s'), 2)} | "
            f"{_cell(x.get('rmse'), 2)} / {_cell(x.get('flip'), 3)} | "
            f"{_cell(x.get('rmse_chosen'), 2)} / {_cell(x.get('flip_chosen'), 3)} | "
            f"{_v(x, 'keyframes')} | {_v(x, 'tiles_rendered')} | "
            f"{_v(x, 'cache_hits')} | {speed} | {within} | "
            f"{_cell(x.get('peak_rss_mb'), 0)} | {_cell(x.get('first_frame_ms'), 1)} | "
            f"{_cell(x.get('first_frame_s'), 2)} | "
            f"{_v(x, 'tiles_loaded')} / {_v(x, 'tiles_bad')} | {_v(x, 'reader_restarts')} |")


def _label(key: str, res: dict) -> str:
    return f"{key}²" if key.isdigit() else f"{key} ({res['side']} a side)"


def path_rows(r: dict, path: str) -> list[str]:
    """The table of one path: per store adaptive, full resolution, every variant and ε."""
    lines = list(ROWS_HEAD)
    for key, res in _stores(r):
        v = res[path]
        ee = {(e["variant"], e.get("key_sse"), e["epsilon"]): e
              for e in equal_error(v)["rows"]}
        label = _label(key, res)
        for x in v.get("adaptive_sweep", [v["adaptive"]]):
            lines.append(_line(label, f"adaptive {x.get('sse', 1.0):g} px", x, None))
        full = v.get("full")
        if full and "median_ms" in full:
            lines.append(_line(label, "full resolution (sampled frames)", full, None))
        for name in VARIANTS:
            for x in v.get(name, []):
                own = x.get("key_sse") in (None, r["config"]["key_sse"])
                run = name if own else f"{name}, keyframes {x['key_sse']:g} px"
                lines.append(_line(label, run, x,
                                   ee[(name, x.get("key_sse"), x["epsilon"])]))
    return lines


def equal_table(r: dict) -> list[str]:
    lines = ["| side | path | adaptive RMSE / FLIP (reported) | best LOD-sprite within both "
             "(chosen frames), its figures on the reported frames | rows within chosen / "
             "reported / measured |", "|---|---|---|---|---|"]
    for key, res in _stores(r):
        for p, e in r["equal_error_speedup"].get(key, {}).items():
            b = e["best"]
            best = ("none" if b is None else f"{b['variant']} ε {b['epsilon']:g}: "
                    f"{f(b['speedup'], 2)}× (RMSE {f(b['rmse'], 2)}, FLIP {f(b['flip'], 3)})")
            ok = sum(x["within"] for x in e["rows"])
            held = sum(x["within_reported"] for x in e["rows"])
            lines.append(f"| {_label(key, res)} | {p} | {f(e['adaptive_rmse'], 2)} / "
                         f"{f(e['adaptive_flip'], 3)} | {best} | {ok} / {held} / "
                         f"{len(e['rows'])} |")
    return lines


def reference_table(r: dict) -> list[str]:
    """How each side's reference (level 0) was made, and the adaptive renderer at 0.25 px
    against it, a validation figure (sides checked without timed runs too)."""
    lines = ["| side | path | reference (level 0) | frames | validation | validation vs "
             "level 0 RMSE / FLIP |", "|---|---|---|---|---|---|"]
    sides = sorted((k for k in r["reference"] if k.isdigit()), key=int)
    for key in [*sides, *sorted(k for k in r["reference"] if not k.isdigit())]:
        label = f"{key}²" if key.isdigit() else key
        for p, d in r["reference"][key].items():
            check = ("—" if "stand_in_rmse" not in d else
                     f"{f(d['stand_in_rmse'], 2)} / {f(d['stand_in_flip'], 3)}")
            note = "" if d.get("timed", True) else " (check only, no timed runs)"
            lines.append(f"| {label}{note} | {p} | {d['level0']} | {d['level0_frames']} | "
                         f"{d.get('stand_in', '—')} | {check} |")
    return lines


def _skipped(r: dict) -> list[str]:
    seen: dict[str, str] = {}
    for _, res in _stores(r):
        for p in r["config"]["paths"]:
            seen.update(res[p].get("skipped", {}))
    return [f"- `{k}` skipped: {why}." for k, why in seen.items()]


def memory_lines(r: dict) -> list[str]:
    """What loading each store's scene adds to a run's peak memory (the in-memory working
    grid ``render`` makes of a store; the adaptive renderer never draws it)."""
    lines = ["Every run's peak RSS (its process and the tile reader's) includes the scene "
             "``render`` loads for a store: an in-memory working grid resampled from the "
             "finest level up to 4096², which the adaptive renderer never draws (only its "
             "texture colours it). What that load adds to a process's peak:", ""]
    for key, res in _stores(r):
        s = res.get("scene_load")
        if s:
            lines.append(f"- {_label(key, res)}: +{f(s['scene_load_mb'], 0)} MB over "
                         f"{f(s['peak_rss_mb_imports'], 0)} MB after the imports "
                         f"(working grid {s['grid']}²).")
    return lines


def _patrol(r: dict) -> list[str]:
    pt = r["patrol"]
    if "skipped" in pt:
        return [f"Skipped: {pt['skipped']}."]
    a, b = pt["without_cache"], pt["with_cache"]
    cut = "—" if pt["keyframe_work_cut"] is None else f"{f(pt['keyframe_work_cut'], 2)}×"
    return [f"{pt['side']}², whole keyframes, ε {pt['epsilon']:g} px; {pt['work']} without "
            f"the cache {a[pt['work']]}, with {pt['cache_mb']:g} MB {b[pt['work']]} "
            f"(cut {cut}); cache hits {b.get('cache_hits', '—')}; total "
            f"{f(a['total_s'], 2)} s against {f(b['total_s'], 2)} s "
            f"({f(pt['speedup'], 2)}×); RMSE / FLIP {f(a['rmse'], 2)} / {f(a['flip'], 3)} "
            f"without, {f(b['rmse'], 2)} / {f(b['flip'], 3)} with (at equal error: "
            f"{_yes(pt.get('equal_error', False))})."]


def _jacksboro(r: dict) -> list[str]:
    j = r.get("jacksboro")
    if j is None:
        return []
    return ["", "## 512² jacksboro, chen1999", "",
            f"LOD-sprite with adaptive keyframes: {f(r['speedup_sprite_vs_full_512'], 2)}× "
            f"faster than full resolution (plain LOD-sprite in the same run: "
            f"{f(j['speedup_plain_sprite'], 2)}×); RMSE against the plain 16² level "
            f"{f(r['rmse_ratio_sprite_vs_lod_512'], 3)} (plain LOD-sprite "
            f"{f(j['rmse_ratio_plain_sprite'], 3)}); {j['keyframes']} keyframes of "
            f"{f(j['mean_ms_keyframe'], 1)} ms, spriteframes {f(j['mean_ms_sprite'], 2)} ms."]


def write_outputs(r: dict, out_dir: Path) -> Path:
    """results.json, ``large_scaling.png`` and ``report.md`` into ``out_dir``."""
    out_dir = Path(out_dir)
    write_json(out_dir / "results.json", r)
    plot = _plot(r, out_dir / "large_scaling.png")
    c = r["config"]
    lines = ["# Large terrain — large", "",
             f"Fractal stores (tiled, seamless), {c['frames']} frames at {c['image']}² along "
             f"each path; adaptive at {c['sse']} px; LOD-sprite with keyframes by the "
             f"adaptive renderer at {c['key_sse']} px, each variant at ε in {c['eps']} px "
             f"({_variants_line()}). "
             "Every run, adaptive's and LOD-sprite's alike, is warmed up untimed at its "
             "first viewpoint (shaders compiled, the first view's tiles resident): that "
             "warm-up is the column *first frame ms* and is in no other figure; *first "
             "frame s* is when it was done, from the run's process start.  Timed runs write "
             "nothing per frame; errors (RMSE in grey levels / mean FLIP) on the sampled "
             "frames of the untimed replay, against the reference of each side (below), "
             "in two interleaved halves: rows are chosen on frames "
             f"{r['chosen_frames']} and every error reported is of frames "
             f"{r['reported_frames']}.  Speedups: adaptive's total time over the row's (the "
             "whole path).  At equal error: the fastest row whose RMSE and FLIP are both at "
             "most adaptive's on the chosen frames, its errors those of the reported "
             "frames; every row measured is in the tables."]
    for p in c["paths"]:
        lines += ["", f"## Path {p}", "", *path_rows(r, p)]
    lines += ["", "## Error–time frontiers", "", *frontier_lines(r, out_dir),
              "", "## At equal error", "", *equal_table(r), "", *_skipped(r),
              "", "## Reference", "", *reference_table(r),
              "", "## Memory", "", *memory_lines(r),
              "", "## Patrol: the keyframe cache", "", *_patrol(r), *_jacksboro(r)]
    h = r["huge"]
    lines += ["", f"65536²: needs up to {f(h['need_gb'], 1)} GB of disk (float32, all levels); "
                  f"{f(h['free_gb'], 1)} GB free here; run with `--huge`.", "",
              "GPU memory in use: the adaptive renderer's GPU cache is a fixed atlas of the "
              "budget (`--gpu-mb`, 256 MB by default), allocated at start; llvmpipe has no "
              "query for the memory a driver holds.", "",
              f"![scaling]({plot.name})", ""]
    report = out_dir / "report.md"
    atomic_write_bytes(report, "\n".join(lines).encode())
    return report


def _variants_line() -> str:
    """What each LOD-sprite variant is, in a few words."""
    def one(name: str, o: dict) -> str:
        tiles = f"{o['tiles']}×{o['tiles']} tiles" if o.get("tiles", 1) > 1 else "whole keyframes"
        cache = f", a {o['cache_mb']:g} MB cache" if o.get("cache_mb") else ""
        return (f"`{name}`: {tiles}{cache}, proxy at {o.get('proxy_sse')} px, metric "
                f"{o.get('metric', 'warp')}")
    return "; ".join(one(k, v) for k, v in VARIANTS.items())


def _speed(v: float | None, at_least: float | None = None) -> str:
    if v is None and at_least is not None:
        return f"≥ {f(at_least, 2)}× (its fastest run is below the level)"
    return "— (not reached)" if v is None else f"{f(v, 2)}×"


def frontier_lines(r: dict, out_dir: Path) -> list[str]:
    """Per store and path: each level's error and both frontiers' times there (median),
    the speedups by the median and the p99, and the plot of both frontiers."""
    lines = ["Each technique along its own knobs (adaptive: its tolerance; LOD-sprite: ε, "
             "keyframe tolerance, whole or tiled keyframes); a technique's frontier is the "
             "lower envelope of its runs, chosen on the chosen frames and drawn with the "
             "reported frames' RMSE.  A level is adaptive's own RMSE at that tolerance; "
             "the speedup is adaptive's frontier time over LOD-sprite's at that error, "
             "interpolated in log time between measured runs, never extrapolated "
             "(not reached: LOD-sprite's frontier has no run at or beyond that error; "
             "≥: LOD-sprite's fastest run is already below that error, the speedup is at "
             "least that run's).", "",
             "| side | path | level | RMSE | adaptive frontier ms | LOD-sprite frontier ms | "
             "speedup (median) | speedup (p99) |", "|---|---|---|---|---|---|---|---|"]
    plots = []
    for key, res in _stores(r):
        for p, block in r.get("frontier", {}).get(key, {}).items():
            speed, p99 = r["frontier_speedup"][key][p], r["frontier_speedup_p99"][key][p]
            bound = block.get("speedup_at_least", {})
            for name in LEVELS:
                e = block["levels"][name]
                lo, lo99 = (bound.get(t, {}).get(name) for t in ("median_ms", "p99_ms"))
                lines.append(f"| {_label(key, res)} | {p} | {name} | {_cell(e, 2)} | "
                             f"{_ms_at(block, 'adaptive', e)} | {_ms_at(block, SPRITE, e)} | "
                             f"{_speed(speed[name], lo)} | {_speed(p99[name], lo99)} |")
            png = plot_frontier(block, out_dir / f"frontier_{key}_{p}.png",
                                f"{_label(key, res)}, {p}")
            plots.append(f"![frontier {key} {p}]({png.name})")
    return [*lines, "", *plots]


def _ms_at(block: dict, tech: str, error: float | None) -> str:
    if error is None:
        return "—"
    t = time_at_error(curve(block[tech], "median_ms")[0], error)
    return "—" if t is None else f(t, 2)
