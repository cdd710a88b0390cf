"""Small prim and layer reads for the validator's rules (:mod:`usdahd.validate`), which never
import pxr themselves: lightmap UVs per triangle corner, mesh topology and transform, the
inputs of the normals rule, UDIM tiles, the AhdLightmapAPI prim definition and a stamp of the
stage's layers on disk.

Each reads the prim as authored, without the scene reader's checks and warnings
(:mod:`usdahd.usd.geometry`): a rule reports what is wrong with it itself.
"""

from __future__ import annotations

import hashlib

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from usdahd.numerics.raster import fan_triangulate
from usdahd.usd import assets, schema

__all__ = [
    "ATLAS_PAGE",
    "ATLAS_SCALE_OFFSET",
    "api_definition",
    "atlas_properties",
    "corner_uvs",
    "layers_stamp",
    "local_to_world",
    "mesh_topology",
    "normals_inputs",
    "primvar_type",
    "udim_tiles",
]


def corner_uvs(prim, name: str) -> np.ndarray | None:
    """Per-triangle-corner values of the primvar ``name`` at the default time: (t, 3, 2)
    float64 by the baker's fan triangulation (:func:`usdahd.numerics.raster.fan_triangulate`),
    or None if the primvar is absent or has no value."""
    mesh = UsdGeom.Mesh(prim)
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    vals = pv.ComputeFlattened()
    if vals is None:
        return None
    vals = np.asarray(vals, dtype=np.float64).reshape(-1, 2)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    interp = pv.GetInterpolation()
    if interp == UsdGeom.Tokens.faceVarying:
        per_corner = vals
    elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        per_corner = vals[fvi]
    elif interp == UsdGeom.Tokens.uniform:
        per_corner = np.repeat(vals, counts, axis=0)
    else:
        per_corner = np.broadcast_to(vals[:1], (len(fvi), 2))
    _, tri = fan_triangulate(counts)
    return per_corner[tri]


def primvar_type(prim, name: str) -> tuple[str, bool] | None:
    """(type name, whether it is ``texCoord2f[]``) of the primvar ``name``; None when it does
    not exist or has no value."""
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    tname = pv.GetTypeName()
    return str(tname), tname.type == Sdf.ValueTypeNames.TexCoord2fArray.type


def mesh_topology(prim) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """points (n, 3) float64, faceVertexCounts (f,) int64, faceVertexIndices (k,) int64 of a
    mesh at the default time (empty arrays when unauthored)."""
    mesh = UsdGeom.Mesh(prim)
    pts = np.asarray(mesh.GetPointsAttr().Get() or [], dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    return pts, counts, fvi


def local_to_world(prim) -> np.ndarray:
    """(4, 4) float64 local-to-world matrix at the default time, for column vectors
    (``world = m[:3, :3] @ p + m[:3, 3]``)."""
    return np.asarray(
        UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
    ).T


def normals_inputs(prim, time="default"):
    """What the normals rule (:func:`usdahd.usd.normals.compute_normals`) and the normals the
    bake authored are compared on, read at ``time`` (a number or "default"):
    (points, faceVertexCounts, faceVertexIndices, authored normals, left-handed) with the
    values as USD returns them (any may be None); the authored normals are ``primvars:normals``
    flattened, else the ``normals`` attribute; the orientation is read at the default time."""
    mesh = UsdGeom.Mesh(prim)
    t = Usd.TimeCode.Default() if time == "default" else Usd.TimeCode(float(time))
    pts, counts, idx = (
        mesh.GetPointsAttr().Get(t),
        mesh.GetFaceVertexCountsAttr().Get(t),
        mesh.GetFaceVertexIndicesAttr().Get(t),
    )
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
    authored = pv.ComputeFlattened(t) if pv and pv.HasValue() else mesh.GetNormalsAttr().Get(t)
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    return pts, counts, idx, authored, left


def udim_tiles(attr, asset: str) -> list[tuple[int, str]]:
    """(tile number, resolved path) of the UDIM set ``asset`` of an asset attribute, resolved
    against the layer that authors its default value ([] when none does)."""
    layer = None
    for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
        if spec.HasDefaultValue():
            layer = spec.layer
            break
    tiles = UsdShade.UdimUtils.ResolveUdimTilePaths(asset, layer) if layer else []
    return [(int(t[1]), str(t[0])) for t in tiles]


def api_definition():
    """The AhdLightmapAPI ``Usd.PrimDefinition`` (None when the schema is not registered)."""
    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(schema.API_NAME)


def layers_stamp(stage):
    """A hashable stamp of every layer the stage uses: sorted (identifier, *file stamp) of the
    layers on disk (plus a digest of a non-empty session layer's content), or None when any
    layer has unsaved edits or is anonymous (other than the session layer) or has no stamp,
    i.e. when the stage may differ from its files."""
    parts = []
    for layer in stage.GetUsedLayers():
        if layer.anonymous and layer != stage.GetSessionLayer():
            return None
        if layer.dirty and not layer.anonymous:
            return None
        if layer.anonymous:
            if not layer.empty:
                # the session layer of a validation's instance view (usdahd.usd.instances):
                # stamped by its content, so the scene is read once per view, not per rule
                text = layer.ExportToString()
                parts.append(("session", hashlib.sha256(text.encode()).hexdigest()))
            continue
        stamp = assets.stamp(layer.realPath)  # a layer inside a usdz: its package's
        if stamp is None:
            return None
        parts.append((layer.identifier, *stamp))
    return tuple(sorted(parts))


#: The atlas properties of a bake record (docs/schema.md; issue 39's contract).
ATLAS_SCALE_OFFSET = "ahdLightmap:atlas:scaleOffset"
ATLAS_PAGE = "ahdLightmap:atlas:page"


def atlas_properties(prim) -> dict | None:
    """A record's atlas properties as authored, for the Atlas rule: None when neither
    ``atlas:scaleOffset`` nor ``atlas:page`` has a value (no atlas: the record's textures are
    its own); else {"scale_offset": tuple of floats or None (absent: (1, 1, 0, 0)) or the raw
    value when not four numbers, "page": the raw value or None (absent: 0), "layer": identifier
    of the layer holding the strongest opinion (pages are numbered per output layer)}."""
    values, layer = {}, None
    for key, name in (("scale_offset", ATLAS_SCALE_OFFSET), ("page", ATLAS_PAGE)):
        attr = prim.GetAttribute(name)
        v = attr.Get() if attr and attr.HasAuthoredValue() else None
        values[key] = v
        if v is not None and layer is None:
            stack = attr.GetPropertyStack(Usd.TimeCode.Default())
            layer = stack[0].layer.identifier if stack else None
    if values["scale_offset"] is None and values["page"] is None:
        return None
    so = values["scale_offset"]
    if so is not None:
        try:
            so = tuple(float(x) for x in so)
        except (TypeError, ValueError):
            so = values["scale_offset"]
    return {"scale_offset": so, "page": values["page"], "layer": layer}
