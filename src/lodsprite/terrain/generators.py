"""Procedural terrain: seeded spectral-synthesis ridged multifractal height fields.

Implements :func:`fractal`, a vectorised (NumPy + ``scipy.fft``) generator of an
``(size+1) x (size+1)`` :class:`~lodsprite.terrain.heightfield.HeightField`:
mountain ranges of sharp ridges and valleys, separated by flatter lowland plains,
with an optional cheap thermal-erosion pass.  Heights are metres (about
0..2500 m), spacing 30 m per sample unless ``extent_m`` is given.

Method (float32 throughout):

1. One complex white-noise spectrum (``numpy.random.Generator(PCG64(seed))``) on
   a periodic ``m x m`` grid, ``m = 9/8 size``, is cut into disjoint frequency
   bands (``_BANDS``, in cycles across the map), each shaped by a power law
   ``|k|^(-beta/2)`` and turned into a field by an inverse real FFT, cropped to
   ``(size+1)^2`` (so opposite edges do not wrap) and normalised to unit
   standard deviation.  Disjoint bands of white noise are independent.
2. The lowest band (<= 3 cycles) is the *macro* field: broad lowland/upland
   undulation and, through a smoothstep, a *range mask*, 0 on the plains and 1
   in the mountain ranges.
3. The middle bands are ridged-multifractal octaves: ``exp(-|n|)`` peaks in a
   cusp along each zero-crossing of ``n``; each octave is weighted by the
   previous one, so spurs and gullies grow on the main ridges.  The highest band
   adds fine fBm roughness, mostly in the ranges.
4. Heights are normalised, redistributed by a power curve (flattens lowlands,
   sharpens peaks) and scaled to ``0..relief_m`` metres; then a few
   vectorised thermal-erosion iterations let slopes steeper than the angle of
   repose shed material downhill (lowering the highest peaks by a few percent).

Cost: O(N log N) in the number of samples; about 3 s for ``size=4096`` and
2.7 GB peak memory for ``size=8192`` on a 2-core machine.
"""

from __future__ import annotations

import numpy as np

from lodsprite.errors import TerrainError
from lodsprite.terrain.heightfield import HeightField, is_power_of_two

DEFAULT_SPACING_M = 30.0
"""Default horizontal spacing of generated terrain, metres per sample."""

RELIEF_M = 2500.0
"""Default height (metres) of the highest generated peak above the lowest point."""

MIN_SIZE = 16
MAX_SIZE = 8192

_BANDS = (            # (low, high] in cycles across the map, spectral exponent beta
    (0.0, 3.0, 3.0),            # macro: lowlands / upland ranges
    (3.0, 12.0, 2.0),           # ridged octaves: main ridges, spurs, gullies
    (12.0, 48.0, 2.0),
    (48.0, 192.0, 2.0),
    (192.0, np.inf, 3.0),       # fine roughness (plain fBm)
)
_RANGE_MASK = (-0.6, 0.8)      # smoothstep of the macro field: plains -> ranges
_RIDGE_SHARPNESS = 1.0         # ridge signal exp(-|n|)
_RIDGE_GAIN = 0.3              # amplitude ratio of successive ridge octaves
_RIDGE_WEIGHTING = 1.5         # finer ridges are weighted by the coarser ridge signal
_LOWLAND_AMPLITUDE = 0.12      # macro undulation, relative to the first ridge octave
_UPLIFT = 0.5                  # broad uplift of the ranges under their ridges
_DETAIL_AMPLITUDE = 0.02
_PLAINS_ROUGHNESS = 0.15
_PLAINS_HILLS = 0.06           # low rolling hills outside the ranges
_REDISTRIBUTION = 1.4          # exponent of the height redistribution curve
_TALUS_SLOPE = 0.8             # thermal erosion: tan of the angle of repose (~39 degrees)
_EROSION_ITERATIONS = 6
_EROSION_RATE = 0.25


def fractal(size: int, seed: int = 0, extent_m: float | None = None, erode: bool = True,
            *, relief_m: float = RELIEF_M) -> HeightField:
    """Generate a ridged-multifractal terrain of ``size`` quads per side.

    ``size`` is a power of two in ``[16, 8192]``; the result has
    ``(size+1, size+1)`` float32 heights in metres from 0 to about ``relief_m``
    (2500 m; erosion trims the highest peaks a little) and equal spacings
    ``dx = dy = extent_m / size`` metres (default 30 m per sample).  The same
    ``seed`` (an integer >= 0) always gives the identical array.  Raises
    :class:`TerrainError` for an invalid ``size``, ``seed``, ``extent_m`` or
    ``relief_m``.
    """
    size = _check_size(size)
    seed = _check_seed(seed)
    spacing = _spacing(size, extent_m)
    if not (isinstance(relief_m, int | float | np.number) and 0 < relief_m < np.inf):
        raise TerrainError(f"fractal relief must be a positive number of metres, got "
                           f"{relief_m!r}")
    rng = np.random.Generator(np.random.PCG64(seed))
    h = _compose(_band_fields(size, rng))
    h *= np.float32(relief_m)
    if erode:
        _thermal_erosion(h, _TALUS_SLOPE * spacing, _EROSION_ITERATIONS, _EROSION_RATE)
    h -= h.min()
    meta = {"generator": "fractal", "size": size, "seed": seed, "eroded": bool(erode),
            "relief_m": float(relief_m)}
    return HeightField(h, spacing, spacing, f"fractal:{size}:{seed}", meta)


def _check_size(size: int) -> int:
    if isinstance(size, bool) or not isinstance(size, int | np.integer):
        raise TerrainError(f"fractal size must be an integer, got {size!r}")
    size = int(size)
    if not (is_power_of_two(size) and MIN_SIZE <= size <= MAX_SIZE):
        raise TerrainError(f"fractal size must be a power of two in [{MIN_SIZE}, {MAX_SIZE}], "
                           f"got {size}")
    return size


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise TerrainError(f"fractal seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def _spacing(size: int, extent_m: float | None) -> float:
    if extent_m is None:
        return DEFAULT_SPACING_M
    if not (isinstance(extent_m, int | float | np.number) and np.isfinite(extent_m)
            and extent_m > 0):
        raise TerrainError(f"fractal extent must be a positive number of metres, got {extent_m!r}")
    return float(extent_m) / size


def _band_fields(size: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Band-limited noise fields, each ``(size+1, size+1) float32`` with zero mean, unit std.

    One field per entry of ``_BANDS`` (in that order), all cut from one white-noise
    spectrum on a periodic ``m x m`` grid (``m = size * 9/8``) and cropped.
    """
    m = size + size // 8
    shape = (m, m // 2 + 1)
    white = rng.standard_normal((*shape, 2), dtype=np.float32).view(np.complex64)[..., 0]
    fields = [_band_field(white, m, size, lo, hi, beta) for lo, hi, beta in _BANDS[:-1]]
    lo, _, beta = _BANDS[-1]
    white *= _band_amplitude(_cycles_sq(np.arange(m), np.arange(shape[1]), m, size),
                             lo, np.inf, beta)
    fields.append(_to_field(white, m, size))
    return fields


def _cycles_sq(rows: np.ndarray, cols: np.ndarray, m: int, size: int) -> np.ndarray:
    """Squared spatial frequency, in cycles across the output map, of spectrum bins."""
    ky = np.where(rows <= m // 2, rows, rows - m).astype(np.float32) * np.float32(size / m)
    kx = cols.astype(np.float32) * np.float32(size / m)
    return ky[:, None] ** 2 + kx[None, :] ** 2


def _band_amplitude(k2: np.ndarray, lo: float, hi: float, beta: float) -> np.ndarray:
    """Spectral amplitude ``|k|^(-beta/2)`` for ``lo < |k| <= hi`` cycles, else 0 (float32)."""
    inside = (k2 > np.float32(lo * lo)) & (k2 <= np.float32(hi * hi))
    amp = np.power(np.maximum(k2, np.float32(1e-6)), np.float32(-beta / 4))
    amp *= inside
    return amp


def _band_field(white: np.ndarray, m: int, size: int, lo: float, hi: float,
                beta: float) -> np.ndarray:
    """Field of a low-frequency band; only the spectrum corner below ``hi`` is touched."""
    kmax = min(int(np.ceil(hi * m / size)) + 1, m // 2)
    rows = np.unique(np.concatenate([np.arange(kmax + 1), np.arange(m - kmax, m)]))
    cols = np.arange(min(kmax + 1, white.shape[1]))
    spec = np.zeros((m, cols.size), dtype=white.dtype)   # higher columns are all zero
    spec[rows] = white[np.ix_(rows, cols)] * _band_amplitude(_cycles_sq(rows, cols, m, size),
                                                            lo, hi, beta)
    return _to_field(spec, m, size)


def _to_field(spec: np.ndarray, m: int, size: int) -> np.ndarray:
    """Inverse real FFT of the leading columns ``spec (m, c)`` of an ``m x m`` spectrum.

    Returns the field cropped to ``(size+1)^2``, float32, zero mean, unit std
    (an all-zero band, above the Nyquist limit, stays zero).  Done as a column
    ``ifft`` then a row ``irfft`` (zero-padding the missing columns) on the
    kept rows only.
    """
    import scipy.fft  # on first use: 0.3 s at every process start otherwise

    n = size + 1
    half = scipy.fft.ifft(spec, axis=0, workers=-1)[:n]
    f = scipy.fft.irfft(half, n=m, axis=1, workers=-1)[:, :n]
    f = np.ascontiguousarray(f, dtype=np.float32)
    f -= f.mean()
    std = float(f.std())
    if std > 1e-12:
        f /= np.float32(std)
    return f


def _smoothstep(lo: float, hi: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - np.float32(lo)) / np.float32(hi - lo), 0, 1)
    return t * t * (3 - 2 * t)


def _compose(fields: list[np.ndarray]) -> np.ndarray:
    """Combine band fields into relative heights ``(n, n) float32`` in ``[0, 1]``.

    ``fields`` = macro, ridge octaves..., detail (see ``_BANDS``); consumed.
    """
    macro, *ridges, detail = fields
    mask = _smoothstep(*_RANGE_MASK, macro)             # 0 on the plains, 1 in ranges
    ranges = np.zeros_like(macro)
    weight = np.ones_like(macro)
    for i, band in enumerate(ridges):                   # ridged multifractal octaves
        s = np.abs(band)
        s *= np.float32(-_RIDGE_SHARPNESS)
        np.exp(s, out=s)                                # 1 on the ridge crest, cusped
        s *= weight
        ranges += np.float32(_RIDGE_GAIN ** i) * s
        np.clip(s * np.float32(_RIDGE_WEIGHTING), 0, 1, out=weight)
    del weight, ridges
    h = macro
    h *= np.float32(_LOWLAND_AMPLITUDE)
    detail *= np.float32(_DETAIL_AMPLITUDE) * (np.float32(_PLAINS_ROUGHNESS) + mask * ranges)
    ranges += np.float32(_UPLIFT)
    ranges *= mask + np.float32(_PLAINS_HILLS)
    h += ranges
    h += detail
    del ranges, detail, mask
    h -= h.min()
    h *= np.float32(1.0 / max(float(h.max()), 1e-12))
    h **= np.float32(_REDISTRIBUTION)
    return h


def _thermal_erosion(h: np.ndarray, talus: float, iterations: int, rate: float) -> None:
    """Erode ``h (n, n) float32`` metres in place: height drops above ``talus`` m/sample slump.

    Each iteration moves ``rate`` of the excess drop from the higher to the lower
    sample of every row- and column-neighbour pair (mass conserving; stable for
    ``rate <= 0.25``).
    """
    t = np.float32(talus)
    r = np.float32(rate)
    for _ in range(iterations):
        for a, b in ((h[:-1, :], h[1:, :]), (h[:, :-1], h[:, 1:])):   # views of h
            diff = a - b                        # > 0 where a is the higher sample
            move = np.abs(diff)
            move -= t
            np.maximum(move, 0, out=move)
            move *= r
            np.copysign(move, diff, out=move)
            a -= move
            b += move
