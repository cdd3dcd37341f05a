"""benchmarks/notebook_vs_rfb.py: its arguments, its notebook's cells and the figures it
derives from the page's and the kernel's logs (the benchmark itself runs JupyterLab and
Chromium for minutes: it is run by hand, not here)."""

import ast
from pathlib import Path

import pytest

from benchmark_scripts import load_benchmark

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("notebook_vs_rfb")


def test_defaults_quick_and_bad_arguments(bench, capsys):
    args = bench.parse_args([])
    assert args.latencies == [0.0, 50.0, 150.0] and args.size == (640, 480)
    assert args.widgets == ["sprite", "rfb"] and args.path == "chen1999"
    quick = bench.parse_args(["--quick"])
    assert quick.latencies == [0.0, 150.0] and quick.frames < args.frames
    for bad in (["--size", "10x10"], ["--size", "big"], ["--latencies", "-5"],
                ["--widgets", "sprite,vnc"], ["--frames", "1"]):
        with pytest.raises(SystemExit) as exc:
            bench.parse_args(bad)
        assert exc.value.code == 2
    assert "error:" in capsys.readouterr().err


@pytest.mark.parametrize("mode", ["sprite", "rfb"])
def test_the_notebook_cells_are_python_a_kernel_runs(bench, mode):
    cells = bench.cells(mode, bench.parse_args(["--quick"]))
    for cell in cells:
        compile(cell, "cell", "exec", flags=ast.PyCF_ALLOW_TOP_LEVEL_AWAIT)
    assert f"stream={mode == 'rfb'}" in cells[0]
    assert "ensure_future" in cells[1]  # the widgets play with the kernel idle


def test_stream_frames_and_input_to_frame_from_the_logs(bench):
    # frames 10..14 put on screen 100 ms apart (wall clock, s); the page's clock starts
    # at origin_ms; a key pressed at 1.05 s (page clock) is in frame 13.
    origin_ms = 1_000_000.0
    shown = [(i, (origin_ms + 1000.0 + 100.0 * (i - 10)) / 1e3) for i in range(10, 15)]
    # frames 11..14 rendered; 12 was a lossless re-send of 11 (not drawn)
    result = {"shown": shown, "drawn": [11, 13, 14], "inputs": [(1.05, 13), (9.0, 99)]}
    assert bench.rfb_frames(result, 2) == pytest.approx([200.0])  # frames 11 and 13
    # frame 13 handed to the page at 1300 ms, loaded at 1303 ms, presented at 1316.7 ms
    rec = {"load": [1103.0, 1203.0, 1303.0], "raf": [1300.0, 1316.7, 1333.4]}
    assert bench.rfb_input_ms(result, origin_ms, rec) == pytest.approx([1316.7 - 1050.0])


def test_the_pages_captured_pixels_are_flipped_to_top_row_first(bench):
    import base64

    import numpy as np

    h, w = 3, 2
    rgba = np.zeros((h, w, 4), np.uint8)
    rgba[0, :, 0] = 255  # the bottom row (GL's first) red
    vp = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1], "o": [5, 6, 7]}
    frames = bench.page_frames([{"index": 8, "vp": vp, "width": w, "height": h,
                                 "rgba": base64.b64encode(rgba.tobytes()).decode()}])
    (index, vp12, image), = frames
    assert index == 8 and vp12.tolist() == [1, 0, 0, 0, 1, 0, 0, 0, 1, 5, 6, 7]
    assert image.shape == (h, w, 3) and image[-1, :, 0].tolist() == [255, 255]
    assert image[0].max() == 0


def test_stream_frames_are_judged_as_the_page_gets_them(bench, tmp_path):
    """Lossless at quality 100 (jupyter_rfb sends a PNG); lossy below (JPEG where an
    encoder is installed: then the decoded image differs from the rendered one)."""
    import numpy as np

    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (1, 16, 24, 3), dtype=np.uint8)
    vps = np.arange(12, dtype=np.float64)[None]
    np.savez(tmp_path / "j.npz", index=np.array([4]), images=image, vps=vps, quality=100)
    (k, vp, shown), = bench.stream_frames(tmp_path / "j.npz")
    assert k == 4 and vp.tolist() == vps[0].tolist()
    assert np.array_equal(shown, image[0])


def test_judge_is_the_mean_rmse_against_the_reference_at_each_frames_viewpoint(
        bench, monkeypatch):
    import numpy as np

    monkeypatch.setattr(bench, "reference",
                        lambda args, vp: np.full((4, 4, 3), int(vp[9]), np.uint8))
    shown = [(0, np.r_[np.zeros(9), 100, 0, 0], np.full((4, 4, 3), 103, np.uint8)),
             (8, np.r_[np.zeros(9), 50, 0, 0], np.full((4, 4, 3), 45, np.uint8))]
    got = bench.judge(shown, bench.parse_args(["--quick"]))
    assert got == {"rmse_shown": pytest.approx(4.0), "rmse_shown_max": pytest.approx(5.0),
                   "judged_frames": 2}
    with pytest.raises(SystemExit):
        bench.parse_args(["--judge-every", "0"])
