"""Alpha cut-outs and fractional opacity in ``usdahd preview``'s wgpu rasteriser (issue 37).

The baker and the Embree preview trace through transmissive surfaces by the rule of
:meth:`usdahd.bake.trace.Tracer.intersect` (UsdPreviewSurface ``opacity`` and
``opacityThreshold``, a constant or a UsdUVTexture channel such as a diffuse texture's alpha):

- ``opacityThreshold > 0`` (a cut-out): the surface is absent where ``opacity < threshold``;
- ``opacityThreshold == 0`` and ``opacity < 1``: a ray passes with probability ``1 - opacity``.

The rasteriser applies the same rule per fragment (:func:`usdahd.preview.gpu.render`): the
opacity is sampled bilinearly at the material's texture coordinate (the primvar the material's
textures read, zeros where the mesh lacks it, as the tracer's per-triangle texcoords), and the
fragment is discarded below the threshold, or, without a threshold, when a per-pixel hash in
[0, 1) is at or above the opacity (screen-door transparency: the same expectation as the
tracer's coin flip, a different noise pattern). Without this the rasteriser drew a cut-out
quad's transparent texels as solid surface (McUsd's fern, sunflowers, rails).

numpy only; the stage's materials are read by :func:`usdahd.preview.meshes.preview_scene`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Cutout", "cutouts", "opaque_triangles"]


@dataclass
class Cutout:
    """One transmissive material's triangles of one baked mesh.

    material : the material's path; tris : (k,) int64 triangle indices into the mesh;
    opacity : the constant opacity (used when ``texture`` is None); threshold : the
    opacityThreshold (> 0: cut-out); texture : (h, w, 1) float32 UsdUVTexture output of the
    opacity channel (:meth:`usdahd.scene.types.Texture.outputs`) or None; wrap : (wrapS, wrapT);
    st : (k, 3, 2) float32 the material's texture coordinates at the corners.
    """

    material: str
    tris: np.ndarray
    opacity: float
    threshold: float
    texture: np.ndarray | None
    wrap: tuple[str, str]
    st: np.ndarray

    def uniform(self) -> np.ndarray:
        """(4,) float32 for the shader: opacity constant, threshold, 1 if textured, 0."""
        return np.array(
            [self.opacity, self.threshold, 0.0 if self.texture is None else 1.0, 0.0], np.float32
        )


def cutouts(stage, meshes) -> list[list[Cutout]]:
    """Per entry of ``meshes`` (:func:`usdahd.preview.meshes.baked_meshes`) its
    :class:`Cutout` groups, one per transmissive material bound to it (empty for opaque
    meshes): the materials and texture coordinates the bake traced
    (:func:`usdahd.preview.meshes.preview_scene` of ``stage``, per lightmap UV set)."""
    from usdahd.preview.meshes import preview_scene

    scenes = {}
    out = []
    for mesh, res, *_ in meshes:
        uv = res.uv_primvar
        if uv not in scenes:
            sc = preview_scene(stage, uv)
            scenes[uv] = (sc, {m.path: k for k, m in enumerate(sc.meshes)})
        scene, index = scenes[uv]
        k = index.get(mesh.path)
        tcs = scene.texcoords[k] if k is not None and k < len(scene.texcoords) else {}
        groups = []
        material = np.asarray(mesh.material)
        for mi in np.unique(material):
            mat = scene.materials[int(mi)]
            if not mat.transmissive:
                continue
            tris = np.nonzero(material == mi)[0]
            st = np.zeros((len(tris), 3, 2), np.float32)
            if mat.texcoord in tcs:
                st = np.asarray(tcs[mat.texcoord], np.float32)[tris]
            tex = mat.opacity_tex
            groups.append(
                Cutout(
                    material=mat.name,
                    tris=tris,
                    opacity=float(mat.opacity),
                    threshold=float(mat.opacity_threshold),
                    texture=None if tex is None else tex.outputs()[..., :1],
                    wrap=("repeat", "repeat") if tex is None else tuple(tex.wrap),
                    st=st,
                )
            )
        out.append(groups)
    return out


def opaque_triangles(n: int, groups: list[Cutout]) -> np.ndarray:
    """(k,) int64 the triangles of an ``n``-triangle mesh in none of its cut-out ``groups``."""
    keep = np.ones(n, bool)
    for g in groups:
        keep[g.tris] = False
    return np.nonzero(keep)[0]
