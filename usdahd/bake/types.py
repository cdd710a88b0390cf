"""Flat-array data passed between scene extraction, texel rasterisation and the integrator.

These are the contracts between ``usdahd/usd/scene.py`` (stage -> MeshData),
``usdahd/bake/texels.py`` (MeshData -> Texels) and ``usdahd/bake/integrate.py``
(Texels + scene -> radiance SH). Everything is world space, right-handed, metres-agnostic
(stage units), float32 unless noted.

Image convention: texel ``(x, y)`` covers UV ``[x/w, (x+1)/w] x [1-(y+1)/h, 1-y/h]``:
row 0 is the *top* of the image (v = 1), as OpenImageIO writes scanlines, so UV (0, 0) is the
bottom-left corner like USD's ``st``. The texel centre is at ``((x+0.5)/w, 1-(y+0.5)/h)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class MeshData:
    """One UsdGeom.Mesh (or flattened instance) after triangulation, in world space.

    path : prim path string (instance proxies get their proxy path).
    points : (v, 3) float64 world positions.
    triangles : (t, 3) int32 vertex indices, counter-clockwise seen from the front side
        (``orientation = leftHanded`` and mirrored transforms already fixed).
    normals : (t, 3, 3) float32 per-corner unit world normals (authored or smooth-computed).
    uv : (t, 3, 2) float32 per-corner lightmap UVs, or None when the mesh has no such set.
    uv_name : name of the lightmap UV primvar read (or to author), e.g. "st".
    material : (t,) int32 index into the scene's material table.
    face : (t,) int32 index of the source polygon of each triangle.
    corner : (t, 3) int32 index of each triangle corner into the source mesh's
        faceVertexIndices (so per-corner data such as an unwrapped UV set can be authored back
        as a faceVarying primvar).
    bake : whether this mesh receives a lightmap (False: occluder only).
    """

    path: str
    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None
    uv_name: str
    material: np.ndarray
    face: np.ndarray
    corner: np.ndarray
    bake: bool = True
    warnings: list[str] = field(default_factory=list)


@dataclass
class Texels:
    """Covered texels of one mesh's lightmap.

    resolution : (width, height).
    xy : (n, 2) int32 texel column, row (row 0 = top, see module doc).
    position : (n, 3) float32 world sample point (texel centre on the surface, or the closest
        point on the triangle for conservatively covered texels).
    geom_normal : (n, 3) float32 unit geometric normal of the sampled triangle (ray offsets).
    frame : (n, 3, 3) float32 rows = tangent, bitangent, shading normal (orthonormal,
        right-handed except on mirrored UV charts, where b = -cross(n, t) and det = -1); the
        tangent space the directional data lives in.
    triangle : (n,) int32 triangle index the sample lies on.
    center_inside : (n,) bool whether the texel centre itself lies inside a triangle.
    """

    resolution: tuple[int, int]
    xy: np.ndarray
    position: np.ndarray
    geom_normal: np.ndarray
    frame: np.ndarray
    triangle: np.ndarray
    center_inside: np.ndarray
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.xy.shape[0])
