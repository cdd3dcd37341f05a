"""Frequency-space LOD error (Scoggins et al. 2000, Eq. 7-16) against direct computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from lodsprite.errors import InputError
from lodsprite.profiles.spectra import (
    SpectralGrid,
    csf,
    distances,
    hann2d,
    lod_errors,
    passband,
    power_spectra,
)


def test_csf_known_values():
    # Eq. 14 at 0 cycles/degree is 2.6 * 0.0192; the Mannos-Sakrison curve peaks near
    # 8 cycles/degree at about 0.98 and falls off on both sides.
    assert csf(0.0) == pytest.approx(2.6 * 0.0192, rel=1e-12)
    f = np.linspace(0.0, 60.0, 60001)
    c = csf(f)
    assert f[c.argmax()] == pytest.approx(7.89, abs=0.02)
    assert c.max() == pytest.approx(0.9809, abs=1e-3)
    assert csf(1.0) < c.max() and csf(30.0) < c.max()
    assert csf(4.0) == pytest.approx(2.6 * (0.0192 + 0.456) * math.exp(-(0.456**1.1)))


@pytest.mark.parametrize(("m", "z", "k"), [(512, 1.0, 256), (512, 2.0, 128), (512, 51.2, 5),
                                           (256, 3.0, 42), (512, 1.37, 186)])
def test_passband_limits(m, z, k):
    assert int(passband(m, 1.0, z)) == k


def test_distances_importance_sampled():
    z = distances(9.0, 9.0 * 1.37, 512)
    assert z[0] == 9.0
    assert np.allclose(z[1:] / z[:-1], 1.37)
    assert passband(512, 9.0, z[-1]) >= 5 > passband(512, 9.0, z[-1] * 1.37)
    with pytest.raises(InputError):
        distances(9.0, 8.0, 512)


def _scene(m: int = 128, seed: int = 1) -> np.ndarray:
    """A smooth blob with sharp-edged facets: something like a flat-shaded object."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[-1:1:m * 1j, -1:1:m * 1j]
    inside = x**2 + y**2 < 0.7
    facets = np.floor((x + 1) * 9) + 3 * np.floor((y + 1) * 7)
    shade = 0.3 + 0.7 * rng.random(int(facets.max()) + 1)[facets.astype(int)]
    return (inside * shade).astype(np.float64)


def _direct(full: np.ndarray, lod: np.ndarray, k: int, weight: np.ndarray | None) -> float:
    """Eq. 7 / Eq. 16 with the whole (not half) spectrum and an explicit box mask."""
    m = full.shape[0]
    w = hann2d(m)
    fh = np.abs(np.fft.fft2(full * w)) ** 2
    fl = np.abs(np.fft.fft2(lod * w)) ** 2
    i = np.abs(np.rint(np.fft.fftfreq(m) * m))
    box = (i[:, None] <= k) & (i[None, :] <= k)
    c2 = np.ones_like(fh) if weight is None else weight
    return float(np.sum((c2 * (fl - fh) ** 2)[box]) / np.sum((c2 * fh**2)[box]))


@pytest.mark.parametrize("weighted", [False, True])
def test_half_spectrum_sums_match_full_spectrum(weighted):
    m, fov = 128, 6.4
    full = _scene(m)
    lod = gaussian_filter(full, 1.5)
    z0 = 10.0
    z = np.array([10.0, 13.7, 30.0, 100.0])
    got = lod_errors(power_spectra(full), power_spectra(lod[None]), z, z0, fov, weighted)[0]
    i = np.rint(np.fft.fftfreq(m) * m)
    cycles = np.hypot(i[:, None], i[None, :])
    deg_per_image = 2 * math.degrees(math.tan(math.radians(fov) / 2))
    for n, zn in enumerate(z):
        k = int(passband(m, z0, zn))
        c2 = csf(cycles / deg_per_image / (z0 / zn)) ** 2 if weighted else None
        assert got[n] == pytest.approx(_direct(full, lod, k, c2), rel=1e-9)


@pytest.mark.parametrize("weighted", [False, True])
def test_error_zero_for_full_model_and_grows_as_chain_coarsens(weighted):
    full = _scene(128)
    # A synthetic LOD chain: coarser levels lose more detail (stronger blur), coarsest first.
    chain = np.stack([gaussian_filter(full, s) for s in (4.0, 2.0, 1.0, 0.5)] + [full])
    z = distances(1.0, 1.37, 128)
    err = lod_errors(power_spectra(full), power_spectra(chain), z, 1.0, 6.4, weighted)
    assert err.shape == (5, len(z))
    assert np.all(err[-1] == 0.0)
    assert np.all(np.diff(err, axis=0) <= 1e-15)          # coarser (lower index) >= finer
    assert np.all(err[:-1, 0] > 0)


def test_spectral_grid_counts_every_bin_once():
    grid = SpectralGrid(64, 5.0)
    assert grid.col_weight.sum() == 64                     # 1 + 2*31 + 1 columns
    assert grid.ring.max() == 32
