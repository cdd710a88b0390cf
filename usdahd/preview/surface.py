"""``usdahd preview --model-view``: the material's albedo and normal map (issue 14).

Per baked mesh and bound material (GeomSubsets split a mesh into groups) a :class:`Surface`:
the UsdPreviewSurface ``diffuseColor`` (constant or UsdUVTexture, read by
:class:`usdahd.usd.materials.MaterialReader` as the bake reads it: scale, bias, channel, wrap,
colour space, ``1 - metallic``, clamped to [0, 1]) and ``inputs:normal`` (a UsdUVTexture or a
constant, read by the same reader), with the material's texture coordinates per corner and the
MikkTSpace-style tangent frame of that UV set (:func:`usdahd.bake.texels.tangent_frames`, the
frame docs/schema.md describes).

The normal-map texture handed to the renderers holds ``0.5 m + 0.5`` where ``m`` is the
UsdUVTexture output ``scale * texel + bias`` (the tangent-space normal UsdPreviewSurface
expects), so that the shipped ``usdahd_apply_normal_map`` (which takes a UNORM texel and
computes ``2 t - 1``) gets exactly ``m``. Both backends evaluate, per pixel:

    lm = tangent_frame(normal, lightmap tangent);  mf = tangent_frame(normal, material tangent)
    N = apply_normal_map(texel, mf);  radiance * pi = albedo * I(to_tangent(lm, N))

the wgpu pipeline with the WGSL functions (:mod:`usdahd.preview.gpu`), the Embree fallback with
the numpy transcription below (:func:`tangent_frame`, :func:`apply_normal_map`,
:func:`to_tangent`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from usdahd.errors import StageError
from usdahd.scene.types import Texture

__all__ = ["Surface", "apply_normal_map", "sample", "surfaces", "tangent_frame", "to_tangent"]

#: The normal-map texel of the unperturbed normal (m = (0, 0, 1)).
FLAT_TEXEL = (0.5, 0.5, 1.0)


@dataclass
class Surface:
    """One material's triangles of one baked mesh, ready for both renderers.

    tris : (k,) int64 triangle indices into the mesh; albedo : (3,) float32 constant factor;
    albedo_tex : (h, w, 3) float32 albedo in [0, 1] or None; normal_tex : (h, w, 3) float32
    texels for ``apply_normal_map`` or None (flat); ``*_wrap`` : (wrapS, wrapT);
    st : (k, 3, 2) float32 material texcoords of the group's corners (zeros when no texture
    reads them); tangent : (k, 3, 3), sign : (k,) the material UV set's frame (the lightmap
    frame when there is no normal map: then unused).
    """

    material: str
    tris: np.ndarray
    albedo: np.ndarray
    albedo_tex: np.ndarray | None
    albedo_wrap: tuple[str, str]
    normal_tex: np.ndarray | None
    normal_wrap: tuple[str, str]
    st: np.ndarray
    tangent: np.ndarray
    sign: np.ndarray


def texels(tex: Texture) -> np.ndarray:
    """The UsdUVTexture output of every texel (h, w, len(channels)) float32
    (:meth:`Texture.outputs`); sampling the result equals ``Texture.sample``."""
    return tex.outputs()


def sample(pixels: np.ndarray, st: np.ndarray, wrap) -> np.ndarray:
    """Bilinear samples (m, 3) float64 of a prepared texture at material texcoords st (m, 2)
    with UsdUVTexture wrap modes (``Texture.sample``'s lookup, which the wgpu sampler mirrors)."""
    t = Texture("", pixels, np.ones(4, np.float32), np.zeros(4, np.float32), (0, 1, 2), wrap)
    return t.sample(np.asarray(st, np.float64)).astype(np.float64)


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def tangent_frame(normal, tangent, sign):
    """numpy ``usdahd_tangent_frame``: rows (t, b, n), each (m, 3): n = normalize(normal),
    t = tangent Gram-Schmidt against n, normalized; b = sign * cross(n, t)."""
    n = _normalize(np.asarray(normal, np.float64))
    tg = np.asarray(tangent, np.float64)
    t = _normalize(tg - n * np.einsum("ij,ij->i", n, tg)[:, None])
    return t, np.asarray(sign, np.float64)[:, None] * np.cross(n, t), n


def apply_normal_map(texel, frame):
    """numpy ``usdahd_apply_normal_map``: unit m.x t + m.y b + m.z n with m = 2 texel - 1."""
    m = 2.0 * np.asarray(texel, np.float64) - 1.0
    t, b, n = frame
    return _normalize(m[:, :1] * t + m[:, 1:2] * b + m[:, 2:3] * n)


def to_tangent(frame, v):
    """numpy ``usdahd_to_tangent``: (v.t, v.b, v.n)."""
    return np.stack([np.einsum("ij,ij->i", v, f) for f in frame], -1)


def _coords(texcoords, k, reader, prim, mesh, mat, name: str) -> np.ndarray:
    """(t, 3, 2) float32 texcoords ``name`` of a material on the mesh: the scene reader's, else
    the primvar at the corners (through its UsdTransform2d); StageError when the mesh lacks it."""
    from usdahd.usd.surface_inputs import corner_primvar

    tc = texcoords[k].get(name) if k < len(texcoords) else None
    if tc is None:
        base, a, b = reader.tc_transforms.get(name, (name, None, None))
        tc = corner_primvar(prim, base, mesh, reader.ctx.time)
        if tc is not None and a is not None:
            tc = (tc.astype(np.float64) @ a.T + b).astype(np.float32)
    if tc is None:
        raise StageError(
            f"{mesh.path}: material {mat.name} reads texture coordinates from primvar "
            f"'{name.split('@')[0]}', which the mesh lacks; author it on the mesh, or preview "
            "without --model-view"
        )
    return np.asarray(tc, np.float32)


def surfaces(stage, meshes) -> list[list[Surface]]:
    """Per entry of ``meshes`` (:func:`usdahd.preview.meshes.baked_meshes`) its
    :class:`Surface` groups, one per bound material. Raises StageError when a material's
    texture reads a primvar the mesh lacks (the fix: author it)."""
    from usdahd.bake import texels as tx
    from usdahd.preview.meshes import preview_scene
    from usdahd.usd.materials import MaterialReader
    from usdahd.usd.reader import ReadContext
    from usdahd.usd.surface_inputs import normal_input

    scenes = {}
    out = []
    for mesh, res, tangent, sign in meshes:
        uv = res.uv_primvar
        if uv not in scenes:
            sc = preview_scene(stage, uv)  # refined, as baked_meshes' meshes are
            ctx = ReadContext(stage, sc.time)
            scenes[uv] = (sc, {m.path: k for k, m in enumerate(sc.meshes)}, MaterialReader(ctx))
        sc, index, reader = scenes[uv]
        k = index[mesh.path]
        prim = stage.GetPrimAtPath(mesh.path)
        groups = []
        for mi in np.unique(np.asarray(mesh.material)):
            mat = sc.materials[int(mi)]
            tris = np.nonzero(np.asarray(mesh.material) == mi)[0]
            nconst, ntex, nname = normal_input(reader, stage, mat.name)

            def coords(name, ctx=(sc.texcoords, k, reader, prim, mesh, mat)):
                return _coords(*ctx, name)

            st = np.zeros((len(mesh.triangles), 3, 2), np.float32)
            albedo_tex = None
            if mat.albedo_tex is not None:
                st = coords(mat.texcoord)
                a = texels(mat.albedo_tex)
                if a.shape[2] == 1:
                    a = np.repeat(a, 3, axis=2)
                albedo_tex = np.clip(a, 0.0, 1.0)
            normal_tex = None
            mtan, msign = tangent, sign
            flat = nconst is None or np.allclose(nconst, (0.0, 0.0, 1.0))
            if ntex is not None or not flat:
                if ntex is not None:
                    nst = coords(nname)
                    if mat.albedo_tex is not None and nname != mat.texcoord:
                        raise StageError(
                            f"{mat.name}: diffuseColor reads '{mat.texcoord}' but normal reads "
                            f"'{nname}'; the preview shades one texture coordinate set per "
                            "material: make both textures read the same primvar"
                        )
                    st = nst
                    normal_tex = 0.5 * texels(ntex) + 0.5
                else:  # a constant tangent-space normal: a 1 x 1 map
                    nst = st
                    normal_tex = (0.5 * nconst + 0.5).reshape(1, 1, 3).astype(np.float32)
                mtan, msign = tx.tangent_frames(dataclasses.replace(mesh, uv=nst))
            groups.append(
                Surface(
                    material=mat.name,
                    tris=tris,
                    albedo=np.asarray(
                        (1.0, 1.0, 1.0) if albedo_tex is not None else np.clip(mat.albedo, 0, 1),
                        np.float32,
                    ),
                    albedo_tex=albedo_tex,
                    albedo_wrap=mat.albedo_tex.wrap
                    if mat.albedo_tex is not None
                    else ("repeat",) * 2,
                    normal_tex=normal_tex,
                    normal_wrap=ntex.wrap if ntex is not None else ("repeat", "repeat"),
                    st=st[tris],
                    tangent=np.asarray(mtan, np.float64)[tris],
                    sign=np.asarray(msign, np.float64)[tris],
                )
            )
        out.append(groups)
    return out
