"""The frame budget wired into the scene technique (GL, tiny): under an ample target the
scheduler turns every knob to its finest setting, under an impossible one to its
cheapest; the objects' benefit model sees the visible objects; the summary reports
shares and the target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.camera import look_at
from lodsprite.scene.world import load_scene_file

SIZE = (64, 48)


def flat_world(folder: Path):
    np.save(folder / "flat.npy", np.zeros((33, 33), np.float32))
    (folder / "near.csv").write_text("".join(f"{x},{y}\n" for x in (-20.0, 0.0, 20.0)
                                             for y in (-60.0, 0.0, 60.0)))
    (folder / "scene.toml").write_text(
        '[terrain]\nsource = "flat.npy"\ngrid = 32\ntexture = "checker:4"\n'
        '[[objects]]\nmesh = "ogre"\nheight_m = 8.0\npoints = "near.csv"\n')
    return load_scene_file(folder / "scene.toml")


@pytest.mark.parametrize("fps, finest", [(1.0, True), (1e5, False)])
def test_the_scheduler_turns_every_knob(gl, tmp_path, fps, finest):
    world = flat_world(tmp_path)
    vps = [look_at((0.0, -150.0 + 2 * i, 15.0), (0.0, 0.0, 4.0)) for i in range(6)]
    with Renderer(world, SIZE, 45.0, ctx=gl.mgl) as r:
        t = techniques.create("scene", r, world=world, schedule="scheduler", target_fps=fps)
        try:
            t.warm_up(vps[0])
            frames = [t.frame(vp) for vp in vps]
            controls = {layer.name: layer.control() for layer in t.layers}
            want = {n: (c.values[-1] if finest else c.values[0]) for n, c in controls.items()}
            assert {n: frames[-1].extra[f"knob_{n}"] for n in controls} == want
            benefit = t.budget.models["objects"].benefit
            assert benefit.lin is not None and len(benefit.lin) > 0   # the objects seen
            assert 0 < benefit.coverage < 1
            s = t.summary(frames)
            assert s["target_ms"] == pytest.approx(1e3 / fps)
            assert s["schedule"] == "scheduler" and "budget_share_objects" in s
            assert all(f.extra["predicted_ms_terrain"] > 0 for f in frames[1:])
        finally:
            t.release()
