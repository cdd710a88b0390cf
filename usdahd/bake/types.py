"""Flat-array data passed between texel rasterisation and the integrator.

These are the contracts between ``usdahd/bake/texels.py`` (:class:`usdahd.scene.types.MeshData`
-> :class:`Texels`) and ``usdahd/bake/integrate.py`` (Texels + scene -> radiance SH); the scene
description itself (meshes, materials, lights) is :mod:`usdahd.scene`. Everything is world
space, right-handed, metres-agnostic (stage units), float32 unless noted.

Image convention: texel ``(x, y)`` covers UV ``[x/w, (x+1)/w] x [1-(y+1)/h, 1-y/h]``:
row 0 is the *top* of the image (v = 1), as OpenImageIO writes scanlines, so UV (0, 0) is the
bottom-left corner like USD's ``st``. The texel centre is at ``((x+0.5)/w, 1-(y+0.5)/h)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Texels"]


@dataclass
class Texels:
    """Covered texels of one mesh's lightmap.

    resolution : (width, height).
    xy : (n, 2) int32 texel column, row (row 0 = top, see module doc).
    position : (n, 3) float32 world sample point (texel centre on the surface, or for
        conservatively covered texels a point inside the part of the texel the triangle covers).
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

    def take(self, index) -> Texels:
        """The texels ``index`` selects (a slice, an int index array or a bool mask) as their own
        :class:`Texels`: copied arrays (a tile pickles small), same resolution, empty stats."""
        return Texels(
            resolution=self.resolution,
            xy=self.xy[index].copy(),
            position=self.position[index].copy(),
            geom_normal=self.geom_normal[index].copy(),
            frame=self.frame[index].copy(),
            triangle=self.triangle[index].copy(),
            center_inside=self.center_inside[index].copy(),
        )
