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


def _coarse_height(hf, lod, x, y):
    """Height (metres) of the coarse level's surface at world ``x, y`` (NaN outside): the
    level's vertices split as the renderer splits them, (nw, sw, se) and (nw, se, ne)."""
    from lodsprite.terrain.lod import level_indices

    idx = level_indices(hf, lod)
    z = hf.heights[np.ix_(idx, idx)].astype(np.float64)
    rows, cols = hf.grid_index(x, y)
    step = idx[1]
    u, v = rows / step, cols / step  # in coarse squares: u down the rows, v along the columns
    inside = (u >= 0) & (u <= lod) & (v >= 0) & (v <= lod)
    i = np.clip(np.floor(u), 0, lod - 1).astype(int)
    j = np.clip(np.floor(v), 0, lod - 1).astype(int)
    fu, fv = u - i, v - j
    nw, ne, sw, se = z[i, j], z[i, j + 1], z[i + 1, j], z[i + 1, j + 1]
    lower = nw + fu * (sw - nw) + fv * (se - sw)    # u >= v: triangle (nw, sw, se)
    upper = nw + fv * (ne - nw) + fu * (se - ne)    # v >= u: triangle (nw, se, ne)
    return np.where(inside, np.where(fu >= fv, lower, upper), np.nan)


def _brute_force_error_px(hf, lod, key, vp, projection, height_px):
    """Eq. 2 computed another way: ``C'`` by marching each ray from the keyframe eye
    through the square centre ``C`` and taking the surface crossing nearest to ``C``; θ
    from the dot product; None when a ray in view crosses nowhere."""
    from lodsprite.terrain.lod import level_indices

    idx = level_indices(hf, lod)
    mid = idx[:-1] + idx[1] // 2
    rr, cc = np.meshgrid(mid, mid, indexing="ij")
    centres = hf.points(rr, cc).reshape(-1, 3)
    clip = np.c_[centres, np.ones(len(centres))] @ (projection.matrix() @ vp.view_matrix()).T
    seen = (clip[:, 3] > 0) & np.all(np.abs(clip[:, :3]) <= clip[:, 3:4], axis=1)
    t = np.linspace(0.05, 4.0, 40000)
    thetas = []
    for c in centres[seen]:
        p = key.o + t[:, None] * (c - key.o)
        g = p[:, 2] - _coarse_height(hf, lod, p[:, 0], p[:, 1])
        k = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
        if k.size == 0:
            return None
        tc = t[k] - g[k] * (t[k + 1] - t[k]) / (g[k + 1] - g[k])  # linear refinement
        best = tc[np.argmin(np.abs(tc - 1.0))]
        c_prime = key.o + best * (c - key.o)
        a, b = c - vp.o, c_prime - vp.o
        cos = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
        thetas.append(np.arccos(np.clip(cos, -1.0, 1.0)))
    beta = np.radians(projection.fov_y_deg) / height_px
    return float(np.sqrt(np.mean(np.square(thetas))) / beta)


def test_the_replayed_error_is_eq2_as_computed_independently_and_flags_a_far_keyframe():
    """The replay's error metric against a brute-force Eq. 2 (ray marching, no triangle
    tests) on a flattened terrain, where every ray in view meets the coarse surface: a
    keyframe far behind the viewer is at or above ε, a near one is not."""
    from dataclasses import replace

    from lodsprite.run import prepare

    flat = replace(CFG, exaggeration=0.3)
    hf = prepare(flat)[0].hf
    with Replayer(flat, stride=CFG.frames) as replayer:
        views = list(replayer.path.viewpoints)
        renderer = replayer.paths.renderer
        stale = replayer.replay(views[:1], np.zeros(len(views), dtype=int))
        errors = stale["per_frame_error_px"]
        for frame in (1, 3, 11):
            vp = views[frame]
            want = _brute_force_error_px(hf, flat.lod, views[0], vp, renderer.projection(vp),
                                         renderer.target.height)
            assert want is not None, "a ray in view misses: choose a flatter terrain"
            assert errors[frame] == pytest.approx(want, rel=1e-3)
    assert errors[0] < 1e-6 and errors[1] < flat.epsilon
    assert errors[11] >= flat.epsilon and stale["over_epsilon"] > 0


def test_inline_quality_measures_the_1999_algorithms_frames():
    q = inline_quality(CFG, stride=4)
    assert q["replayed_frames"] == 12 and q["quality_frames"] == 3
    errors = np.array(q["per_frame_error_px"], dtype=float)
    assert errors[0] == 0.0 and np.all(np.isfinite(errors))  # the first frame is a keyframe
    assert 0.0 < q["rmse_sprite_mean"] < q["rmse_lod_mean"]


def test_replays_need_a_recorded_run(tmp_path, replayer):
    with pytest.raises(InputError):
        recorded_keyframes(tmp_path)
    (tmp_path / "keyframes.json").write_text(json.dumps({"keyframes": []}))
    (tmp_path / "frames.csv").write_text("frame,keyframe\n0,0\n")
    with pytest.raises(InputError):  # names a keyframe that was never recorded
        recorded_keyframes(tmp_path)
    with pytest.raises(InputError):
        replayer.replay([], np.array([-1, -1]))  # not the path's frame count
