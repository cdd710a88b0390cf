"""Synthetic tangent-space radiance SH of several environment families, and the sample file.

Each family returns (n, 3, 9) float64 hemispherical radiance SH (zero below the tangent-plane
horizon): smooth parts are projected with the exact hemisphere Gauss-Legendre rule of
usdahd.sh, delta lights (sun, point-like lights) are added analytically as P * Y(s), which is the
exact projection of a delta of integrated radiance P.

    python benchmarks/make_sample_sh.py            # writes samples/sh/sky_sun.npy (64 texels)

The families are used by benchmarks/fit.py and tests; everything is deterministic in ``seed``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from usdahd.numerics import sh  # noqa: E402

QUAD_THETA = 24  # 24 x 48 hemisphere rule: smooth radiance is projected to ~1e-6


def _frames(normals):
    """Tangent frames (n, 3, 3) whose rows are T, B, N for world normals (n, 3)."""
    a = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(a, normals)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.stack([t, np.cross(normals, t), normals], axis=1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _project_hemi(radiance_fn, n):
    """Project tangent-space radiance radiance_fn(dirs (m,3)) -> (n, m, 3) into (n, 3, 9)."""
    d, w = sh.hemisphere_quadrature(QUAD_THETA)
    vals = radiance_fn(d)  # (n, m, 3)
    return np.einsum("nmc,mk,m->nck", vals, sh.basis(d), w)


def _add_delta(out, s_tan, power):
    """Add delta lights of integrated radiance power (n, 3) at tangent dirs s_tan (n, 3)."""
    up = s_tan[:, 2] > 0
    out[up] += power[up, :, None] * sh.basis(s_tan[up])[:, None, :]
    return out


def sky_sun(n, seed=0):
    """Blue sky with a brighter horizon, a grey ground bounce and a sun (2-80 deg elevation)
    seen from surfaces of random orientation (normals from straight up to 70 deg past vertical).
    The sun gives 4-20x the sky's horizontal irradiance."""
    rng = np.random.default_rng(seed)
    nz = rng.uniform(-0.35, 1.0, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    nrm = np.stack([np.sqrt(1 - nz**2) * np.cos(ph), np.sqrt(1 - nz**2) * np.sin(ph), nz], -1)
    frames = _frames(nrm)  # rows T, B, N: world = tangent @ frames
    sky = rng.uniform([0.25, 0.45, 0.8], [0.45, 0.6, 1.0], (n, 3))
    ground = rng.uniform(0.05, 0.3, (n, 1)) * np.array([0.9, 0.8, 0.7])
    el = np.radians(rng.uniform(2, 80, n))
    saz = rng.uniform(0, 2 * np.pi, n)
    sun_w = np.stack([np.cos(el) * np.cos(saz), np.cos(el) * np.sin(saz), np.sin(el)], -1)
    ratio = rng.uniform(4, 20, n)
    # horizontal sun irradiance = power * sin(el) / pi = ratio * (sky irradiance ~ mean sky)
    power = (ratio * sky.mean(1) * np.pi / np.sin(el))[:, None] * np.array([1.0, 0.95, 0.85])

    def rad(d):
        w = np.einsum("mi,nij->nmj", d, frames)  # world directions (n, m, 3)
        z = w[..., 2:3]
        sky_l = sky[:, None, :] * (0.7 + 0.6 * (1.0 - np.clip(z, 0, 1)) ** 3)
        return np.where(z > 0, sky_l, ground[:, None, :] * sky.mean(1)[:, None, None] * 3.0)

    out = _project_hemi(rad, n)
    sun_t = np.einsum("nj,nij->ni", sun_w, frames)
    return _add_delta(out, sun_t, power)


def area_lights(n, seed=1):
    """Two to four coloured smooth lobes exp(k (w.s - 1)), k in [10, 60], plus a dim ambient."""
    rng = np.random.default_rng(seed)
    d, _ = sh.hemisphere_quadrature(QUAD_THETA)
    out = np.zeros((n, 3, 9))
    count = rng.integers(2, 5, n)
    for j in range(4):
        s = _unit(rng.normal(size=(n, 3)))
        s[:, 2] = np.abs(s[:, 2])
        k = rng.uniform(10, 60, n)
        col = rng.uniform(0.2, 1.0, (n, 3)) * rng.uniform(1, 10, (n, 1)) * (j < count)[:, None]

        def rad(dd, s=s, k=k, col=col):
            lobe = np.exp(k[:, None] * (np.einsum("mi,ni->nm", dd, s) - 1.0))
            return lobe[..., None] * col[:, None, :]

        out += _project_hemi(rad, n)
    amb = rng.uniform(0.01, 0.05, (n, 3))
    return out + _project_hemi(lambda dd: np.broadcast_to(amb[:, None, :], (n, len(dd), 3)), n)


def smooth(n, seed=2):
    """Smooth low-contrast radiance: base * (1 + 0.3 a.w + 0.1 quadratic), all positive."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.3, 1.0, (n, 3))
    a = rng.uniform(-1, 1, (n, 3))
    q = rng.uniform(-1, 1, (n, 3))

    def rad(d):
        lin = np.einsum("mi,ni->nm", d, a)
        quad = np.einsum("mi,ni->nm", d * d, q)
        return base[:, None, :] * (1.0 + 0.3 * lin + 0.1 * quad)[..., None]

    return _project_hemi(rad, n)


def horizon_light(n, seed=3):
    """A single delta light 1-10 degrees above the tangent horizon, nothing else."""
    rng = np.random.default_rng(seed)
    el = np.radians(rng.uniform(1, 10, n))
    az = rng.uniform(0, 2 * np.pi, n)
    s = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    power = rng.uniform(0.5, 2.0, (n, 3)) * np.pi
    return _add_delta(np.zeros((n, 3, 9)), s, power)


def uniform(n, seed=4):
    """A constant-radiance (coloured) sky over the whole hemisphere."""
    rng = np.random.default_rng(seed)
    col = rng.uniform(0.1, 2.0, (n, 3))
    return _project_hemi(lambda d: np.broadcast_to(col[:, None, :], (n, len(d), 3)), n)


def black(n, seed=5):
    """All zero."""
    return np.zeros((n, 3, 9))


def hdr(n, seed=6):
    """sky_sun scaled per texel by 10^U(-4, 4)."""
    rng = np.random.default_rng(seed)
    return sky_sun(n, seed=seed) * 10.0 ** rng.uniform(-4, 4, (n, 1, 1))


FAMILIES = {
    "sky+sun": sky_sun,
    "area lights": area_lights,
    "smooth": smooth,
    "horizon light": horizon_light,
    "uniform": uniform,
    "black": black,
    "hdr 1e-4..1e4": hdr,
}


def main():
    out = Path(__file__).resolve().parents[1] / "samples" / "sh" / "sky_sun.npy"
    out.parent.mkdir(parents=True, exist_ok=True)
    data = sky_sun(64, seed=2024).astype(np.float32)
    np.save(out, data)
    print(f"wrote {out} {data.shape} {data.dtype}")


if __name__ == "__main__":
    main()
