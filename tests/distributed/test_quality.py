"""Replaying a client's frames to measure their image error (real GL on llvmpipe)."""

import json

import numpy as np
import pytest

from lodsprite.distributed.quality import Replayer, inline_quality, recorded_keyframes
from lodsprite.errors import InputError
from lodsprite.run import RenderConfig

CFG = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=16, frames=12, path="chen1999",
                   mode="sprite")


@pytest.fixture(scope="module")
def replayer():
    with Replayer(CFG, stride=3) as r:
        yield r


def test_frames_shown_from_their_own_viewpoint_carry_no_error(replayer):
    views = list(replayer.path.viewpoints)
    fresh = replayer.replay(views, np.arange(len(views)))
    assert fresh["replayed_frames"] == 12 and fresh["quality_frames"] == 4
    assert fresh["error_px_max"] < 1e-6 and fresh["over_epsilon"] == 0.0
    # Along the silhouettes the coarse level covers other pixels than full resolution,
    # so even these frames differ from it, but less than the plain coarse level does.
    assert fresh["rmse_sprite_mean"] < fresh["rmse_lod_mean"]


def test_a_stale_keyframe_shows_as_error_and_frames_without_one_are_left_out(replayer):
    views = list(replayer.path.viewpoints)
    stale = replayer.replay(views[:1], np.array([-1] + [0] * 11))
    assert stale["replayed_frames"] == 11 and stale["per_frame_error_px"][0] is None
    errors = np.array(stale["per_frame_error_px"][1:])
    assert errors[-1] > errors[0] and stale["over_epsilon"] > 0
    fresh = replayer.replay(views, np.arange(len(views)))
    assert stale["rmse_sprite_mean"] > fresh["rmse_sprite_mean"]


def test_inline_frames_never_show_epsilon_or_more():
    q = inline_quality(CFG, stride=4)
    assert q["replayed_frames"] == 12 and q["quality_frames"] == 3
    assert q["error_px_max"] < CFG.epsilon and q["over_epsilon"] == 0.0


def test_replays_need_a_recorded_run(tmp_path, replayer):
    with pytest.raises(InputError):
        recorded_keyframes(tmp_path)
    (tmp_path / "keyframes.json").write_text(json.dumps({"keyframes": []}))
    (tmp_path / "frames.csv").write_text("frame,keyframe\n0,0\n")
    with pytest.raises(InputError):  # names a keyframe that was never recorded
        recorded_keyframes(tmp_path)
    with pytest.raises(InputError):
        replayer.replay([], np.array([-1, -1]))  # not the path's frame count
