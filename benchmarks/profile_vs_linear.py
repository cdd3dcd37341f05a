"""Profile LOD against distance-linear LOD at equal triangles (issue 23, must-have 3).

A crowd of ``--objects`` built-in ogres and ``--trees`` built-in trees (two types, both
``lod = "profile"``), seen from ``--views`` viewpoints along its walkthrough at
``--size`` pixels: each type's error profile (built on first use with the scene settings
and cached in the user cache folder, ``$LODSPRITE_CACHE``), the profile's LODs at
``--threshold``, the linear rule tuned to the same triangles, and RMSE and FLIP of each
against the full-detail render (:func:`lodsprite.manager.profile_compare.profile_vs_linear`).
The first run builds the tree's profile (tens of seconds); later runs read the cache.

    python benchmarks/profile_vs_linear.py [--objects 300] [--trees 12] [--views 4]
                                           [--size 128] [--threshold 1e-3]
"""

from __future__ import annotations

import argparse
import json
import time

from lodsprite.gl.context import GLContext
from lodsprite.manager.profile_compare import profile_vs_linear, type_profiles
from lodsprite.manager.scene import build_crowd, walkthrough
from lodsprite.profiles.object_lod import DEFAULT_THRESHOLD, stats
from lodsprite.scene.objects import builtin_type


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=300)
    ap.add_argument("--trees", type=int, default=12)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--threshold", type=float, default=DEFAULT_THRESHOLD)
    a = ap.parse_args()
    t0 = time.perf_counter()
    types = [builtin_type("ogre", None, "profile"), builtin_type("tree", None, "profile")]
    profiles = type_profiles(types, [t.model for t in types])
    setup_s = time.perf_counter() - t0
    crowd = build_crowd([types[0].model], objects=a.objects, trees=a.trees,
                        tree_model=types[1].model)
    path = walkthrough(crowd, frames=max(2, 2 * a.views))
    gl = GLContext()
    try:
        t0 = time.perf_counter()
        r = profile_vs_linear(gl, crowd, profiles, list(path.viewpoints[::2][:a.views]),
                              size=(a.size, a.size), threshold=a.threshold)
        compare_s = time.perf_counter() - t0
    finally:
        gl.release()
    print(json.dumps(r.as_dict(), indent=1))
    print(f"profiles {setup_s:.1f} s ({stats['built']} built, {stats['loaded']} from the "
          f"cache), comparison {compare_s:.1f} s; GL shared with other work: noisy")


if __name__ == "__main__":
    main()
