"""Benchmark: a digest of each reproduction's deterministic figures (issue 31, must-have 8).

Runs every reproduction in a short configuration (:data:`RUNS`), one after another, each
in a process of its own, then reads from each run's ``results.json`` the figures that come
from deterministic decisions only and writes them to one JSON digest (reproduction ->
figure -> value).  The digest taken before a change of the code compared with the one
taken after shows whether the change altered any decision.

    python benchmarks/reproduce_digest.py [--out DIR] [--only NAME ...] [--keep-going]
    python benchmarks/reproduce_digest.py --out DIR --from-runs   # re-read DIR's outputs
    python benchmarks/reproduce_digest.py --compare BEFORE.json AFTER.json

``DIR/runs/NAME`` holds each reproduction's outputs (``DIR/runs/NAME.log`` its output),
``DIR/cache`` the runs' own profile cache (``$LODSPRITE_CACHE``), ``DIR/digest.json`` the
digest.  ``--compare`` exits 1 when a figure differs or is
missing after.

What is kept: never times, rates, shares of time or memory (:data:`TIMED`), inputs,
the machine or paths (:data:`NEVER`); of each reproduction what :data:`SELECT` keeps,
which leaves out the runs whose decisions follow measured time; and not the figures
that two runs of one commit gave different values (:data:`UNSTABLE`).  Three runs of
commit 3395c6c on the shared 2-core machine (two for the reduced swan2002 and large)
gave every kept figure equal to the digit, so :data:`UNSTABLE` is empty; the same runs
showed each part :data:`SELECT` leaves out to differ between runs (swan2002's other
set-ups, sloan1997's time-critical runs, gumbau's ``crowd_target``, battlefield's
scheduler and independent runs, large's tiled variants: keyframes, extractions,
triangles, tiles and errors alike).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

#: name -> the ``reproduce`` arguments of its short run (the fastest each offers), or
#: Python code run with the output folder as ``sys.argv[1]`` where that is still long
#: for what the digest keeps of it:
#:
#: * swan2002: ``--quick --size 128 --no-links`` with the ``inline`` set-up alone (the
#:   others are processes whose decisions follow time, none in the digest; with all of
#:   them it took 109 s on a quiet machine and 230 s on a loaded one, inline alone 47 s
#:   on the loaded one);
#: * large: its quick configuration on the 256² store alone, not the 512² one, and the
#:   ``whole`` variant alone (the tiled ones follow time, none in the digest), through
#:   the API: ``large --quick`` took 573 s here, its 256² store alone with every variant
#:   555 s under heavier load.
RUNS: dict[str, list[str] | str] = {
    "chen1999": ["--quick"],
    "swan2002": ("import sys; import lodsprite.experiments.swan2002.run as run; "
                 "run.SETUPS = {'inline': None}; from lodsprite.cli import main; "
                 "main(['reproduce', 'swan2002', '--quick', '--size', '128', '--no-links', "
                 "'--out', sys.argv[1]])"),
    "scoggins2000": ["--quick"],
    "sloan1997": ["--quick"],
    "gumbau": ["--quick"],
    "large": ("import sys; from dataclasses import replace; from pathlib import Path; "
              "from lodsprite.experiments import get; "
              "from lodsprite.experiments.large.run import LargeConfig; "
              "get('large').run(replace(LargeConfig.quick(), sizes=(256,), variants=('whole',)), "
              "Path(sys.argv[1]), None)"),
    "battlefield": ["--quick"],
    "timecritical": ("import sys; from pathlib import Path; from lodsprite.experiments import get; "
                     "from lodsprite.experiments.timecritical.run import TimeCriticalConfig; "
                     "get('timecritical').run(TimeCriticalConfig(terrain='fractal:64:3', "
                     "path='chen1999', size=48, seconds=0.6, samples=2), Path(sys.argv[1]), "
                     "None)"),
}
CLI = "from lodsprite.cli import main; main()"

#: A figure with a part of its name holding one of these words is a measured time (or a
#: rate, a ratio or share of times, or memory): never in the digest.
TIMED = re.compile(r"(^|_)(ms|s|seconds|fps|hz|speedup|rss|jitter|time|wall|elapsed|share)(_|$)")
#: Names no reproduction's digest keeps: its inputs, the machine and its free disk, and
#: memory measured from the process's resident size.
NEVER = re.compile(r"^(config|paper_thresholds|huge)\.|(^|\.)(gl_renderer|gl_version|machine|"
                   r"python|cpus|workers|scene_file|lumigraph|report|scene_load_mb)$")
#: name -> (kept figures, dropped figures): regular expressions on the dotted names of
#: ``results.json``.  A figure is kept when it matches the first and not the second.
#: What is dropped here are decisions that depend on measured time:
#:
#: * swan2002: every set-up but ``inline`` (which keyframe the client shows depends on when
#:   the server's arrive), ``prediction`` (ahead by the measured δt), ``policies``;
#: * sloan1997: the time-critical runs (``critical``, ``critical_frames``,
#:   ``quality_vs_*``: the choice of images each frame follows the measured frame time
#:   and its fitted cost scale);
#: * gumbau: ``crowd_target`` (its LOD exponent is fed back from measured frame times);
#: * battlefield: ``scheduler`` and ``independent`` (both hold a frame budget by measured
#:   time), pooled or per path;
#: * timecritical: every run (each is played in real time: what it shows follows the
#:   clock); kept are the reference's description and how many reference images it drew;
#: * large: the ``tiled`` and ``tiled+cache`` variants (their tiles are refreshed within
#:   ``tile_budget_ms`` of measured time a frame) and ``equal_error_speedup`` (its best
#:   row is the fastest; its other figures repeat the rows');
SELECT: dict[str, tuple[str, str]] = {
    "chen1999": (r".", r"^images\.fig1[34]\.(full|lod|sprite|keyframe_image|diff_\w+)$"),
    "swan2002": (r"^inline\.", r"^$"),
    "scoggins2000": (r".", r"^$"),
    "sloan1997": (r".", r"^(critical|critical_frames|quality_vs_texture_mb|quality_vs_target)\."),
    "gumbau": (r".", r"^runs\.crowd_target\.|^frame_ms_|^target_fps$"),
    "large": (r".", r"^equal_error_speedup\.|^sizes\.\d+\.\w+\.tiled"),
    "battlefield": (r".", r"(^|\.)(scheduler|independent)\."),
    "timecritical": (r"^(reference|reference_images|path|terrain)$", r"^$"),
}
#: Figures that differed between two runs of the same code (dropped from the digest):
#: name -> figure names.  Measured by running the digest twice on one commit.
UNSTABLE: dict[str, tuple[str, ...]] = {}
#: Images each run writes whose pixels come from deterministic decisions only: their
#: SHA-256 is a figure (``png.NAME``).
IMAGES: dict[str, tuple[str, ...]] = {
    "chen1999": ("fig13_full.png", "fig13_lod.png", "fig13_sprite.png",
                 "fig13_keyframe_image.png", "fig14_full.png", "fig14_lod.png",
                 "fig14_sprite.png", "fig14_keyframe_image.png"),
    "scoggins2000": ("fig7a_full.png", "fig7b_lod_csf.png", "fig7c_lod_coded.png"),
}


def run_all(out: Path, only: list[str], keep_going: bool) -> dict[str, float]:
    """Run each reproduction in turn into ``out/runs/NAME``; wall seconds each."""
    seconds = {}
    for name in only:
        run_dir = out / "runs" / name
        how = RUNS[name]
        cmd = ([sys.executable, "-c", how, str(run_dir)] if isinstance(how, str) else
               [sys.executable, "-c", CLI, "reproduce", name, *how, "--out", str(run_dir)])
        t0 = time.perf_counter()
        # A cache of this digest's own: a profile cached by another commit's code (its
        # key covers the inputs, not the code) would hide a change in how it is built.
        env = {**os.environ, "LODSPRITE_CACHE": str(out / "cache")}
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        seconds[name] = time.perf_counter() - t0
        (out / "runs").mkdir(parents=True, exist_ok=True)
        (out / "runs" / f"{name}.log").write_text(proc.stdout + proc.stderr)
        print(f"{name}: {seconds[name]:.0f} s, exit {proc.returncode}", flush=True)
        if proc.returncode != 0 and not keep_going:
            sys.exit(f"reproduce {name} failed (exit {proc.returncode}); see "
                     f"{out / 'runs' / (name + '.log')}")
    return seconds


Value = int | float | str | bool | None | list


def flatten(obj, prefix: str = "") -> dict[str, Value]:
    """``obj`` (parsed JSON) as dotted name -> value; a list of plain values (or of lists
    of them) stays one value, a list holding objects is numbered."""
    if isinstance(obj, dict):
        out: dict[str, Value] = {}
        for k, v in obj.items():
            out.update(flatten(v, f"{prefix}{k}."))
        return out
    if isinstance(obj, list) and any(isinstance(_leaf(v), dict) for v in obj):
        out = {}
        for i, v in enumerate(obj):
            out.update(flatten(v, f"{prefix}{i}."))
        return out
    return {prefix[:-1]: obj}


def _leaf(v):
    while isinstance(v, list) and v:
        v = v[0]
    return v


def _names_a_file(v: Value) -> bool:
    """Whether ``v`` holds a path (it names the run's own folder)."""
    if isinstance(v, list):
        return any(_names_a_file(x) for x in v)
    return isinstance(v, str) and "/" in v


def is_timed(name: str) -> bool:
    """Whether any part of the dotted ``name`` says it is a time, rate or memory figure."""
    return any(TIMED.search(part) for part in name.split("."))


def extract(name: str, run_dir: Path) -> dict[str, Value]:
    """The deterministic figures of reproduction ``name`` from its outputs in ``run_dir``."""
    keep, drop = (re.compile(x) for x in SELECT[name])
    unstable = set(UNSTABLE.get(name, ()))
    results = json.loads((run_dir / "results.json").read_text())
    figures = {k: v for k, v in flatten(results).items()
               if keep.search(k) and not drop.search(k) and not NEVER.search(k)
               and not is_timed(k) and k not in unstable
               and not _names_a_file(v)}
    for png in IMAGES.get(name, ()):
        f = run_dir / png
        if f"png.{png}" not in unstable:
            figures[f"png.{png}"] = (hashlib.sha256(f.read_bytes()).hexdigest()
                                     if f.exists() else None)
    return dict(sorted(figures.items()))


def same(a: Value, b: Value) -> bool:
    """Equal to the digit: integers, strings and flags exactly, other numbers to six
    significant digits (1e-9 absolute near zero), NaN equal to NaN, lists element by
    element."""
    if isinstance(a, list) or isinstance(b, list):
        return (isinstance(a, list) and isinstance(b, list) and len(a) == len(b)
                and all(same(x, y) for x, y in zip(a, b, strict=True)))
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if not (isinstance(a, int | float) and isinstance(b, int | float)):
        return a == b
    if isinstance(a, int) and isinstance(b, int):
        return a == b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    # a figure written rounded to six digits (a CSV column) equals its full value
    return f"{a:.6g}" == f"{b:.6g}" or math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9)


def show(v: Value) -> str:
    """A short text for a figure's value."""
    if isinstance(v, list):
        head = ", ".join(show(x) for x in v[:4])
        return f"[{head}{', …' if len(v) > 4 else ''}] ({len(v)})"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)[:20] if isinstance(v, str) and len(v) == 64 else str(v)


def differences(before: dict, after: dict) -> tuple[list, list, list]:
    """``(equal, differing, new)`` figure names ``(reproduction, figure)``; a figure
    before and missing after differs."""
    equal, differing, new = [], [], []
    for name in sorted(set(before) | set(after)):
        b, a = before.get(name, {}), after.get(name, {})
        for fig in sorted(set(b) | set(a)):
            if fig not in b:
                new.append((name, fig))
            elif fig in a and same(b[fig], a[fig]):
                equal.append((name, fig))
            else:
                differing.append((name, fig))
    return equal, differing, new


def compare(before_file: Path, after_file: Path, renames: list[str] = ()) -> int:
    """Print which figures are equal to the digit and which differ; 1 on a difference.
    ``renames``: ``OLD:NEW`` parts of figure names the code renamed between the two
    (e.g. ``rmse_sprite:rmse``), applied to BEFORE's names."""
    before = json.loads(before_file.read_text())["figures"]
    for old, _, new in (r.partition(":") for r in renames):
        before = {run: {fig.replace(old, new): v for fig, v in figs.items()}
                  for run, figs in before.items()}
    after = json.loads(after_file.read_text())["figures"]
    equal, differing, new = differences(before, after)
    for name in sorted(set(before) | set(after)):
        n_eq = sum(1 for r, _ in equal if r == name)
        n_b = len(before.get(name, {}))
        print(f"{name}: {n_eq} of {n_b} figures equal to the digit")
    for name, fig in differing:
        b, a = before[name].get(fig, "(missing)"), after.get(name, {}).get(fig, "(missing)")
        print(f"DIFFERS {name} {fig}: before {show(b)}  after {show(a)}")
    for name, fig in new:
        print(f"new     {name} {fig}: {show(after[name][fig])}")
    print(f"{len(equal)} equal, {len(differing)} differ, {len(new)} new")
    return 1 if differing else 0


def table(figures: dict[str, dict[str, Value]]) -> None:
    """Print the digest: one line a figure under its reproduction."""
    for name, figs in figures.items():
        print(f"== {name}: {len(figs)} figures")
        for fig, v in figs.items():
            print(f"  {fig:<58} {show(v)}")


def _commit() -> str:
    proc = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True)
    return proc.stdout.strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/digest"))
    ap.add_argument("--only", nargs="*", choices=list(RUNS), default=list(RUNS))
    ap.add_argument("--keep-going", action="store_true",
                    help="run the others when one reproduction fails")
    ap.add_argument("--from-runs", action="store_true",
                    help="read the outputs already in OUT/runs; run nothing")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--quiet", action="store_true", help="no table")
    ap.add_argument("--rename", action="append", default=[], metavar="OLD:NEW",
                    help="with --compare: a part of BEFORE's figure names the code renamed")
    args = ap.parse_args()
    if args.compare:
        sys.exit(compare(*args.compare, args.rename))
    args.out.mkdir(parents=True, exist_ok=True)
    if args.from_runs:  # the times of the run that wrote them, where it saved them
        saved = args.out / "seconds.json"
        seconds = json.loads(saved.read_text()) if saved.exists() else {}
    else:
        seconds = run_all(args.out, args.only, args.keep_going)
        (args.out / "seconds.json").write_text(json.dumps(seconds, indent=1))
    figures = {name: extract(name, args.out / "runs" / name) for name in args.only
               if (args.out / "runs" / name / "results.json").exists()}
    seconds = {k: v for k, v in seconds.items() if k in args.only}
    digest = {"commit": _commit(), "seconds": seconds, "unstable": UNSTABLE,
              "figures": figures}
    (args.out / "digest.json").write_text(json.dumps(digest, indent=1, allow_nan=True))
    if not args.quiet:
        table(figures)
    print(f"digest: {args.out / 'digest.json'} ({sum(map(len, figures.values()))} figures, "
          f"{sum(seconds.values()):.0f} s of runs)")


if __name__ == "__main__":
    main()
