"""Tone mapping and linear statistics of ``usdahd preview`` images ((H, W, 4) float32: linear
normalized irradiance RGB, alpha 1 on covered pixels)."""

from __future__ import annotations

import numpy as np

__all__ = ["stats", "tonemap", "tonemap_with"]

#: Rec. 709 luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])


#: Linear value the median covered luminance maps to: photographic middle grey (an 18 % card),
#: so half the visible surface is darker and half brighter than mid-grey whatever the light
#: level; keyed on the maximum (or the 99th percentile) a few bright pixels set the exposure
#: and an evenly lit view came out near white (issue 37).
KEY = 0.18


def tonemap(image: np.ndarray, exposure_stops: float = 0.0) -> tuple[np.ndarray, float]:
    """(H, W, 4) linear -> (H, W, 3) uint8 sRGB and the scale applied (the median of the
    covered luminance -> KEY, times 2^stops)."""
    covered = image[..., 3] > 0
    lum = image[..., :3] @ LUMA
    lit = lum[covered & np.isfinite(lum)]
    ref = float(np.median(lit)) if lit.size else 0.0
    if not ref > 0 and lit.size:  # mostly black: key on what is lit
        ref = float(np.median(lit[lit > 0])) if (lit > 0).any() else 0.0
    scale = (KEY / ref if ref > 0 else 1.0) * 2.0**exposure_stops
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
