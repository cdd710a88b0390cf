"""Triangle geometry and texel frames: the one home of area, normal, barycentrics and the
tangent frame a lightmap texel's SH is expressed in (numpy only).

Triangles are ``p : (n, 3, 3) float64`` (triangle, corner, xyz). ``edge_cross(p)`` is
``(p1 - p0) x (p2 - p0)``: the geometric normal scaled by twice the area, counter-clockwise
positive; every other function here is built on it, so each caller computes the same bits.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "TINY2",
    "any_perpendicular",
    "barycentrics",
    "edge_cross",
    "normalize",
    "texel_frame",
    "triangle_areas",
    "unit_normals",
    "uv_areas",
]

#: Squared length below which a vector is treated as zero (tangent/normal fallbacks).
TINY2 = 1e-24


def edge_cross(p: np.ndarray) -> np.ndarray:
    """(n, 3) ``(p1 - p0) x (p2 - p0)`` of triangles ``p`` (n, 3, 3)."""
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def triangle_areas(p: np.ndarray) -> np.ndarray:
    """(n,) areas of triangles ``p`` (n, 3, 3)."""
    return 0.5 * np.linalg.norm(edge_cross(p), axis=1)


def uv_areas(uv: np.ndarray) -> np.ndarray:
    """(n,) unsigned areas of 2-D (UV) triangles ``uv`` (n, 3, 2), in UV units squared."""
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit vectors (..., 3), mask (...) of inputs longer than sqrt(TINY2)); zero where not."""
    n2 = np.einsum("...i,...i->...", v, v)
    ok = n2 > TINY2
    out = np.where(ok[..., None], v / np.sqrt(np.where(ok, n2, 1.0))[..., None], 0.0)
    return out, ok


def unit_normals(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit geometric normals (n, 3), mask (n,) of non-degenerate triangles) of ``p``."""
    return normalize(edge_cross(p))


def barycentrics(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Barycentric weights (n, 3) float64 of points ``q`` (n, 3) on triangles ``p`` (n, 3, 3)
    (of q projected into each triangle's plane; zero-area triangles give zeros)."""
    n = edge_cross(p)
    nn = np.einsum("ni,ni->n", n, n)
    nn = np.where(nn > 0, nn, 1.0)
    lam = np.stack(
        [
            np.einsum("ni,ni->n", np.cross(p[:, 2] - p[:, 1], q - p[:, 1]), n),
            np.einsum("ni,ni->n", np.cross(p[:, 0] - p[:, 2], q - p[:, 2]), n),
            np.einsum("ni,ni->n", np.cross(p[:, 1] - p[:, 0], q - p[:, 0]), n),
        ],
        axis=1,
    )
    return lam / nn[:, None]


def any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to unit ``n`` (..., 3): Duff et al. 2017 branchless ONB."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    return np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)


def texel_frame(shade: np.ndarray, tangent: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """The lightmap tangent frame (m, 3, 3) float64, rows (t, b, n), of texels with unit shading
    normal ``shade`` (m, 3), interpolated tangent ``tangent`` (m, 3) and handedness ``sign``
    (m,): t = tangent Gram-Schmidt against n, normalised (any perpendicular where it vanishes);
    b = sign * (n x t); n = shade (docs/schema.md, ``tangentFrame = "mikktspace_uv"``)."""
    tan = tangent - shade * np.einsum("ni,ni->n", shade, tangent)[:, None]
    tan, tok = normalize(tan)
    tan = np.where(tok[:, None], tan, any_perpendicular(shade))
    bit = sign[:, None] * np.cross(shade, tan)
    return np.stack([tan, bit, shade], axis=1)
