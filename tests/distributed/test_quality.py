"""The quality of a distributed client's runs: the harness's untimed replay of the frames
it showed, and each frame's error metric against its keyframe (real GL on llvmpipe).

The client here has no server that answers: it draws from its own keyframes (the 1999
algorithm), so its decisions are deterministic and the replay can be checked frame by
frame against what it drew."""

from dataclasses import replace

import numpy as np
import pytest

from lodsprite.camera import Viewpoint
from lodsprite.distributed.client import LodClient
from lodsprite.distributed.quality import error_summary
from lodsprite.distributed.render import scene_args
from lodsprite.distributed.technique import DistributedTechnique
from lodsprite.errors import InputError
from lodsprite.harness import run_path
from lodsprite.run import RenderConfig, prepare
from lodsprite.scene.spec import SceneSpec

CFG = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=16, frames=12, path="chen1999",
                   mode="sprite")


def _technique(cfg: RenderConfig) -> tuple[DistributedTechnique, object, object]:
    """A client of a server that never answers (it draws from its own keyframes), as the
    batch runs make it; (technique, scene, path)."""
    scene, path = prepare(cfg, light=False)
    args = scene_args(SceneSpec(cfg.terrain, cfg.texture, None, cfg.exaggeration), cfg.size)
    client = LodClient(scene, args, ["127.0.0.1:9"], cfg.size, cfg.lod, epsilon=cfg.epsilon,
                       max_error=None)
    technique = DistributedTechnique.on_client(client, ["127.0.0.1:9"])
    technique.warmup_s = 0.1  # no server keyframe is coming
    return technique, scene, path


def _reference(technique: DistributedTechnique):
    terrain = technique.client.terrain_gl.drawer

    def full(viewpoint):
        terrain.render(viewpoint, None)
        return terrain.target.read_color()

    return full


def test_error_summary_leaves_out_frames_without_a_keyframe_and_counts_inf_as_over():
    s = error_summary(np.array([np.nan, 0.0, 0.5, np.inf, 2.0]), epsilon=1.0)
    assert s["replayed_frames"] == 4 and s["unmeasurable_frames"] == 1
    assert s["per_frame_error_px"][0] is None and s["per_frame_error_px"][2] == 0.5
    assert s["over_epsilon"] == 0.5  # inf and 2.0 of the four measured
    assert s["error_px_max"] == 2.0 and s["error_px_mean"] == pytest.approx(2.5 / 3)
    assert "error_px_mean" not in error_summary(np.array([np.nan]), 1.0)


def test_the_harness_replays_the_clients_frames_as_it_drew_them():
    """The same replay path as every technique's: each recorded decision drawn again
    equals the frame the client drew, and the harness's quality columns are those of
    the drawn frames against the one reference."""
    from lodsprite.metrics import rmse

    technique, _, path = _technique(CFG)
    client = technique.client
    try:
        def draw(vp):  # the frame as drawn, read back (outside any timed run)
            technique.frame(vp)
            return client.image(), technique.decision()

        drawn, decisions = zip(*[draw(vp) for vp in path.viewpoints], strict=True)
        kinds = {client.shown[d["keyframe"]]["local"] for d in decisions}
        assert kinds == {True}  # no server answered: the client's own keyframes
        reference = _reference(technique)
        want = [rmse(img, reference(vp)) for img, vp in zip(drawn, path.viewpoints,
                                                            strict=True)]
        for i in (11, 0, 5):  # out of order: the keyframe is rendered again when needed
            again = technique.replay(path.viewpoints[i], decisions[i])
            assert np.abs(again.astype(int) - drawn[i].astype(int)).max() <= 2
        result = run_path(technique, path, finish=client.terrain_gl.ctx.finish,
                          ground_truth=True, reference=reference, quality_stride=3)
    finally:
        client.close()
    assert [d["keyframe"] >= 0 for d in result.decisions] == [True] * 12
    rows = result.rows
    assert [i for i, r in enumerate(rows) if "rmse" in r] == [0, 3, 6, 9]
    for i in (0, 3, 6, 9):  # the run's own decisions; the same as the loop's above
        if result.decisions[i]["keyframe"] - result.decisions[0]["keyframe"] == \
                decisions[i]["keyframe"] - decisions[0]["keyframe"]:
            assert rows[i]["rmse"] == pytest.approx(want[i], abs=0.05)
        assert rows[i]["rmse"] < rows[i]["rmse_lod"] or rows[i]["rmse_lod"] == 0
    assert result.summary["quality_frames"] == 4
    assert result.summary["rmse_ratio"] == pytest.approx(
        result.summary["rmse_mean"] / result.summary["rmse_lod_mean"])


def test_a_frame_that_showed_no_keyframe_is_refused_by_the_replay():
    technique, _, path = _technique(CFG)
    try:
        with pytest.raises(InputError):
            technique.replay(path.viewpoints[0], {"keyframe": -1})
        errors = technique.replayed_errors(path.viewpoints[:2], [{"keyframe": -1}] * 2)
        assert np.all(np.isnan(errors))
    finally:
        technique.client.close()


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
    """The replayed error metric against a brute-force Eq. 2 (ray marching, no triangle
    tests) on a flattened terrain, where every ray in view meets the coarse surface: a
    keyframe far behind the viewer is at or above ε, a near one is not."""
    flat = replace(CFG, exaggeration=0.3)
    technique, scene, path = _technique(flat)
    client = technique.client
    try:
        views = list(path.viewpoints)
        client.shown.append({"slot": 0, "seq": 0, "t0": 0.0, "local": True,
                             "viewpoint": views[0].to_dict()})
        errors = technique.replayed_errors(views, [{"keyframe": 0}] * len(views))
        renderer = client.terrain_gl.drawer
        for frame in (1, 3, 11):
            vp = views[frame]
            want = _brute_force_error_px(scene.hf, flat.lod, Viewpoint.from_dict(
                views[0].to_dict()), vp, renderer.projection(vp), renderer.target.height)
            assert want is not None, "a ray in view misses: choose a flatter terrain"
            assert errors[frame] == pytest.approx(want, rel=1e-3)
    finally:
        client.close()
    assert errors[0] < 1e-6 and errors[1] < flat.epsilon
    assert errors[11] >= flat.epsilon and error_summary(errors, flat.epsilon)["over_epsilon"] > 0
