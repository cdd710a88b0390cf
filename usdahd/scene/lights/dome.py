"""UsdLuxDomeLight: a uniform or latlong-textured environment."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.numerics.sampling import sample_discrete
from usdahd.numerics.sh import LUMINANCE
from usdahd.scene.lights.base import (
    FALLOFF_CONSTANT,
    TWO_PI,
    Bound,
    Light,
    LightHits,
    LightSamples,
    lum,
    norm,
)

__all__ = ["DomeLight"]


@dataclass
class DomeLight(Light):
    """UsdLuxDomeLight: uniform ``radiance`` (3,), optionally times a latlong ``image``.

    image : (h, w, 3) float32 linear radiance multipliers or None (OpenEXR latlong layout:
        column 0 = longitude +pi, row 0 = latitude +pi/2, longitude 0 = local +Z, pi/2 = +X,
        pole = local +Y).
    rotation : (3, 3) world-from-dome rotation (dome transform and pole alignment).
    Textured domes are importance sampled by a piecewise-constant 2-D CDF over
    luminance * sin(theta); uniform domes are left to hemisphere sampling (``sampled`` False).
    """

    image: np.ndarray | None = None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    infinite = True
    KIND = "dome"
    #: textured flag; offsets of the image's pmf/cdf and pixels in the shared blocks;
    #: world-from-dome rotation (row major), its inverse; image height, width
    FIELDS = (
        ("dome_textured", 1),
        ("dome_pmf", 1),
        ("dome_pix", 1),
        ("dome_rot", 9),
        ("dome_inv_rot", 9),
        ("dome_h", 1),
        ("dome_w", 1),
    )

    def pack(self, rec, blocks) -> None:
        rec.dome_rot = np.asarray(self.rotation, np.float64)
        if self.image is None:  # uniform: hit by rays only, never sampled
            rec.dome_textured = rec.dome_pmf = rec.dome_pix = rec.dome_h = rec.dome_w = 0.0
            rec.dome_inv_rot = np.zeros(9)
            return
        h, w = self._img.shape[:2]
        rec.dome_textured = 1.0
        rec.dome_pmf = rec.dome_pix = blocks.add(
            self._img[..., :3].reshape(-1, 3), self._pmf, self._cdf
        )
        rec.dome_inv_rot = self._inv_rot
        rec.dome_h, rec.dome_w = h, w

    def __post_init__(self):
        self.sampled = self.image is not None
        if self.image is None:
            return
        img = np.asarray(self.image, dtype=np.float64)
        h, w = img.shape[:2]
        self._img = img
        theta = np.pi * (np.arange(h) + 0.5) / h
        y = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        wgt = np.maximum(y, 0.0) * np.sin(theta)[:, None]
        if not np.any(wgt > 0):
            wgt = np.ones_like(wgt) * np.sin(theta)[:, None]
        flat = wgt.reshape(-1)
        self._pmf = flat / flat.sum()
        self._cdf = np.cumsum(self._pmf)
        self._cdf[-1] = 1.0
        self._inv_rot = np.linalg.inv(self.rotation)

    def _lookup(self, d):
        loc = d @ self._inv_rot.T
        loc /= np.maximum(norm(loc), 1e-300)[:, None]
        h, w = self._img.shape[:2]
        lat = np.arcsin(np.clip(loc[:, 1], -1.0, 1.0))
        lon = np.arctan2(loc[:, 0], loc[:, 2])
        x = np.clip(((np.pi - lon) / TWO_PI * w).astype(np.int64), 0, w - 1)
        y = np.clip(((0.5 * np.pi - lat) / np.pi * h).astype(np.int64), 0, h - 1)
        return x, y

    def eval(self, d):
        """Radiance arriving along world directions ``d`` (m,3) -> (m,3)."""
        if self.image is None:
            return np.broadcast_to(self.radiance, d.shape).copy()
        x, y = self._lookup(d)
        return self._img[y, x, :3] * self.radiance[None, :]

    def bound(self) -> Bound:
        m = 1.0
        if self.image is not None:  # the image's mean luminance over the sphere
            h = self._img.shape[0]
            sin = np.sin(np.pi * (np.arange(h) + 0.5) / h)
            row = np.maximum(self._img[..., :3] @ LUMINANCE, 0.0).mean(axis=1)
            m = float((row * sin).sum() / sin.sum())
        return Bound(FALLOFF_CONSTANT, cap=np.pi * lum(self.radiance) * m)

    def sample(self, p, u):
        n = len(p)
        h, w = self._img.shape[:2]
        # Reuse u[:,0] for the pixel choice and a stratified remainder for the jitter.
        idx = sample_discrete(self._cdf, u[:, 0])
        lo = np.where(idx > 0, self._cdf[np.maximum(idx - 1, 0)], 0.0)
        frac = np.clip((u[:, 0] - lo) / np.maximum(self._pmf[idx], 1e-300), 0.0, 1.0 - 1e-12)
        y, x = np.divmod(idx, w)
        theta = np.pi * (y + frac) / h
        lon = np.pi - TWO_PI * (x + u[:, 1]) / w
        lat = 0.5 * np.pi - theta
        loc = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
        dirs = loc @ self.rotation.T
        dirs /= norm(dirs)[:, None]
        pdf = self._pmf[idx] * (h * w) / (2.0 * np.pi * np.pi * np.maximum(np.sin(theta), 1e-12))
        value = self._img[y, x, :3] * self.radiance[None, :]
        return LightSamples(dirs, np.full(n, np.inf), value, pdf)

    def intersect(self, o, d):
        n = len(o)
        return LightHits(np.ones(n, bool), np.full(n, np.inf), self.eval(d))

    def pdf(self, o, d, t):
        if self.image is None:
            return np.zeros(len(o))
        h, w = self._img.shape[:2]
        x, y = self._lookup(d)
        loc = d @ self._inv_rot.T
        sin_t = np.sqrt(np.clip(1.0 - (loc[:, 1] / np.maximum(norm(loc), 1e-300)) ** 2, 0, 1))
        return self._pmf[y * w + x] * (h * w) / (2.0 * np.pi * np.pi * np.maximum(sin_t, 1e-12))
