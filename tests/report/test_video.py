"""Videos of rendered paths: content, atomic writing, and the render command's --video."""

import csv

import imageio.v3 as iio
import numpy as np
import pytest

from conftest import run_cli
from lodsprite.errors import InputError
from lodsprite.report.video import DIFF_GAIN, VideoWriter, check_video_path, side_by_side


def test_side_by_side_shows_truth_shown_and_amplified_difference():
    truth = np.zeros((4, 6, 3), np.uint8)
    shown = np.full((4, 6, 3), 10, np.uint8)
    shown[0, 0] = 200  # a difference larger than 255 / DIFF_GAIN saturates
    out = side_by_side(truth, shown)
    assert out.shape == (4, 18, 3)
    assert np.array_equal(out[:, :6], truth) and np.array_equal(out[:, 6:12], shown)
    assert out[1, 12, 0] == 10 * DIFF_GAIN and out[0, 12, 0] == 255


def _frames(n: int, h: int = 33, w: int = 47) -> list[np.ndarray]:
    """Smooth frames that differ from each other (H.264 keeps them within a few levels)."""
    y, x = np.mgrid[0:h, 0:w]
    return [np.stack([(x * 5 + 20 * k) % 256, (y * 7) % 256, np.full_like(x, 40 * k)],
                     axis=-1).astype(np.uint8) for k in range(n)]


def test_frames_come_back_in_order_within_the_codec_tolerance(tmp_path):
    path = tmp_path / "v.mp4"
    frames = _frames(5)
    with VideoWriter(path, fps=10) as v:
        for f in frames:
            v.append(f)
    back = iio.imread(path)
    assert back.shape == (5, 34, 48, 3)  # odd sides padded to even
    assert path.stat().st_mode & 0o777 == 0o644  # readable like any other output
    for k, f in enumerate(frames):
        err = np.abs(back[k, :33, :47].astype(float) - f).mean()
        assert err < 6.0, (k, err)  # lossy H.264 at quality 8: a few grey levels
        assert all(np.abs(back[j, :33, :47].astype(float) - f).mean() > err
                   for j in range(5) if j != k)


def test_a_failed_run_leaves_no_video_and_no_temporary_file(tmp_path):
    path = tmp_path / "v.mp4"
    with pytest.raises(RuntimeError), VideoWriter(path) as v:
        v.append(_frames(1)[0])
        raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_only_mp4_files_are_accepted(tmp_path):
    with pytest.raises(InputError, match="mp4"):
        check_video_path(tmp_path / "v.avi")
    (tmp_path / "d.mp4").mkdir()
    with pytest.raises(InputError, match="folder"):
        check_video_path(tmp_path / "d.mp4")


def _lodsprite(*args):
    return run_cli(*args)  # in this process: no start-up per run


def test_render_writes_a_side_by_side_video_of_the_frames_shown(tmp_path):
    out = tmp_path / "o"
    proc = _lodsprite("render", "--terrain", "fractal:64:3", "--size", "64x64", "--mode",
                      "sprite", "--lod", "8", "--frames", "12", "--epsilon", "4",
                      "--ground-truth", "--save-frames", "--out", str(out),
                      "--video", str(out / "v.mp4"))
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader((out / "frames.csv").open()))
    video = iio.imread(out / "v.mp4")
    assert video.shape == (len(rows), 64, 192, 3)
    for i in (0, 5, 11):  # reference | frame shown | difference, both saved as PNG too
        png = iio.imread(out / "frames" / f"frame_{i:05d}.png").astype(float)
        ref = iio.imread(out / "frames" / f"ref_{i:05d}.png").astype(float)
        assert np.abs(video[i, :, 64:128] - png).mean() < 6.0
        assert np.abs(video[i, :, :64] - ref).mean() < 6.0
        diff = np.clip(np.abs(ref - png) * DIFF_GAIN, 0, 255)
        assert np.abs(video[i, :, 128:] - diff).mean() < 6.0


def test_render_refuses_a_video_it_cannot_write(tmp_path, cli):
    for args in (["--video", str(tmp_path / "v.gif")],   # (in this process: refused first)
                 ["--mode", "distributed", "--video", str(tmp_path / "v.mp4")]):
        proc = cli("render", "--terrain", "fractal:64:3", "--size", "64x64",
                   "--frames", "4", "--out", str(tmp_path / "o"), *args)
        assert proc.returncode == 2, proc.stderr
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in proc.stderr
        assert "video" in lines[0]
    assert not (tmp_path / "o").exists()
