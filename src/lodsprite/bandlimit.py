"""Band-limiting: ``k x k`` samples a pixel filtered down to one pixel, in a stated colour
space with a stated filter.

A reference image that aliases is no reference: a renderer that filters correctly would be
charged for not aliasing the same way.  Supersampling and filtering the samples (the
ground truth of amortised supersampling and temporal antialiasing: Yang, Nehab, Sander,
Sitthi-amorn, Lawrence & Hoppe 2009; Yang, Liu & Salvi 2020) removes most of it.

Colour space: the renderers write display-encoded (sRGB) values.  Light adds in linear
units, so the samples are decoded (IEC 61966-2-1), filtered, and encoded again
(``space="linear"``, the default); ``space="srgb"`` filters the encoded values as they
are.

Filters, in output pixels (each pixel covers ``k x k`` samples):

- ``box``: the mean of the pixel's own ``k x k`` samples (a 1-pixel box);
- ``tent``: a separable triangle of radius one pixel centred on the pixel (2-pixel
  support, sample weights ``1 - |d| / k`` for sample-centre distance ``d`` in samples),
  renormalised at the image's edges.

All functions are pure numpy over arrays; images are ``(H, W, 3)``.
"""

from __future__ import annotations

import numpy as np

from lodsprite.errors import InputError

FILTERS = ("box", "tent")
SPACES = ("linear", "srgb")


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """Display-encoded values in [0, 1] to linear light (the sRGB transfer function)."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] to display-encoded values (inverse of :func:`srgb_to_linear`)."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1 / 2.4) - 0.055)


_DECODE = srgb_to_linear(np.arange(256) / 255.0)  # uint8 -> linear, by table


def check_filter(k: int, filter: str, space: str) -> None:
    """Raise :class:`InputError` for a sample count or filter or space not known."""
    if not (isinstance(k, int | np.integer) and 1 <= int(k) <= 16):
        raise InputError(f"samples a pixel side must be an integer in 1..16, not {k!r}")
    if filter not in FILTERS:
        raise InputError(f"the reference filter is one of {', '.join(FILTERS)}, not "
                         f"{filter!r}")
    if space not in SPACES:
        raise InputError(f"the reference filters in colour space linear or srgb, not "
                         f"{space!r}")


def _tent_axis(v: np.ndarray, k: int, axis: int) -> np.ndarray:
    """The tent filter along ``axis`` of ``v``, ``k`` samples an output pixel: output ``i``
    sums samples ``i k + m`` weighted ``1 - |m + 1/2 - k/2| / k`` (the distance of the
    sample's centre from the pixel's, in samples), over the samples inside the image,
    renormalised."""
    v = np.moveaxis(v, axis, 0)
    n_out = v.shape[0] // k
    m = np.arange(-k, 2 * k)
    w = np.clip(1.0 - np.abs(m + 0.5 - k / 2) / k, 0.0, None)
    m, w = m[w > 0], w[w > 0]
    pad = -int(m[0])
    padded = np.zeros((v.shape[0] + 2 * pad + k, *v.shape[1:]), np.float64)
    padded[pad:pad + v.shape[0]] = v
    inside = np.zeros(padded.shape[0])
    inside[pad:pad + v.shape[0]] = 1.0
    out = np.zeros((n_out, *v.shape[1:]), np.float64)
    norm = np.zeros(n_out)
    for mm, ww in zip(m, w, strict=True):
        rows = slice(pad + mm, pad + mm + n_out * k, k)
        out += ww * padded[rows]
        norm += ww * inside[rows]
    out /= norm.reshape(-1, *([1] * (out.ndim - 1)))
    return np.moveaxis(out, 0, axis)


def resolve(samples: np.ndarray, k: int, filter: str = "box", space: str = "linear"
            ) -> np.ndarray:
    """Filter ``samples (H*k, W*k, 3)`` (uint8, or floats in [0, 1], display-encoded) down
    to ``(H, W, 3) uint8``, ``k`` samples a pixel side (module doc)."""
    check_filter(k, filter, space)
    s = np.asarray(samples)
    if s.ndim != 3 or s.shape[0] % k or s.shape[1] % k:
        raise InputError(f"{s.shape} samples do not tile into {k}x{k} per pixel")
    if s.dtype == np.uint8:
        v = _DECODE[s] if space == "linear" else s / 255.0
    else:
        v = srgb_to_linear(s) if space == "linear" else s.astype(np.float64)
    h, w = s.shape[0] // k, s.shape[1] // k
    if filter == "box":
        out = v.reshape(h, k, w, k, -1).mean(axis=(1, 3))
    else:
        out = _tent_axis(_tent_axis(v, k, 0), k, 1)
    if space == "linear":
        out = linear_to_srgb(out)
    return np.clip(np.rint(out * 255.0), 0, 255).astype(np.uint8)


def downsample(image: np.ndarray, factor: int, space: str = "linear") -> np.ndarray:
    """An ``(H, W, 3) uint8`` image box-filtered ``factor`` times smaller in each side
    (``H`` and ``W`` divisible by it), in ``space``: how two references of different
    sizes are compared."""
    return resolve(image, factor, "box", space)


__all__ = ["FILTERS", "SPACES", "check_filter", "downsample", "linear_to_srgb", "resolve",
           "srgb_to_linear"]
