"""The Stanford archive's rectified layout, on folders made here in that layout."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from lodsprite.errors import InputError
from lodsprite.lumigraph.importer import import_stanford
from lodsprite.lumigraph.store import Lumigraph

GRID, W, H = 3, 120, 80  # the archive's images are neither square nor powers of two


def make_archive(folder, grid=GRID, skip=None, first_col=0):
    folder.mkdir()
    for r in range(grid):
        for c in range(first_col, first_col + grid):
            if (r, c) == skip:
                continue
            img = np.zeros((H, W, 3), np.uint8)
            img[..., 0], img[..., 1] = 40 + 60 * r, 40 + 60 * (c - first_col)  # the camera
            img[:, W // 2:, 2] = 200  # the right half blue: checks the orientation
            y, x = -100.0 * r, 100.0 * c
            Image.fromarray(img).save(folder / f"out_{r:02d}_{c:02d}_{y:.6f}_{x:.6f}_.png")
    return folder


def test_a_rectified_folder_becomes_a_lumigraph(tmp_path):
    src = make_archive(tmp_path / "rectified")
    s = import_stanford(src, tmp_path / "lf", n_uv=32, codec="png")
    assert s["nodes"] == GRID * GRID and s["grid"] == GRID
    lf = Lumigraph(tmp_path / "lf")
    assert lf.slabs[0].n_st == GRID and lf.slabs[0].n_uv == 32
    for r in range(GRID):
        for c in range(GRID):
            img = lf.node(0, c, GRID - 1 - r)  # column along s, row 0 at the top (t max)
            assert img.shape == (32, 32, 3)
            assert abs(int(img[16, 4, 0]) - (40 + 60 * r)) <= 2
            assert abs(int(img[16, 4, 1]) - (40 + 60 * c)) <= 2
            assert img[16, 4, 2] < 10 and img[16, 28, 2] > 190  # not mirrored
    # the grid spans 200 units of positions on an 80-unit-wide square crop
    assert lf.slabs[0].st_size == pytest.approx(200 / 80)


def test_an_unknown_layout_is_one_clear_error(tmp_path):
    (tmp_path / "other").mkdir()
    Image.new("RGB", (8, 8)).save(tmp_path / "other" / "view_1.png")
    with pytest.raises(InputError, match="rectified layout"):
        import_stanford(tmp_path / "other", tmp_path / "lf")


def test_a_grid_with_gaps_is_refused(tmp_path):
    src = make_archive(tmp_path / "rectified", skip=(1, 1))
    with pytest.raises(InputError, match="gaps"):
        import_stanford(src, tmp_path / "lf")


def test_columns_numbered_from_one_are_placed_from_the_left(tmp_path):
    src = make_archive(tmp_path / "rectified", first_col=1)
    import_stanford(src, tmp_path / "lf", n_uv=16, codec="png")
    lf = Lumigraph(tmp_path / "lf")
    assert len(lf.nodes(0)) == GRID * GRID
    assert abs(int(lf.node(0, 0, GRID - 1)[8, 2, 1]) - 40) <= 2  # leftmost column, top row
