"""Image metrics between a test image and a reference (ground truth).

All functions take ``(H, W, 3) uint8`` (or equally shaped numeric) arrays; the
data range is fixed at 255 so results are comparable across images.
"""

from __future__ import annotations

import math

import numpy as np

DATA_RANGE = 255.0


def _check(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    return a, b


def rmse(image: np.ndarray, reference: np.ndarray) -> float:
    """Root-mean-square error over all pixels and channels, in grey levels (0..255)."""
    a, b = _check(image, reference)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB for data range 255; ``inf`` for identical images."""
    e = rmse(image, reference)
    return math.inf if e == 0.0 else 20.0 * math.log10(DATA_RANGE / e)


def ssim(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean structural similarity (scikit-image, ``data_range=255``, over colour channels)."""
    from skimage.metrics import structural_similarity

    a, b = _check(image, reference)
    return float(structural_similarity(a, b, data_range=DATA_RANGE, channel_axis=-1))


def flicker(image: np.ndarray, previous: np.ndarray, reference: np.ndarray,
            previous_reference: np.ndarray) -> float:
    """Temporal error between two consecutive displayed images, in grey levels: the RMS
    over pixels and channels of ``(I_t - I_t-1) - (R_t - R_t-1)``, the change the viewer
    sees less the change the reference makes.  Shimmer, popping and a held image the
    camera has moved on from score; motion the reference shares does not."""
    a, b = _check(image, previous)
    r, q = _check(reference, previous_reference)
    if a.shape != r.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {r.shape}")
    return float(np.sqrt(np.mean(((a - b) - (r - q)) ** 2)))


def difference_image(image: np.ndarray, reference: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """Absolute difference ``(H, W) uint8`` (mean over channels, scaled by ``gain``) to look at."""
    a, b = _check(image, reference)
    d = np.abs(a - b).mean(axis=-1) * gain
    return np.clip(d, 0, 255).astype(np.uint8)


def flip(image: np.ndarray, reference: np.ndarray, ppd: float = 67.0) -> float:
    """Mean LDR-FLIP error in [0, 1] (NVIDIA's perceptual difference evaluator,
    flip-evaluator), sRGB ``uint8`` images, ``ppd`` pixels per degree of visual angle
    (67: a 0.7 m viewing distance from a 24-inch 4K monitor, FLIP's default)."""
    import flip_evaluator

    a, b = _check(image, reference)
    _, mean, _ = flip_evaluator.evaluate(
        (b / DATA_RANGE).astype(np.float32), (a / DATA_RANGE).astype(np.float32), "LDR",
        applyMagma=False, parameters={"ppd": float(ppd)})
    return float(mean)
