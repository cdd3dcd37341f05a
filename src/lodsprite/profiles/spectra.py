"""Frequency-space LOD error as a function of viewing distance.

Implements Scoggins, Machiraju & Moorhead, *Enabling Level-of-Detail Matching for
Exterior Scene Synthesis* (IEEE Visualization 2000), §3 and §4.1, with the equations as
restated in ``shared/papers/README.md``:

* Eq. 5-6   sample rate and Nyquist frequency shrink as ``z0 / z``;
* Eq. 7     ``eps_z = sum (F_L - F_H)^2 / sum F_H^2`` over the passband, ``F`` the power
            spectra of the Hanning-windowed LOD and full-model images;
* Eq. 8     passband ``|i|, |j| <= (M/2) (z0/z)`` (integer frequency indices, cycles per
            image);
* Eq. 9-13  importance-sampled distances ``z_(i+1) = z_i (z1/z0)``;
* Eq. 14    Mannos-Sakrison contrast sensitivity ``C(f)``, ``f`` in cycles per degree;
* Eq. 15-16 ``alpha = z0/z`` and the CSF-weighted error with weights ``C(f_ij / alpha)^2``.

The distance loop stops when the passband half-width reaches ``f_min`` (default 5: a
10 x 10 pixel impostor).  All functions are pure numpy over arrays.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

from lodsprite.errors import InputError

F_MIN = 5
CSF_NAME = "Mannos-Sakrison 1974"


def csf(f_cpd: np.ndarray | float) -> np.ndarray:
    """Mannos-Sakrison contrast sensitivity (Eq. 14) at ``f_cpd`` cycles per degree.

    ``C(f) = 2.6 (0.0192 + 0.114 f) exp(-(0.114 f)^1.1)``; peaks near 8 cycles/degree.
    """
    f = np.asarray(f_cpd, dtype=np.float64)
    return 2.6 * (0.0192 + 0.114 * f) * np.exp(-((0.114 * f) ** 1.1))


def passband(image_size: int, z0: float, z: np.ndarray | float) -> np.ndarray:
    """Passband half-width ``k = floor((M/2) (z0/z))`` in frequency indices (Eq. 8)."""
    ratio = z0 / np.asarray(z, dtype=np.float64)
    return np.floor((image_size // 2) * ratio + 1e-9).astype(np.int64)


def distances(z0: float, z1: float, image_size: int, f_min: int = F_MIN) -> np.ndarray:
    """Importance-sampled viewing distances ``(nz,) float64`` (Eq. 12): ``z0, z1, z1^2/z0 ...``
    while the passband half-width (Eq. 8) is at least ``f_min``.  Units are those of z0."""
    if not (z0 > 0 and z1 > z0):
        raise InputError(f"need 0 < z0 < z1, got z0={z0}, z1={z1}")
    if image_size // 2 < f_min:
        raise InputError(f"image size {image_size} is too small for f_min={f_min}")
    ratio = z1 / z0
    n = int(math.floor(math.log((image_size // 2) / f_min) / math.log(ratio) + 1e-9)) + 1
    z = z0 * ratio ** np.arange(n + 1)
    return z[passband(image_size, z0, z) >= f_min]


def hann2d(image_size: int) -> np.ndarray:
    """Separable 2-D Hanning window ``(M, M) float64``."""
    w = np.hanning(image_size)
    return np.outer(w, w)


def power_spectra(images: np.ndarray) -> np.ndarray:
    """Power spectra of Hanning-windowed images.

    ``images (..., M, M)`` real (luminance); returns ``(..., M, M//2 + 1) float64``, the
    non-negative-column half of ``|FFT|^2`` (real images have symmetric spectra, §4.1).
    """
    images = np.asarray(images, dtype=np.float64)
    m = images.shape[-1]
    if images.shape[-2] != m:
        raise InputError("profile images must be square")
    spec = scipy.fft.rfft2(images * hann2d(m), workers=1)
    return spec.real**2 + spec.imag**2


class SpectralGrid:
    """Frequency indices of an ``M x M`` image's half spectrum and what the sums need.

    ``fov_deg`` is the angle the ``M`` pixels span (the profile view's field of view);
    radial frequencies are converted to cycles per degree at the image centre.
    """

    def __init__(self, image_size: int, fov_deg: float) -> None:
        m = int(image_size)
        self.m = m
        i = np.rint(np.fft.fftfreq(m) * m).astype(np.int64)          # rows: signed
        j = np.arange(m // 2 + 1, dtype=np.int64)                      # columns: >= 0
        self.abs_i, self.j = np.abs(i), j
        self.ring = np.maximum(self.abs_i[:, None], j[None, :])        # box "radius"
        # Columns 0 < j < M/2 stand for +j and -j of the full spectrum.
        w = np.full(j.shape, 2.0)
        w[0] = 1.0
        if m % 2 == 0:
            w[-1] = 1.0
        self.col_weight = w
        cycles = np.hypot(i[:, None].astype(np.float64), j[None, :].astype(np.float64))
        degrees_per_image = 2.0 * math.degrees(math.tan(math.radians(fov_deg) / 2.0))
        self.f_cpd = cycles / degrees_per_image

    def rows(self, k: int) -> np.ndarray:
        """Row indices with ``|i| <= k``."""
        return np.flatnonzero(self.abs_i <= k)


def lod_errors(spectrum_full: np.ndarray, spectra_lod: np.ndarray, z: np.ndarray, z0: float,
               fov_deg: float, weighted: bool) -> np.ndarray:
    """Error of each LOD at each distance: Eq. 7 (``weighted=False``) or Eq. 16 (True).

    ``spectrum_full (M, M//2+1)`` and ``spectra_lod (L, M, M//2+1)`` from
    :func:`power_spectra`; ``z (nz,)`` distances with ``z[0] >= z0``.  Returns
    ``(L, nz) float64``, 0 where an LOD image equals the full-model image.
    """
    fh = np.asarray(spectrum_full, dtype=np.float64)
    fl = np.asarray(spectra_lod, dtype=np.float64)
    m = fh.shape[0]
    grid = SpectralGrid(m, fov_deg)
    diff2 = (fl - fh) ** 2 * grid.col_weight
    ref2 = fh**2 * grid.col_weight
    ks = passband(m, z0, z)
    out = np.zeros((fl.shape[0], len(ks)), dtype=np.float64)
    if not weighted:
        # Box sums for every half-width at once: per-ring totals, then a running sum.
        nring = m // 2 + 1
        ring = grid.ring.ravel()
        num = np.stack([np.bincount(ring, d.ravel(), nring) for d in diff2]).cumsum(axis=1)
        den = np.bincount(ring, ref2.ravel(), nring).cumsum()
        out[:] = num[:, ks] / np.where(den[ks] > 0, den[ks], 1.0)
        return out
    for n, (k, zn) in enumerate(zip(ks, np.asarray(z, dtype=np.float64), strict=True)):
        rows = grid.rows(int(k))
        alpha = z0 / zn                                                  # Eq. 15
        c2 = csf(grid.f_cpd[rows, : k + 1] / alpha) ** 2
        den = float(np.sum(c2 * ref2[rows, : k + 1]))
        num = np.einsum("lij,ij->l", diff2[:, rows, : k + 1], c2)
        out[:, n] = num / den if den > 0 else 0.0
    return out
