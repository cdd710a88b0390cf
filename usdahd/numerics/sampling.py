"""Direction samplers with their pdfs and low-discrepancy point sets (numpy only).

Every sampler maps uniform numbers ``u`` in [0, 1)^2 to unit directions and returns the
solid-angle pdf of the direction it produced, so callers can combine strategies with
multiple importance sampling. Local frames are z-up: ``z`` is the surface normal.

Low discrepancy: the R2 sequence (Roberts 2018, the 2-D generalisation of the golden ratio
sequence) gives one well-spread point set that all texels share; each texel gets an
independent Cranley-Patterson rotation (a random toroidal shift), which keeps the point set's
stratification while making per-texel estimates independent and unbiased.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SPHERICAL_RECT_MAX_SR",
    "SPHERICAL_RECT_MIN_SR",
    "concentric_disk",
    "cone_local",
    "cosine_hemisphere",
    "orthonormal_basis",
    "r2_sequence",
    "sample_discrete",
    "spherical_rectangle",
    "texel_hemisphere",
    "texel_hemisphere_pdf",
    "to_local",
    "to_world",
    "uniform_hemisphere",
]

TWO_PI = 2.0 * np.pi
#: Plastic number: the R2 sequence's generator (x^3 = x + 1).
_PLASTIC = 1.324717957244746025960908854
R2_ALPHA = np.array([1.0 / _PLASTIC, 1.0 / (_PLASTIC * _PLASTIC)])


def r2_sequence(n: int, offset: int = 0) -> np.ndarray:
    """First ``n`` points of the R2 low-discrepancy sequence in [0, 1)^2.

    returns : (n, 2) float64.
    """
    i = np.arange(offset + 1, offset + n + 1, dtype=np.float64)[:, None]
    return np.mod(0.5 + i * R2_ALPHA[None, :], 1.0)


def cranley_patterson(points: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Toroidally shift one point set by one random offset per group.

    points : (s, d) in [0,1); shifts : (m, d) in [0,1).
    returns : (m, s, d) float64 in [0,1).
    """
    return np.mod(points[None, :, :] + shifts[:, None, :], 1.0)


def uniform_hemisphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform directions on the z >= 0 hemisphere (equal-area map: z = u0).

    u : (..., 2).  returns : dirs (..., 3), pdf (...,) = 1/(2 pi).
    """
    z = u[..., 0]
    phi = TWO_PI * u[..., 1]
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    d = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)
    return d, np.full(z.shape, 1.0 / TWO_PI)


def texel_hemisphere_pdf(z: np.ndarray) -> np.ndarray:
    """Solid-angle pdf of :func:`texel_hemisphere` at local z: ``(1 + 2 z) / (4 pi)``."""
    return (1.0 + 2.0 * np.asarray(z)) / (2.0 * TWO_PI)


def texel_hemisphere_z(u0: np.ndarray) -> np.ndarray:
    """Inverse CDF of :func:`texel_hemisphere` in z: ``z = (sqrt(1 + 8 u) - 1) / 2``."""
    return 0.5 * (np.sqrt(1.0 + 8.0 * np.asarray(u0)) - 1.0)


def texel_hemisphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions on the z >= 0 hemisphere with pdf (1 + 2z)/(4 pi): the even mixture of
    uniform (1/2pi) and cosine (z/pi) sampling, drawn by one inverse-CDF warp (so a
    low-discrepancy point set stays stratified). Irradiance-weighted terms (I_z, the z
    coefficient) get most of the cosine lobe's variance reduction (3.4x lower variance of I_z
    under constant radiance), while 1/pdf stays bounded by 4 pi, so SH coefficients that do not
    vanish at the horizon keep a finite variance (pure cosine sampling makes theirs infinite).

    u : (..., 2).  returns : dirs (..., 3), pdf (...,).
    """
    z = texel_hemisphere_z(u[..., 0])
    phi = TWO_PI * u[..., 1]
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    d = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)
    return d, texel_hemisphere_pdf(z)


def cosine_hemisphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cosine-weighted directions on the z >= 0 hemisphere (Malley's method).

    u : (..., 2).  returns : dirs (..., 3), pdf (...,) = z / pi.
    """
    r = np.sqrt(u[..., 0])
    phi = TWO_PI * u[..., 1]
    z = np.sqrt(np.clip(1.0 - u[..., 0], 0.0, None))
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    return d, z / np.pi


def uniform_sphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform directions on the unit sphere.

    u : (..., 2).  returns : dirs (..., 3), pdf (...,) = 1/(4 pi).
    """
    z = 1.0 - 2.0 * u[..., 0]
    phi = TWO_PI * u[..., 1]
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    d = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)
    return d, np.full(z.shape, 1.0 / (4.0 * np.pi))


def cone_local(u: np.ndarray, one_minus_cos_max) -> np.ndarray:
    """Uniform directions (..., 3) in the cone around +z of solid angle
    2 pi ``one_minus_cos_max``: z = 1 - u0 (1 - cos_max), phi = 2 pi u1.

    Stable for tiny cones (distant spheres, the sun): the sine is sqrt(u0 (1 - cos_max)(1 + z))
    (= sqrt(1 - z^2) without its cancellation), so pass 1 - cos_max, not cos_max. The one cone
    sampler: :func:`uniform_cone`, the numpy lights (usdahd.scene.lights) and its numba twin
    ``usdahd.bake.kernels.lights._cone`` (tests/test_kernel_parity.py) use this rule.
    u : (..., 2); one_minus_cos_max : broadcastable to (...,), in (0, 2].
    """
    z = 1.0 - u[..., 0] * one_minus_cos_max
    phi = TWO_PI * u[..., 1]
    s = np.sqrt(np.clip(u[..., 0] * one_minus_cos_max * (1.0 + z), 0.0, None))  # sqrt(1-z^2)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def uniform_cone(u: np.ndarray, cos_max: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Uniform directions in the cone of half-angle acos(cos_max) around +z
    (:func:`cone_local`).

    u : (..., 2); cos_max : broadcastable to (...,), in [-1, 1).
    returns : dirs (..., 3), pdf (...,) = 1 / (2 pi (1 - cos_max)).
    """
    omc = 1.0 - np.asarray(cos_max, dtype=np.float64)
    d = cone_local(u, omc)
    pdf = np.broadcast_to(1.0 / (TWO_PI * omc), d.shape[:-1])
    return d, np.array(pdf)


def cone_pdf(cos_max: np.ndarray | float) -> np.ndarray:
    """Solid-angle pdf of :func:`uniform_cone`."""
    return 1.0 / (TWO_PI * (1.0 - np.asarray(cos_max, dtype=np.float64)))


def concentric_disk(u: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of the unit square onto the unit disk (area preserving).

    u : (..., 2).  returns : (..., 2) points with |p| <= 1, uniform in area.
    """
    a = 2.0 * u[..., 0] - 1.0
    b = 2.0 * u[..., 1] - 1.0
    first = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    r = np.where(first, a, b)
    theta = np.where(first, (np.pi / 4) * (b / safe_a), (np.pi / 2) - (np.pi / 4) * (a / safe_b))
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=-1)


def orthonormal_basis(n: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal frames whose third row is ``n`` (Duff et al. 2017, branchless).

    n : (..., 3) unit vectors.  returns : (..., 3, 3) rows = tangent, bitangent, n.
    """
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bt = np.stack([b, sign + y * y * a, -y], axis=-1)
    return np.stack([t, bt, n], axis=-2)


def to_world(local: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Local (frame) coordinates to world: ``local @ frame``.

    local : (..., 3); frame : (..., 3, 3) rows = axes.  returns : (..., 3).
    """
    return np.einsum("...i,...ij->...j", local, frame)


def to_local(world: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """World directions into frame coordinates: ``frame @ world``."""
    return np.einsum("...ij,...j->...i", frame, world)


def sample_discrete(cdf: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Indices drawn from a discrete distribution given its normalized CDF.

    cdf : (k,) non-decreasing, last element 1.  u : (...,) in [0,1).
    returns : (...,) int64 in [0, k).
    """
    idx = np.searchsorted(cdf, u, side="right")
    return np.minimum(idx, cdf.shape[0] - 1)


def balance_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    """MIS balance-heuristic weight of strategy a: ``pa / (pa + pb)`` (0 where both are 0)."""
    den = pdf_a + pdf_b
    return np.divide(pdf_a, den, out=np.zeros_like(den, dtype=np.float64), where=den > 0)


#: Rectangles are sampled by solid angle when the solid angle estimated from their centre
#: (area x cos / d^2) is at least SPHERICAL_RECT_MIN_SR and the exact one at most
#: SPHERICAL_RECT_MAX_SR. Below, the rectangle is far and small: the distance barely varies
#: over it, so area sampling has almost the same variance at half the cost per sample (the
#: spherical set-up costs four arcsines; measured on samples/cornell_box, whose light subtends
#: ~0.06 sr from the floor: 3.1 vs 6.2 Mrays per CPU second with and without it). Above, the
#: point almost touches it and area sampling is better conditioned (pbrt-v4's
#: MaxSphericalSampleArea).
SPHERICAL_RECT_MIN_SR = 0.1
SPHERICAL_RECT_MAX_SR = 6.22


def _angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (..., 3), accurate near 0 and pi (pbrt's AngleBetween)."""
    dot = np.einsum("...i,...i->...", a, b)
    near = 2.0 * np.arcsin(np.clip(np.linalg.norm(b - a, axis=-1) / 2.0, 0.0, 1.0))
    far = np.pi - 2.0 * np.arcsin(np.clip(np.linalg.norm(a + b, axis=-1) / 2.0, 0.0, 1.0))
    return np.where(dot < 0, far, near)


def spherical_rectangle(
    o: np.ndarray, corner: np.ndarray, ex: np.ndarray, ey: np.ndarray, u: np.ndarray | None
):
    """Uniform sampling of the solid angle a rectangle subtends (Urena, Fajardo and King 2013).

    o : (m, 3) float64 reference points; corner : (3,) one corner; ex, ey : (3,) its two
    (orthogonal) edges from ``corner``; u : (m, 2) in [0, 1) or None (solid angle only).
    returns : (points (m, 3) float64 on the rectangle, or None; solid_angle (m,) float64 sr).
    The pdf of the direction to ``points`` is 1 / solid_angle.
    """
    o = np.asarray(o, np.float64)
    exl, eyl = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
    x, y = ex / exl, ey / eyl
    z = np.cross(x, y)
    dl = corner[None, :] - o
    x0, y0, z0 = dl @ x, dl @ y, dl @ z
    flip = z0 > 0  # z points away from the rectangle in the local frame
    z0 = np.where(flip, -z0, z0)
    x1, y1 = x0 + exl, y0 + eyl

    def unit(v):
        return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)

    zero = np.zeros_like(z0)
    # normals of the planes through o and each edge (v00 -> v10 -> v11 -> v01)
    n0 = unit(np.stack([zero, z0, -y0], -1))
    n1 = unit(np.stack([-z0, zero, x1], -1))
    n2 = unit(np.stack([zero, -z0, y1], -1))
    n3 = unit(np.stack([z0, zero, -x0], -1))
    g0, g1 = _angle_between(-n0, n1), _angle_between(-n1, n2)
    g2, g3 = _angle_between(-n2, n3), _angle_between(-n3, n0)
    solid = np.maximum(g0 + g1 + g2 + g3 - 2.0 * np.pi, 0.0)
    if u is None:
        return None, solid
    b0, b1 = n0[:, 2], n2[:, 2]
    au = u[:, 0] * solid - g2 - g3
    sin_au = np.sin(au)
    fu = (np.cos(au) * b0 - b1) / np.where(sin_au == 0, 1e-300, sin_au)
    cu = np.copysign(1.0 / np.sqrt(fu * fu + b0 * b0), fu)
    cu = np.clip(cu, -1.0 + 1e-12, 1.0 - 1e-12)
    xu = np.clip(-(cu * z0) / np.sqrt(np.maximum(1.0 - cu * cu, 0.0)), x0, x1)
    dd = np.sqrt(xu * xu + z0 * z0)
    h0 = y0 / np.sqrt(dd * dd + y0 * y0)
    h1 = y1 / np.sqrt(dd * dd + y1 * y1)
    hv = h0 + u[:, 1] * (h1 - h0)
    hv2 = hv * hv
    yv = np.where(hv2 < 1.0 - 1e-12, hv * dd / np.sqrt(np.maximum(1.0 - hv2, 1e-300)), y1)
    zw = np.where(flip, -1.0, 1.0)[:, None] * z[None, :]
    pts = o + xu[:, None] * x[None, :] + yv[:, None] * y[None, :] + z0[:, None] * zw
    return pts, solid
