"""ColorVideoVDP on played sequences (lodsprite.vdp): the window filmed on every display
tick, the extra's absence a typed error, and, where the extra is installed, the metric's
own verdicts on sequences whose order is known."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite import vdp
from lodsprite.camera import look_at
from lodsprite.display import judge_display
from lodsprite.errors import InputError

HZ = 60.0


class Levels:
    """Frame k replays as a constant grey image of ``levels[k]``."""

    def __init__(self, levels):
        self.levels = levels

    def replay(self, viewpoint, decision):
        return np.full((8, 8, 3), self.levels[decision["k"]], np.uint8)


def _no_cvvdp(monkeypatch):
    monkeypatch.setattr(vdp, "_installed", lambda module: module != "pycvvdp")


def test_without_the_extra_asking_for_it_is_an_input_error_naming_it(monkeypatch):
    _no_cvvdp(monkeypatch)
    assert not vdp.available()
    with pytest.raises(InputError, match=r"lodsprite\[vdp\]"):
        vdp.require()
    vps = [look_at((0, -10, 5), (0, 0, 0))] * 2
    with pytest.raises(InputError, match="vdp"):
        judge_display(Levels([1, 2]), vps, [{"k": 0}, {"k": 1}], np.array([0.0, 0.5]),
                      lambda t: [vps[0]] * len(t), lambda vp: np.zeros((8, 8, 3), np.uint8),
                      HZ, 1.0, video=(0.2, 0.4))


def test_the_window_is_centred_and_never_longer_than_the_run():
    assert vdp.window(0.0, 10.0, 2.0) == (4.0, 6.0)
    assert vdp.window(1.0, 2.0, 5.0) == (1.0, 2.0)
    with pytest.raises(InputError):
        vdp.window(0.0, 1.0, 0.0)


def test_a_window_too_large_is_refused_before_it_is_allocated():
    with pytest.raises(InputError, match="GiB"):
        vdp.check_size(10_000, 4096, 4096)


def test_the_window_films_every_tick_whatever_the_stride(monkeypatch):
    """Ticks 0..59 (1 s at 60 Hz), judged every 20th pair; the window 0.25-0.5 s films
    ticks 15..30, each the image on screen then (frame 0 until 0.3 s, then frame 1) and
    the reference at that tick's viewpoint; the rows stay the strided ones."""
    seen = {}

    def fake_jod(test, ref, fps, display):
        seen.update(test=test.copy(), ref=ref.copy(), fps=fps, display=display)
        return 7.5

    monkeypatch.setattr(vdp, "require", lambda: None)
    monkeypatch.setattr(vdp, "jod", fake_jod)
    vps = [look_at((0, -10, 5), (0, 0, 0))] * 2
    refs = {}

    def reference(vp):  # the tick's viewpoint carries its time: a grey of 100 + tick
        return np.full((8, 8, 3), refs[id(vp)], np.uint8)

    def viewpoint_at(ts):
        out = []
        for t in ts:
            vp = look_at((0, -10, 5 + t), (0, 0, 0))
            refs[id(vp)] = 100 + round(t * HZ)
            out.append(vp)
        return out

    rows, summary = judge_display(
        Levels([10, 20]), vps, [{"k": 0}, {"k": 1}], np.array([0.0, 0.3]), viewpoint_at,
        reference, HZ, 59 / HZ, stride=20, video=(0.25, 0.5))
    assert [r["tick"] for r in rows] == [0, 1, 20, 21, 40, 41]
    ticks = np.arange(15, 31)
    assert seen["test"].shape == (16, 8, 8, 3) and seen["fps"] == HZ
    assert seen["test"][:, 0, 0, 0].tolist() == [10 if j < 18 else 20 for j in ticks]
    assert seen["ref"][:, 0, 0, 0].tolist() == (100 + ticks).tolist()
    assert summary["cvvdp_jod"] == 7.5
    assert summary["cvvdp_window_s"] == pytest.approx([15 / HZ, 30 / HZ])


def test_run_played_refuses_vdp_without_ground_truth():
    from lodsprite.playback import run_played

    class Tech:
        plays_in_time, replays = True, True

    path = type("P", (), {"viewpoints": [0, 1]})()
    with pytest.raises(InputError, match="ground truth"):
        run_played(Tech(), path, vdp_seconds=1.0)


def test_render_config_refuses_vdp_unless_played_with_ground_truth():
    from lodsprite.runconfig import RenderConfig

    with pytest.raises(InputError, match="--vdp"):
        RenderConfig(vdp_seconds=1.0, ground_truth=True).validate()
    with pytest.raises(InputError, match="--vdp"):
        RenderConfig(vdp_seconds=1.0, play=True).validate()
    RenderConfig(mode="lod", vdp_seconds=1.0, play=True, ground_truth=True).validate()


def _moving_checker(frames: int, shift: float, size: int = 96) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    out = np.empty((frames, size, size, 3), np.uint8)
    for f in range(frames):
        v = 0.5 + 0.3 * np.sin((x + shift * f) / 4.0) * np.sin(y / 4.0)
        out[f] = np.round(v * 255)[..., None]
    return out


def test_colorvideovdp_scores_held_frames_worse_the_longer_they_are_held():
    """Where the extra is installed: a moving pattern against itself scores 10 JOD
    (within 0.01); shown as a display that misses slots (each image held 2, 3, then 6
    frames of 30 a second) it scores less the longer each image is held, the way a
    played run that misses slots is seen (measured 9.69, 8.79, 5.49)."""
    if not vdp.available():
        pytest.skip("the vdp extra (cvvdp, PyTorch) is not installed")
    ref = _moving_checker(30, 0.5)
    scores = [vdp.jod(ref[(np.arange(30) // hold) * hold], ref, 30.0)
              for hold in (1, 2, 3, 6)]
    assert scores[0] == pytest.approx(10.0, abs=0.01)
    assert all(a > b + 0.1 for a, b in zip(scores, scores[1:], strict=False)), scores


def test_a_played_run_with_a_gl_context_is_judged_without_pytorch_beside_it(gl):
    """Where the extra is installed: a GL context is current and a frame drawn, the metric
    runs, and the GL process never imports PyTorch (a CUDA build of PyTorch imported
    beside Mesa's EGL context crashed the process)."""
    import sys

    if not vdp.available():
        pytest.skip("the vdp extra (cvvdp, PyTorch) is not installed")
    ref = _moving_checker(20, 0.5, size=64)
    assert vdp.jod(ref, ref, 60.0) == pytest.approx(10.0, abs=0.01)
    assert "torch" not in sys.modules and "pycvvdp" not in sys.modules
    fbo = gl.mgl.simple_framebuffer((8, 8))  # and GL still draws in this process
    fbo.use()
    fbo.clear(0.5, 0.25, 1.0)
    assert np.frombuffer(fbo.read(), np.uint8)[:3].tolist() == [128, 64, 255]
    fbo.release()
