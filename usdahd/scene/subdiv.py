"""Subdivision surfaces at bake time: a ``catmullClark`` / ``loop`` mesh is traced on a
refinement of its control cage (docs/usd-semantics.md, "Subdivision surfaces").

The scene reader keeps every mesh as its cage (what the layer holds: the lightmap UVs are
checked, unwrapped, hashed and authored per cage corner) and records the cage's polygons in
:class:`Cage`. Once the UV set of every baked mesh is known (after planning),
:func:`refine_scene` swaps each subdivision mesh of the scene for its refinement
(:func:`usdahd.numerics.subdivision.refine`): limit-surface positions and normals, the
lightmap UVs and material texture coordinates refined linearly within each cage face, the cage
face's material and index. A texel addressed through the cage's UVs lands on the refined
surface at the same cage-face parameter. :func:`restore_scene` puts the cages back.

numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from usdahd.numerics import subdivision as SD
from usdahd.numerics.triangles import uv_areas
from usdahd.scene.types import MeshData

__all__ = ["SUBDIV_VERSION", "cage_from_topology", "refine_scene", "restore_scene"]

#: Refinement levels by default (each level multiplies the faces by 4; Catmull-Clark's first
#: level turns an n-gon into n quads).
DEFAULT_LEVELS = 2
#: Levels used at most (a baked cage face spanning many texels gets one more level).
MAX_LEVELS = 3
#: A baked mesh whose cage faces span this many texels on average gets MAX_LEVELS: level 3 cuts
#: a quad into 8 x 8 sub-quads, ~2 x 2 texels each at 16 x 16 texels per face.
TEXELS_FOR_MAX_LEVEL = 16 * 16
#: Refined triangles allowed per mesh: levels are lowered (down to 0: the cage) to stay below.
MAX_REFINED_TRIANGLES = 2_000_000
#: Refined triangles allowed over the whole scene (instanced copies count each time): baked
#: meshes are refined first, then occluders, each with the levels that still fit.
MAX_SCENE_REFINED_TRIANGLES = 6_000_000
#: Part of the bake's generator id: change it when refined surfaces change.
SUBDIV_VERSION = "subdiv-1: CC/Loop uniform, 2 levels (3 for >= 256 texels/face), CC limit"


@dataclass
class Cage:
    """The control cage of a subdivision mesh, as the reader found it.

    scheme : "catmullClark" or "loop".
    counts : (f,) int64 polygon sizes (faces with 3 or more corners).
    indices : (c,) int64 point indices of those polygons, counter-clockwise seen from the front
        (orientation and mirrored transforms fixed), into ``MeshData.points``.
    corners : (c,) int64 the faceVertexIndices position of each cage corner (what
        ``MeshData.corner`` indexes).
    faces : (f,) int64 the source face index of each polygon (what ``MeshData.face`` holds).
    """

    scheme: str
    counts: np.ndarray
    indices: np.ndarray
    corners: np.ndarray
    faces: np.ndarray


def cage_from_topology(scheme, counts, idx, flip: bool) -> Cage:
    """A :class:`Cage` from faceVertexCounts / faceVertexIndices; ``flip`` reverses every
    polygon's winding (left-handed orientation or a mirroring transform)."""
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(idx, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    keep = counts >= 3
    c = counts[keep]
    s = start[keep]
    face = np.repeat(np.arange(len(c)), c)
    first = np.concatenate([[0], np.cumsum(c)[:-1]])
    k = np.arange(int(c.sum())) - first[face]
    if flip:  # (0, 1, ..., n-1) -> (0, n-1, ..., 1)
        k = np.where(k == 0, 0, c[face] - k)
    corners = s[face] + k
    return Cage(scheme, c, idx[corners], corners, np.flatnonzero(keep).astype(np.int64))


def refined_triangles(cage: Cage, levels: int) -> int:
    """Triangles of ``cage`` after ``levels`` levels (0: its fan triangulation)."""
    if levels == 0:
        return int((cage.counts - 2).sum())
    if cage.scheme == "loop" and np.all(cage.counts == 3):
        return len(cage.counts) * 4**levels
    return 2 * len(cage.indices) * 4 ** (levels - 1)


def choose_levels(mesh: MeshData, cage: Cage, resolution=None, budget=None) -> int:
    """DEFAULT_LEVELS, MAX_LEVELS for a baked mesh whose cage faces average
    TEXELS_FOR_MAX_LEVEL texels or more, lowered to keep MAX_REFINED_TRIANGLES (and
    ``budget``, the scene's triangles left)."""
    levels = DEFAULT_LEVELS
    if resolution is not None and mesh.uv is not None and len(cage.counts):
        uv = np.asarray(mesh.uv, np.float64)
        area = uv_areas(uv).sum()
        per_face = area * float(resolution[0]) * float(resolution[1]) / len(cage.counts)
        if per_face >= TEXELS_FOR_MAX_LEVEL:
            levels = MAX_LEVELS
    cap = MAX_REFINED_TRIANGLES if budget is None else min(MAX_REFINED_TRIANGLES, budget)
    while levels > 0 and refined_triangles(cage, levels) > cap:
        levels -= 1
    return levels


def _corner_values(values, mesh: MeshData, cage: Cage):
    """Per-triangle-corner (t, 3, k) values -> (per cage corner (c, k), None), or (None, why)
    when a cage corner is in no triangle (its triangles were dropped as degenerate) or the
    triangles of one polygon disagree on a corner's value (an unwrap that cut the polygon)."""
    v = np.asarray(values, np.float64).reshape(-1, np.shape(values)[-1])
    corner = np.asarray(mesh.corner).reshape(-1)
    n = int(max(cage.corners.max(initial=-1), corner.max(initial=-1))) + 1
    out = np.full((n, v.shape[1]), np.nan)
    out[corner] = v
    if np.any(np.abs(out[corner] - v) > 1e-6):
        return None, "the triangles of a polygon hold different UVs at one corner"
    res = out[cage.corners]
    if np.isnan(res).any():
        return None, "degenerate cage triangles were dropped"
    return res, None


def refine_mesh(mesh: MeshData, texcoords: dict, levels: int):
    """The refined MeshData of a subdivision mesh and its refined material texcoords, or
    (None, reason) when it cannot be refined (the cage is traced)."""
    cage: Cage = mesh.cage
    fv = []
    if mesh.uv is not None:
        uv, why = _corner_values(mesh.uv, mesh, cage)
        if uv is None:
            return None, why
        fv.append(uv)
    names = sorted(texcoords)
    for name in names:
        tc, why = _corner_values(texcoords[name], mesh, cage)
        if tc is None:
            return None, f"texture coordinates {name}: {why}"
        fv.append(tc)
    n_src = int(max(cage.faces.max(initial=-1), np.asarray(mesh.face).max(initial=-1))) + 1
    face_mat = np.zeros(n_src, np.int32)
    face_mat[np.asarray(mesh.face)] = np.asarray(mesh.material)
    p, tris, parent, vals, vn = SD.refine(
        mesh.points, cage.counts, cage.indices, cage.scheme, levels, fv
    )
    src_face = cage.faces[parent]
    start = np.concatenate([[0], np.cumsum(cage.counts)[:-1]])
    corner = np.repeat(cage.corners[start[parent]][:, None], 3, axis=1)
    uv = vals.pop(0).astype(np.float32) if mesh.uv is not None else None
    refined = MeshData(
        path=mesh.path,
        points=p,
        triangles=tris.astype(np.int32),
        normals=vn[tris].astype(np.float32),
        uv=uv,
        uv_name=mesh.uv_name,
        material=face_mat[src_face].astype(np.int32),
        face=src_face.astype(np.int32),
        corner=corner.astype(np.int32),
        bake=mesh.bake,
        warnings=mesh.warnings,
        double_sided=mesh.double_sided,
    )
    tcs = {n: v.astype(np.float32) for n, v in zip(names, vals, strict=True)}
    return (refined, tcs), None


def refine_scene(scene, jobs) -> list:
    """Swap every subdivision mesh of ``scene`` (and of ``jobs``) for its refinement.

    jobs : PrimJobs (``mesh``, ``resolution``, ``texels``, ``report``); their texels are
    cleared (re-rasterised on the refined triangles). returns the undo list for
    :func:`restore_scene`."""
    by_mesh = {id(j.mesh): j for j in jobs if j.mesh is not None}
    undo = []
    budget = MAX_SCENE_REFINED_TRIANGLES
    order = sorted(range(len(scene.meshes)), key=lambda i: not scene.meshes[i].bake)
    for i in order:
        mesh = scene.meshes[i]
        cage = getattr(mesh, "cage", None)
        if cage is None:
            continue
        job = by_mesh.get(id(mesh))
        res = job.resolution if job is not None else None
        levels = choose_levels(mesh, cage, res, budget)
        tcs = scene.texcoords[i] if i < len(scene.texcoords) else {}
        note = None
        if levels == 0:
            note = (
                f"subdivisionScheme {cage.scheme}: refining it would exceed "
                f"{min(budget, MAX_REFINED_TRIANGLES)} triangles (per mesh "
                f"{MAX_REFINED_TRIANGLES}, per scene {MAX_SCENE_REFINED_TRIANGLES}); the "
                "control cage is traced as is"
            )
            out = None
        else:
            out, why = refine_mesh(mesh, tcs, levels)
            if out is None:
                note = (
                    f"subdivisionScheme {cage.scheme}: not refined ({why}); the control cage "
                    "is traced as is"
                )
        if out is None:
            if job is not None and note:
                job.report.setdefault("warnings", []).append(note)
            continue
        refined, rtcs = out
        budget -= len(refined.triangles)
        undo.append((i, mesh, tcs, job))
        scene.meshes[i] = refined
        if i < len(scene.texcoords):
            scene.texcoords[i] = rtcs
        if job is not None:
            job.mesh = refined
            job.texels = None
            scheme = "Loop" if cage.scheme == "loop" and np.all(cage.counts == 3) else "CC"
            job.report.setdefault("notes", []).append(
                f"subdivisionScheme {cage.scheme}: traced on a {levels}-level {scheme} "
                f"refinement ({len(refined.triangles)} triangles from {len(cage.counts)} cage "
                f"faces{', limit positions' if scheme == 'CC' else ''}); texels addressed "
                "through the cage's UVs"
            )
    return undo


def restore_scene(scene, undo) -> None:
    """Put the cages back (the layer is authored per cage corner)."""
    for i, mesh, tcs, job in undo:
        scene.meshes[i] = mesh
        if i < len(scene.texcoords):
            scene.texcoords[i] = tcs
        if job is not None:
            job.mesh = mesh
