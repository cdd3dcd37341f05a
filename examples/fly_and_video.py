"""Build a camera path in Python, save it as JSON, render it with LOD-sprite to an MP4.

A straight low flight across Jacksboro from the south-west corner to the north-east one,
looking ahead and down, is saved as ``DIR/flight.json`` (the JSON path format that
``lodsprite render --path`` and ``lodsprite view --play`` read), then rendered with
LOD-sprite against an untimed full-resolution ground truth, as ``lodsprite render --mode
sprite --ground-truth --video`` does.  Writes ``DIR/frames.csv``, ``DIR/summary.json``,
``DIR/keyframes.json`` and ``DIR/flight.mp4`` (full resolution | LOD-sprite |
difference x4, side by side) and prints the summary's keyframes, median ms and RMSE::

    python examples/fly_and_video.py --out out/flight --frames 120
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import lodsprite


def straight_flight(scene: lodsprite.Scene, frames: int) -> lodsprite.CameraPath:
    """``frames`` viewpoints on a straight line 1500 m above the highest peak."""
    lo, hi = scene.hf.bounds()
    start = np.array([0.8 * lo[0], 0.8 * lo[1], hi[2] + 1500.0])
    end = np.array([0.5 * hi[0], 0.5 * hi[1], hi[2] + 1500.0])
    heading = (end - start) / np.linalg.norm(end - start)
    ahead_and_down = 8000.0 * heading - np.array([0.0, 0.0, 2500.0])
    viewpoints = [lodsprite.look_at(eye, eye + ahead_and_down)
                  for eye in np.linspace(start, end, frames)]
    return lodsprite.CameraPath("straight-flight", tuple(viewpoints))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/flight"), help="output folder")
    parser.add_argument("--frames", type=int, default=120, help="frames of the flight (>= 2)")
    parser.add_argument("--epsilon", type=float, default=1.0, help="LOD-sprite threshold, px")
    args = parser.parse_args()
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        scene = lodsprite.load_scene("jacksboro")
        path_file = args.out / "flight.json"
        straight_flight(scene, args.frames).to_json(path_file)
        config = lodsprite.RenderConfig(terrain="jacksboro", path=str(path_file), mode="sprite",
                                        epsilon=args.epsilon, ground_truth=True)
        summary = lodsprite.render_path(config, args.out, video=args.out / "flight.mp4")
    except lodsprite.LodspriteError as exc:
        raise SystemExit(f"error: {exc}") from None
    print(f"{summary['frames']} frames: {summary['keyframes']} keyframes, median "
          f"{summary['median_ms']:.2f} ms per frame, RMSE LOD-sprite "
          f"{summary['rmse_mean']:.2f} vs plain {summary['lod']}² "
          f"{summary['rmse_lod_mean']:.2f} grey levels; wrote {args.out / 'flight.mp4'}")


if __name__ == "__main__":
    main()
