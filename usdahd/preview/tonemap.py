"""Tone mapping and linear statistics of ``usdahd preview`` images ((H, W, 4) float32: linear
normalized irradiance RGB, alpha 1 on covered pixels)."""

from __future__ import annotations

import numpy as np

#: Rec. 709 luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])


def tonemap(image: np.ndarray, exposure_stops: float = 0.0) -> tuple[np.ndarray, float]:
    """(H, W, 4) linear -> (H, W, 3) uint8 sRGB and the scale applied (99th percentile of the
    covered luminance -> 0.9, times 2^stops)."""
    covered = image[..., 3] > 0
    lum = image[..., :3] @ LUMA
    ref = float(np.percentile(lum[covered], 99)) if covered.any() else 0.0
    scale = (0.9 / ref if ref > 0 else 1.0) * 2.0**exposure_stops
    return tonemap_with(image, scale), scale


def tonemap_with(image: np.ndarray, scale: float) -> np.ndarray:
    """(H, W, 4) linear -> (H, W, 3) uint8 sRGB at a given linear scale (uncovered: black)."""
    x = np.clip(image[..., :3] * scale, 0.0, 1.0)
    x = np.where(image[..., 3:] > 0, x, 0.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(255.0 * srgb).astype(np.uint8)


def stats(image: np.ndarray) -> dict:
    """Linear statistics of the covered pixels (normalized irradiance, Rec. 709 luminance)."""
    covered = image[..., 3] > 0
    lum = (image[..., :3] @ LUMA)[covered]
    rgb = image[..., :3][covered]
    if not lum.size:
        return {"covered_fraction": 0.0}
    return {
        "covered_fraction": float(covered.mean()),
        "mean_rgb": [float(v) for v in rgb.mean(axis=0)],
        "luminance": {
            "mean": float(lum.mean()),
            "min": float(lum.min()),
            "p50": float(np.percentile(lum, 50)),
            "p99": float(np.percentile(lum, 99)),
            "max": float(lum.max()),
        },
        "non_finite": int((~np.isfinite(image[..., :3][covered])).sum()),
    }
