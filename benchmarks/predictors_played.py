"""Which viewpoint should a played frame be drawn for?  Along a path played at a display
rate, a frame started at one slot is shown at the next; drawn for the viewpoint at its
start it shows where the camera was.  Printed: the mean RMSE, against the band-limited
reference at the display time's viewpoint, of a full-resolution frame drawn for

* the viewpoint at the frame's start (no prediction),
* the 2002 paper's predictor (``decay``: the eye extrapolated, the orientation kept),
* ``kalman`` (the eye and the orientation extrapolated),
* the exact viewpoint at the display time (what one sample a pixel leaves),

each predictor fed the viewpoints at the slots' starts.  No clock: the slots are the
display rate's, so the figures are the same on any machine.

    python benchmarks/predictors_played.py [--terrain fractal:128] [--path chen1999]
        [--rate 30] [--frames 60] [--size 256]
"""

from __future__ import annotations

import argparse

import numpy as np

import lodsprite as ls
from lodsprite import metrics
from lodsprite.harness import scene_reference
from lodsprite.playback import PREDICTORS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="fractal:128")
    ap.add_argument("--path", default="chen1999")
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=60, help="display slots judged")
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args()
    scene = ls.load_scene(args.terrain)
    path = ls.get_path(args.path, scene.hf)
    at = path.sampler()
    period = 1.0 / args.rate
    errors: dict[str, list[float]] = {"start": [], **{k: [] for k in PREDICTORS}, "exact": []}
    predictors = {k: cls() for k, cls in PREDICTORS.items()}
    with ls.Renderer(scene, (args.size, args.size)) as r, scene_reference(r) as ref:
        for k in range(args.frames):
            t = k * period
            now = at(np.array([t * 30.0]))[0]          # the path at 30 frames a second
            shown = at(np.array([(t + period) * 30.0]))[0]
            truth = ref(shown)
            drawn = {"start": now, "exact": shown}
            for name, p in predictors.items():
                p.observe(t, now)
                drawn[name] = p.predict(period)
            if k < 2:  # the predictors need two samples for a velocity
                continue
            for name, vp in drawn.items():
                r.render(vp)
                errors[name].append(metrics.rmse(r.read_color(), truth))
    print(f"{args.terrain}, {args.path}, {args.size}², {args.rate:g} Hz, "
          f"{len(errors['start'])} slots: RMSE against the reference at display time")
    for name, e in errors.items():
        print(f"  drawn for {name:>6}: mean {np.mean(e):.2f}, median {np.median(e):.2f}")


if __name__ == "__main__":
    main()
