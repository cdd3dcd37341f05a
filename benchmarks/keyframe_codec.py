"""Keyframe compression, measured: bytes on the wire and encode/decode time, raw vs zlib.

The LOD server sends each keyframe's colour and z-buffer (the coarse level's for the
default visibility rule) raw or zlib-compressed (``lodsprite serve --codec``).  This
script renders keyframes along the swan2002 path exactly as the server does and prints,
per codec, the median message size, encode time (server) and decode time (client), and
the time to send it over 10 and 100 Mbit/s links at the wire rate.

    python benchmarks/keyframe_codec.py [--terrain jacksboro] [--size 512] [--keyframes 12]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lodsprite.distributed.protocol import CODECS, decode_keyframe, encode_keyframe
from lodsprite.distributed.render import KeyframeService, scene_args
from lodsprite.paths import swan2002
from lodsprite.scene.spec import SceneSpec
from lodsprite.terrain import DEFAULT_EXAGGERATION, load_terrain

LINKS_MBIT = (10, 100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--keyframes", type=int, default=12)
    a = ap.parse_args()
    args = {**scene_args(SceneSpec(a.terrain, "terrain", None, DEFAULT_EXAGGERATION),
                         (a.size, a.size)),
            "lod": 16, "visibility": "coarse", "epsilon": 1.0}
    renderer = KeyframeService(args)
    path = list(swan2002(load_terrain(a.terrain), 600).viewpoints)
    picks = np.linspace(60, len(path) - 1, a.keyframes).astype(int)
    keyframes = [renderer.render(path[i], int(i), 0.0) for i in picks]
    renderer.release()
    print(f"{a.terrain}, {a.size}² keyframes (colour + coarse z-buffer), "
          f"{len(keyframes)} along swan2002; medians")
    print(f"{'codec':>6} {'MB':>7} {'ratio':>6} {'encode ms':>10} {'decode ms':>10}"
          + "".join(f" {f'{m} Mbit/s ms':>14}" for m in LINKS_MBIT))
    raw_mb = None
    for codec in CODECS:
        sizes, enc, dec = [], [], []
        for kf in keyframes:
            t0 = time.perf_counter()
            frames = encode_keyframe(kf, codec)
            t1 = time.perf_counter()
            wire = [bytes(f) for f in frames]  # what arrives
            t2 = time.perf_counter()
            decode_keyframe(wire)
            t3 = time.perf_counter()
            sizes.append(sum(len(w) for w in wire))
            enc.append((t1 - t0) * 1e3)
            dec.append((t3 - t2) * 1e3)
        mb = float(np.median(sizes)) / 1e6
        raw_mb = raw_mb or mb
        print(f"{codec:>6} {mb:7.3f} {raw_mb / mb:6.2f} {np.median(enc):10.2f} "
              f"{np.median(dec):10.2f}"
              + "".join(f" {mb * 8e3 / m:14.0f}" for m in LINKS_MBIT))


if __name__ == "__main__":
    main()
