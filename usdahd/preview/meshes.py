"""The baked meshes ``usdahd preview`` draws: read from a baked layer, as vertex arrays."""

from __future__ import annotations

import numpy as np

from usdahd.errors import StageError, UsageError

__all__ = ["baked_meshes", "draw_items", "preview_scene", "render_view", "vertex_data"]


def preview_scene(stage, uv: str):
    """The stage's Scene as the bake traced it: subdivision meshes (catmullClark / loop)
    replaced by their refinement (:func:`usdahd.scene.subdiv.refine_scene`; texels still
    addressed through the cage's lightmap UVs)."""
    from usdahd.scene import subdiv
    from usdahd.usd.reader import load_scene

    sc = load_scene(stage, uv_name=uv)
    subdiv.refine_scene(sc, [])
    return sc


def baked_meshes(layer: str):
    """[(MeshData, BakeResults)] of every baked mesh, and the stage's up axis."""
    from usdahd.bake import texels
    from usdahd.usd import schema
    from usdahd.usd.stage import open_stage

    stage = open_stage(layer)  # re-read from disk when this process opened it before
    # Mesh records and instance entries (each copy its own lightmap), by the scene's mesh path.
    records = schema.stage_records(stage)
    if not records:
        raise UsageError(f"{layer}: no baked prim (formatVersion 0); run usdahd bake first")
    out, up = [], "Y"
    for uv in sorted({r.uv_primvar for r in records.values()}):
        sc = preview_scene(stage, uv)
        up = sc.up_axis
        for mesh in sc.meshes:
            res = records.get(mesh.path)
            if res is None or res.uv_primvar != uv:
                continue
            if mesh.uv is None:
                raise StageError(f"{mesh.path}: the baked UV set {uv!r} is missing")
            tangent, sign = texels.tangent_frames(mesh)
            out.append((mesh, res, tangent, sign))
    if not out:
        raise StageError(f"{layer}: the baked prims are not visible meshes of the stage")
    return stage, out, up


def vertex_data(mesh, tangent, sign, surface=None, cutout=None, tris=None) -> np.ndarray:
    """Per-corner vertices (3t, 12) float32: position, lightmap st, normal, tangent + sign;
    with a :class:`usdahd.preview.surface.Surface` (--model-view) the group's triangles only,
    (3k, 18): then also the material's texcoord and tangent + sign. With a
    :class:`usdahd.preview.cutout.Cutout` its triangles only, and 2 more floats: the cut-out's
    texcoord. ``tris``: only these triangles (without a surface or cut-out)."""
    if cutout is not None:  # a Surface of the same material holds the same triangles
        tris = cutout.tris
    elif surface is not None:
        tris = surface.tris
    elif tris is None:
        tris = np.arange(len(mesh.triangles))
    t = len(tris)
    base = 12 if surface is None else 18
    pos = np.asarray(mesh.points, np.float64)[np.asarray(mesh.triangles)[tris]]
    v = np.zeros((t, 3, base + (2 if cutout is not None else 0)), np.float32)
    v[..., 0:3] = pos
    v[..., 3:5] = np.asarray(mesh.uv)[tris]
    v[..., 5:8] = np.asarray(mesh.normals)[tris]
    v[..., 8:11] = np.asarray(tangent)[tris]
    v[..., 11] = np.asarray(sign)[tris][:, None]
    if surface is not None:
        v[..., 12:14] = surface.st
        v[..., 14:17] = surface.tangent
        v[..., 17] = surface.sign[:, None]
    if cutout is not None:
        v[..., base : base + 2] = cutout.st
    return v.reshape(-1, v.shape[-1])


def _textures(mesh, res, ahd_classic: bool = False) -> tuple:
    """(model, ratio, textures, factors) a renderer draws of one baked mesh: its stored textures
    in the layout order, or with ``ahd_classic`` the classic C_a, d, C_d textures
    (:func:`usdahd.preview.classic.item`; UsageError for a model it does not apply to)."""
    from usdahd import models
    from usdahd.usd import schema

    layout = models.get(res.model).layout(res.ratio)
    textures = [schema.read_record_pixels(res, t.role, t.channels) for t in layout]
    if not ahd_classic:
        return res.model, res.ratio, textures, res.factors
    from usdahd.preview import classic

    classic.check(mesh.path, res.model)
    return classic.item(res.model, res.ratio, textures, res.factors)


def draw_items(meshes, surfaces=None, ahd_classic: bool = False, cutouts=None) -> list:
    """[(vertices (3t, 12), model, ratio, textures [(h, w, c) stored pixels], factors)] of
    ``meshes`` (:func:`baked_meshes`), textures in the model's layout order: what
    :func:`usdahd.preview.gpu.render` draws. With ``surfaces``
    (:func:`usdahd.preview.surface.surfaces`, --model-view): one item per mesh and material,
    the Surface appended. ``ahd_classic``: the classic AHD textures instead
    (:mod:`usdahd.preview.classic`). With ``cutouts`` (:func:`usdahd.preview.cutout.cutouts`)
    a mesh's transmissive materials are drawn as items of their own, the Cutout appended after
    the Surface (None without --model-view), which the fragment shader discards by the
    tracer's opacity rule."""
    from usdahd.preview.cutout import opaque_triangles

    items = []
    for k, (mesh, res, tangent, sign) in enumerate(meshes):
        drawn = _textures(mesh, res, ahd_classic)
        cuts = cutouts[k] if cutouts is not None else []
        if surfaces is None:
            if not cuts:
                items.append((vertex_data(mesh, tangent, sign), *drawn))
                continue
            rest = opaque_triangles(len(mesh.triangles), cuts)
            if len(rest):
                items.append((vertex_data(mesh, tangent, sign, tris=rest), *drawn))
            for cut in cuts:
                items.append((vertex_data(mesh, tangent, sign, cutout=cut), *drawn, None, cut))
            continue
        by_material = {c.material: c for c in cuts}
        for surf in surfaces[k]:
            cut = by_material.get(surf.material)
            verts = vertex_data(mesh, tangent, sign, surf, cutout=cut)
            items.append((verts, *drawn, surf) if cut is None else (verts, *drawn, surf, cut))
    return items


def render_view(
    stage, meshes, items, viewproj: np.ndarray, size, dev=None, surfaces=None, ahd_classic=False
) -> np.ndarray:
    """The preview image (H, W, 4) float32 of ``items`` (:func:`draw_items` of ``meshes``,
    with ``surfaces`` for --model-view): rasterised on the wgpu device ``dev``, or with ``dev``
    None by the Embree fallback (:mod:`usdahd.preview.raytrace`, the stage's materials);
    ``ahd_classic`` as given to :func:`draw_items`."""
    if dev is not None:
        from usdahd.preview.gpu import render

        return render(dev, items, viewproj, size)
    from usdahd.preview import raytrace

    scene = preview_scene(stage, meshes[0][1].uv_primvar)  # the materials
    if surfaces is None and len(items) == len(meshes):  # one item per mesh: reuse its textures
        traced = [(mesh,) + it[1:5] for (mesh, *_), it in zip(meshes, items)]
        return raytrace.render(scene, traced, viewproj, size)
    traced = []
    for mesh, res, *_ in meshes:  # one entry per mesh: the tracer holds each once
        traced.append((mesh, *_textures(mesh, res, ahd_classic)))
    if surfaces is None:
        return raytrace.render(scene, traced, viewproj, size)
    frames = [(tangent, sign) for _, _, tangent, sign in meshes]
    return raytrace.render(scene, traced, viewproj, size, surfaces=surfaces, frames=frames)
