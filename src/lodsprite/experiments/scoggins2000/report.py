"""Plots, images and a Markdown report for the Scoggins, Machiraju & Moorhead (2000)
LOD-matching reproduction (:func:`lodsprite.experiments.scoggins2000.run.reproduce_scoggins2000`).

Our analogues of the paper's Figures 5-8, the two profile tables, ``results.json`` and
``report.md`` with every measured number beside the paper's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lodsprite.experiments.paper_numbers import PAPER_2000
from lodsprite.files import atomic_write_bytes, save_figure, write_json, write_png
from lodsprite.report.values import fmt_fixed


def _fig5(r: dict, path: Path) -> Path:
    s = r["spiral"]
    fig = Figure(figsize=(6.5, 4), dpi=110)
    ax = fig.add_subplot()
    d = np.array(s["distances"])
    ax.plot(d, s["triangles_nocsf"], "o-", label="no CSF (Eq. 7)")
    ax.plot(d, s["triangles_csf"], "s-", label="CSF (Eq. 16)")
    ax.axhline(r["snowflake_triangles_full"], color="k", lw=0.8, ls="--",
               label=f"full resolution ({r['snowflake_triangles_full']:,})")
    ax.set(xscale="log", yscale="log", xlabel="viewing distance (sphere diameters)",
           ylabel="triangles per sphereflake",
           title="Fig. 5 — sphereflake triangles vs distance")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path)


def _fig6a(r: dict, path: Path) -> Path:
    z = np.array(r["mountain"]["z"]) / 1000.0
    fig = Figure(figsize=(9, 3.8), dpi=110)
    for n, (key, title) in enumerate((("nocsf", "Eq. 7 (no CSF)"), ("csf", "Eq. 16 (CSF)"))):
        ax = fig.add_subplot(1, 2, n + 1)
        for v in r["mean_error"].values():
            ax.plot(z, v[key], "o-", ms=3,
                    label=f"θ = {v['theta_deg']:.0f}°, φ = {v['phi_deg']:.0f}°")
        ax.set(yscale="log", xscale="log", xlabel="viewing distance z (km)",
               ylabel="mean error over LODs", title=f"Fig. 6a — mountain, {title}")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return save_figure(fig, path)


def _fig6b(r: dict, path: Path) -> Path:
    s = r["sweep"]
    d = np.array(s["distances"]) / 1000.0
    fig = Figure(figsize=(6.5, 4), dpi=110)
    ax = fig.add_subplot()
    ax.step(d, s["faces_nocsf"], where="mid", label="no CSF")
    ax.step(d, s["faces_csf"], where="mid", label="CSF")
    ax.axhline(s["full_faces"], color="k", lw=0.8, ls="--", label="full TIN")
    ax.set(xlabel="viewing distance (km)", ylabel="mountain triangles",
           title=f"Fig. 6b — mountain sweep, {s['fov_deg']:.0f}° field of view")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def _fig7(images: dict, path: Path) -> Path:
    fig = Figure(figsize=(8, 8.4), dpi=110)
    titles = (("fig7a_full", "(a) full-resolution spheres"),
              ("fig7b_lod_csf", "(b) LOD spheres from the CSF profile"),
              ("fig7c_lod_coded", "(c) LOD number: red high, green low"),
              ("fig7d_error", "(d) |a − b| × 4"))
    for n, (key, title) in enumerate(titles):
        ax = fig.add_subplot(2, 2, n + 1)
        ax.imshow(images[key], cmap="gray" if images[key].ndim == 2 else None,
                  interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.suptitle("Fig. 7 — sphereflake spiral, nearest top left, farthest at the centre")
    fig.tight_layout()
    return save_figure(fig, path)


def _crop_box(img: np.ndarray, margin: int = 6) -> tuple[slice, slice]:
    mask = img.max(axis=-1) > 0
    if not mask.any():
        return slice(None), slice(None)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    side = max(rows[-1] - rows[0], cols[-1] - cols[0]) + 2 * margin
    cr, cc = (rows[0] + rows[-1]) // 2, (cols[0] + cols[-1]) // 2
    r0, c0 = max(cr - side // 2, 0), max(cc - side // 2, 0)
    return slice(r0, r0 + side), slice(c0, c0 + side)


def _fig8(r: dict, images: dict, path: Path) -> Path | None:
    rows = sorted({k.split("_")[1] for k in images if k.startswith("fig8_")}, key=int)
    if not rows:
        return None
    dists = r["sweep"]["fig8_distances"]
    fig = Figure(figsize=(8, 2.7 * len(rows)), dpi=110)
    cols = (("full", "(a) full TIN"), ("nocsf", "(b) profile, no CSF"), ("csf", "(c) profile, CSF"))
    for i, row in enumerate(rows):
        box = _crop_box(images[f"fig8_{row}_full"])
        for j, (key, title) in enumerate(cols):
            ax = fig.add_subplot(len(rows), 3, 3 * i + j + 1)
            ax.imshow(images[f"fig8_{row}_{key}"][box], interpolation="nearest")
            ax.set_title(f"{title}, {dists[i] / 1000:.1f} km", fontsize=8)
            ax.axis("off")
    fig.suptitle("Fig. 8 — mountain, cropped to its extent (colour: LOD, red high, green low; "
                 "white full)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def write_outputs(results: dict, out_dir: Path) -> tuple[Path, list[Path]]:
    """Write results.json, the two tables, figure PNGs and report.md; return (report, plots)."""
    out_dir = Path(out_dir)
    images, tables = results.get("_images", {}), results.get("_tables", {})
    plain = {k: v for k, v in results.items() if not k.startswith("_")}
    write_json(out_dir / "results.json", plain)
    for name, table in tables.items():
        table.save(out_dir / f"profile_{name}.npz")
    for key in ("fig7a_full", "fig7b_lod_csf", "fig7c_lod_coded"):
        if key in images:
            write_png(out_dir / f"{key}.png", images[key])
    plots = [_fig5(results, out_dir / "fig05_snowflake_triangles.png"),
             _fig6a(results, out_dir / "fig06a_mean_error.png"),
             _fig6b(results, out_dir / "fig06b_mountain_triangles.png")]
    if "fig7a_full" in images:
        plots.append(_fig7(images, out_dir / "fig07_spiral.png"))
    fig8 = _fig8(results, images, out_dir / "fig08_mountain.png")
    if fig8 is not None:
        plots.append(fig8)
    return write_report(plain, out_dir, plots), plots


def write_report(r: dict, out_dir: Path, plots: list[Path]) -> Path:
    p = PAPER_2000
    sph, mnt = r["sphere"], r["mountain"]
    lines = [
        "# Scoggins, Machiraju & Moorhead (2000) LOD matching — scoggins2000", "",
        f"LOD sphere family: {len(sph['faces'])} levels, {sph['faces'][0]:,}–"
        f"{sph['faces'][-1]:,} triangles (paper: 19 levels up to {p['sphere_faces_full']:,}). "
        f"Mountain: `{r['config']['terrain']}`, full TIN {mnt['faces'][-1]:,} faces, LODs "
        f"{', '.join(f'{f:,}' for f in mnt['faces'][:-1])} (paper: 8,538; 1,000..7,000). "
        f"Profiles: {sph['views']} views, {sph['image_size']}² px, {len(sph['z'])} (sphere) and "
        f"{len(mnt['z'])} (mountain) distances, z0 = 9 bounding diameters, field of view "
        f"{sph['fov_deg']:.2f}° / {mnt['fov_deg']:.2f}° from the bounding sphere "
        f"(paper: 10°/7° set by hand); workers: {sph['workers']}.", "",
        "| quantity | this run | paper |", "|---|---|---|",
        f"| profile generation, sphere family | {fmt_fixed(r['profile_s_sphere'], 1)} s | "
        f"{p['profile_min_sphere']} min (1 view) |",
        f"| profile generation, mountain | {fmt_fixed(r['profile_s_mountain'], 1)} s | "
        f"{p['profile_min_mountain']} min |",
        f"| sphereflake, full-resolution triangles | {r['snowflake_triangles_full']:,} "
        f"({r['spiral']['spheres_per_flake']} spheres) | {p['snowflake_triangles_full']:,} |",
        f"| sphereflake at the spiral's far end, CSF | {r['snowflake_triangles_far_csf']:,} "
        f"({fmt_fixed(r['snowflake_reduction_far_csf'], 0)}× fewer) | (Fig. 5) |",
        f"| sphereflake at the spiral's far end, no CSF | "
        f"{r['snowflake_triangles_far_nocsf']:,} "
        f"({fmt_fixed(r['snowflake_reduction_far_nocsf'], 0)}× fewer) | (Fig. 5) |",
        f"| sphereflake thresholds (the paper's), no CSF / CSF | {p['threshold_nocsf']:g} / "
        f"{p['threshold_csf']:g} | {p['threshold_nocsf']:g} / {p['threshold_csf']:g} |",
        f"| the paper's threshold rule (LOD L−2 at z0) on our sphere table | "
        f"{sph['rule_thresholds']['nocsf']:.3g} / {sph['rule_thresholds']['csf']:.3g} | |",
        f"| mountain thresholds (the rule on our mountain table) | "
        f"{mnt['rule_thresholds']['nocsf']:.3g} / {mnt['rule_thresholds']['csf']:.3g} | "
        "(in its Fig. 6b) |", "",
        "## Profile selection vs geometric screen-space error at equal triangles", "",
        "Profile selection uses the CSF table at the scene's threshold above; "
        "screen-space-error "
        "selection (Hausdorff distance to the full model projected to pixels, the coarsest "
        "LOD within a tolerance) gets the pixel tolerance whose total triangle count is the "
        "largest not above the profile's. Both are compared with full-resolution renders.", "",
        "| scene | images | triangles profile / SSE / full | SSE tolerance px | "
        "RMSE profile / SSE | FLIP profile / SSE | SSIM profile / SSE |",
        "|---|---|---|---|---|---|---|"]
    for name, c in r["comparison"].items():
        lines.append(
            f"| {name} | {c['images']} | {c['triangles_profile']:,} / {c['triangles_sse']:,} / "
            f"{c['triangles_full']:,} | {fmt_fixed(c['sse_tolerance_px'], 2)} | "
            f"{fmt_fixed(c['rmse_profile'], 3)} / {fmt_fixed(c['rmse_sse'], 3)} | "
            f"{fmt_fixed(c['flip_profile'], 4)} / {fmt_fixed(c['flip_sse'], 4)} | "
            f"{fmt_fixed(c['ssim_profile'], 4)} / {fmt_fixed(c['ssim_sse'], 4)} |")
    win = "profile" if r["rmse_profile"] < r["rmse_sse"] else "screen-space error"
    lines += ["", f"Over all {sum(c['images'] for c in r['comparison'].values())} images: RMSE "
                  f"{fmt_fixed(r['rmse_profile'], 3)} (profile) vs {fmt_fixed(r['rmse_sse'], 3)}"
                  f" (SSE), FLIP {fmt_fixed(r['flip_profile'], 4)} vs "
                  f"{fmt_fixed(r['flip_sse'], 4)}: lower RMSE with {win} selection.", "",
              "Times are measured in this run on this machine; the paper's are from a dual "
              "600 MHz Pentium III. The sphereflakes use the paper's threshold values; the "
              "paper's rule for choosing them gives far smaller values on our sphere table "
              "(above), which would keep nearly full spheres everywhere. The mountain uses "
              "the rule. Without the CSF (Eq. 7) the DC term dominates both sums, so an "
              "LOD's error hardly falls with distance and selection barely coarsens; with "
              "the CSF (Eq. 16) it does.", ""]
    lines += [f"![{q.stem}]({q.name})" for q in plots]
    path = Path(out_dir) / "report.md"
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    return path
