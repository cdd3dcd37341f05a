"""The reference's filter (lodsprite.bandlimit): k x k samples a pixel to one, by a box or
a tent, in linear light or in the encoded values."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.bandlimit import downsample, linear_to_srgb, resolve, srgb_to_linear
from lodsprite.errors import InputError


def test_srgb_transfer_round_trips_and_has_its_known_points():
    v = np.linspace(0, 1, 101)
    assert np.allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-12)
    assert srgb_to_linear(np.array([0.5]))[0] == pytest.approx(0.21404, abs=1e-5)


def test_half_black_half_white_averages_in_linear_light():
    """A pixel half black, half white shows half the light: sRGB 188 (0.5 linear), not the
    mean of the encoded values (128), which 'srgb' space gives."""
    s = np.zeros((4, 4, 3), np.uint8)
    s[:, :2] = 255
    assert resolve(s, 4)[0, 0].tolist() == [188, 188, 188]
    assert resolve(s, 4, space="srgb")[0, 0].tolist() == [128, 128, 128]


def test_box_is_the_mean_of_each_pixels_own_samples():
    rng = np.random.default_rng(1)
    s = rng.integers(0, 256, (12, 18, 3), dtype=np.uint8)
    got = resolve(s, 3, "box", "srgb")
    want = np.rint(s.reshape(4, 3, 6, 3, 3).mean(axis=(1, 3))).astype(np.uint8)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_tent_keeps_a_constant_and_reaches_one_pixel_beyond(k):
    """Renormalised at the edges a constant stays; a lone bright pixel's samples spread
    into its four neighbours (two-pixel support), not beyond, weights summing to one."""
    flat = np.full((5 * k, 5 * k, 3), 77, np.uint8)
    assert np.array_equal(resolve(flat, k, "tent"), np.full((5, 5, 3), 77, np.uint8))
    s = np.zeros((5 * k, 5 * k, 3), np.float64)
    s[2 * k:3 * k, 2 * k:3 * k] = 1.0
    out = resolve(s, k, "tent", "srgb").astype(float) / 255
    assert out[2, 2, 0] > out[2, 1, 0] > 0 and out[2, 1, 0] > out[1, 1, 0]
    assert out[0].max() == 0 and out[:, 0].max() == 0
    assert out[..., 0].sum() == pytest.approx(1.0, abs=0.03)


def test_downsample_is_a_box():
    s = np.arange(8 * 8 * 3, dtype=np.uint8).reshape(8, 8, 3)
    assert np.array_equal(downsample(s, 2, "srgb"), resolve(s, 2, "box", "srgb"))


@pytest.mark.parametrize("bad", [dict(k=0), dict(k=17), dict(filter="gauss"),
                                 dict(space="lab"), dict(k=3)])
def test_bad_filter_settings_are_input_errors(bad):
    args = dict(k=2, filter="box", space="linear") | bad
    with pytest.raises(InputError):
        resolve(np.zeros((8, 8, 3), np.uint8), args["k"], args["filter"], args["space"])
