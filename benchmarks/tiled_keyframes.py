"""Whole against tiled keyframes on a fractal store's flyover (issue 22, must-have 5; Qu,
Wan, Qin & Kaufman 2000: part of the image re-rendered every frame under a budget).

For each ``--tiles`` value (1 = whole keyframes, the 1999 algorithm), one timed run of
``lodsprite render --mode sprite --key-sse PX --path flyover --ground-truth`` on the store:
median and p99 frame time and their ratio (the target: p99 at most 1.5x the median on the
16k² flyover), keyframes, tiles rendered, and the RMSE of the untimed replay against full
resolution.  Timings on a shared machine are noisy: rerun before quoting.

    python benchmarks/tiled_keyframes.py [--store STORE.zarr | --side 1024] [--tiles 1 4]
        [--frames 120] [--size 256x256] [--key-sse 1.0] [--epsilon 1.0]
        [--tile-budget-ms 8] [--out DIR]

Without ``--store`` a ``fractal:SIDE`` store is built in a temporary folder
(``lodsprite tile``); a 16k² one takes a while: build it once with ``lodsprite tile
fractal:16384 --out fractal_16384.zarr`` and pass ``--store``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

CLI = [sys.executable, "-c", "from lodsprite.cli import main; main()"]
KEYS = ("median_ms", "p99_ms", "keyframes", "tiles_rendered", "rmse_mean", "mean_error_px")


def run(store: str, tiles: int, args: argparse.Namespace, out: Path) -> dict:
    """One timed run (and its untimed replay); the figures of its summary.json."""
    cmd = ["render", "--terrain", store, "--mode", "sprite", "--key-sse", str(args.key_sse),
           "--path", "flyover", "--frames", str(args.frames), "--size", args.size,
           "--epsilon", str(args.epsilon), "--ground-truth", "--tiles", str(tiles),
           "--tile-budget-ms", str(args.tile_budget_ms), "--out", str(out)]
    subprocess.run(CLI + cmd, check=True, stdout=subprocess.DEVNULL)
    s = json.loads((out / "summary.json").read_text())
    row = {k: s.get(k) for k in KEYS}
    row["tiles"] = tiles
    row["p99_over_median"] = s["p99_ms"] / s["median_ms"]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", help="a terrain store (default: build fractal:SIDE)")
    ap.add_argument("--side", type=int, default=1024, help="side of the fractal store built")
    ap.add_argument("--tiles", type=int, nargs="+", default=[1, 4])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--key-sse", type=float, default=1.0)
    ap.add_argument("--epsilon", type=float, default=1.0)
    ap.add_argument("--tile-budget-ms", type=float, default=8.0)
    ap.add_argument("--out", type=Path, default=None, help="write results.json here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store = args.store
        if store is None:
            store = str(Path(tmp) / f"fractal_{args.side}.zarr")
            subprocess.run(CLI + ["tile", f"fractal:{args.side}", "--out", store], check=True,
                           stdout=subprocess.DEVNULL)
        rows = [run(store, t, args, Path(tmp) / f"tiles_{t}") for t in args.tiles]
    print(f"{'tiles':>5} {'median':>8} {'p99':>8} {'p99/med':>7} {'keyfr':>5} "
          f"{'tiles_r':>7} {'rmse':>7}")
    for r in rows:
        print(f"{r['tiles']:>5} {r['median_ms']:8.2f} {r['p99_ms']:8.2f} "
              f"{r['p99_over_median']:7.2f} {r['keyframes']:>5} {r['tiles_rendered']:>7} "
              f"{r['rmse_mean']:7.3f}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps({"args": vars(args) | {
            "out": str(args.out)}, "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
