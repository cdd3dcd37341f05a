"""Reference frames kept on disk (lodsprite.reference_cache): a frame drawn once is read
back equal, a different view or terrain is not served from it, a damaged file is drawn
again, and ``render --ground-truth`` judges alike with the folder as without it."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conftest import run_cli
from lodsprite.camera import look_at
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.reference_cache import ENV, cached_images
from lodsprite.terrain.generators import fractal


def _counting(ref: LevelZeroReference) -> list[int]:
    drawn = [0]
    image = ref.image

    def counted(*a, **k):
        drawn[0] += 1
        return image(*a, **k)

    ref.image = counted
    return drawn


def test_a_frame_is_drawn_once_and_read_back_equal(gl, tmp_path):
    field = fractal(32, seed=3)
    ref = LevelZeroReference(gl, field, (32, 24), samples=2)
    drawn = _counting(ref)
    image = cached_images(ref, tmp_path / "refs")
    a = look_at((0.0, -1500.0, 2500.0), (0.0, 0.0, 0.0))
    b = look_at((300.0, -1500.0, 2500.0), (0.0, 0.0, 0.0))
    first = image(a)
    assert first.std() > 5  # terrain in view, not the sky alone
    again = image(a)
    assert drawn[0] == 1
    np.testing.assert_array_equal(first, again)
    fresh = LevelZeroReference(gl, field, (32, 24), samples=2)
    np.testing.assert_array_equal(first, fresh.image(a))
    fresh.release()
    other = image(b)
    assert drawn[0] == 2 and not np.array_equal(first, other)
    assert len(list((tmp_path / "refs").glob("*.npy"))) == 2
    ref.release()


def test_another_terrain_or_setting_is_not_served_from_the_folder(gl, tmp_path):
    a = look_at((0.0, -1500.0, 2500.0), (0.0, 0.0, 0.0))
    one = LevelZeroReference(gl, fractal(32, seed=3), (32, 24), samples=2)
    two = LevelZeroReference(gl, fractal(32, seed=4), (32, 24), samples=2)
    three = LevelZeroReference(gl, fractal(32, seed=3), (32, 24), samples=3)
    counts = [_counting(r) for r in (one, two, three)]
    for r in (one, two, three):
        cached_images(r, tmp_path)(a)
    assert [c[0] for c in counts] == [1, 1, 1]
    assert len(list(tmp_path.glob("*.npy"))) == 3
    for r in (one, two, three):
        r.release()


@pytest.mark.parametrize("damage", [b"", b"not a numpy file", "wrong shape"])
def test_a_damaged_file_is_drawn_again_and_replaced(gl, tmp_path, damage):
    ref = LevelZeroReference(gl, fractal(32, seed=3), (32, 24), samples=2)
    drawn = _counting(ref)
    image = cached_images(ref, tmp_path)
    a = look_at((0.0, -1500.0, 2500.0), (0.0, 0.0, 0.0))
    good = image(a)
    (file,) = tmp_path.glob("*.npy")
    if damage == "wrong shape":
        np.save(file, np.zeros((4, 4, 3), np.uint8))
    else:
        file.write_bytes(damage)
    np.testing.assert_array_equal(image(a), good)
    assert drawn[0] == 2
    np.testing.assert_array_equal(image(a), good)
    assert drawn[0] == 2
    ref.release()


def _rmse_column(folder) -> list[str]:
    with open(folder / "frames.csv", newline="") as f:
        return [r["rmse"] for r in csv.DictReader(f)]


def test_render_judges_alike_with_the_folder(tmp_path, monkeypatch):
    args = ["render", "--terrain", "fractal:64", "--mode", "lod", "--lod", "8", "--frames",
            "4", "--size", "48x32", "--ground-truth"]
    plain = run_cli(*args, "--out", str(tmp_path / "plain"))
    assert plain.returncode == 0, plain.stderr
    monkeypatch.setenv(ENV, str(tmp_path / "refs"))
    for name in ("first", "second"):
        res = run_cli(*args, "--out", str(tmp_path / name))
        assert res.returncode == 0, res.stderr
    assert len(list((tmp_path / "refs").glob("*.npy"))) == 4
    assert _rmse_column(tmp_path / "plain") == _rmse_column(tmp_path / "first") \
        == _rmse_column(tmp_path / "second")
