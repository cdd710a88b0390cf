"""``usdahd export gltf``: a baked stage as glTF 2.0 with directional lightmaps (issue 42).

What goes into the file (docs/gltf.md is the user-facing description):

- one node per baked mesh (named by its prim path) under a root node that converts the stage's
  ``metersPerUnit`` and up axis to glTF's metres and +Y; the node carries the prim's
  local-to-world transform as TRS (a transform with shear is baked into the points instead);
- one mesh per node, one primitive per bound material (GeomSubsets), triangulated as the baker
  triangulates it: POSITION, NORMAL (the bake's shading normals), TEXCOORD_1 = the lightmap UVs
  (``baked:uvPrimvar``, v flipped to glTF's top-left origin), ``_LIGHTMAP_TANGENT`` (the
  lightmap tangent frame of docs/schema.md, w = sign), and with a textured material TEXCOORD_0
  (+ TANGENT when a normal map is bound);
- UsdPreviewSurface as glTF PBR: ``diffuseColor`` (constant or texture) as the base colour,
  ``inputs:normal`` as the normal texture, metallic 0, roughness 1;
- the ``USDAHD_lightmap_directional`` extension: at the root one *page* per texture set (model,
  ratio, decode factors, texture roles with their encodings), on each node the page, the UV
  scale/offset into it and the texCoord index (docs/gltf/USDAHD_lightmap_directional.*.json).
  A page is one texture set: an atlas page shared by the records packed into it (one image per
  page and role, whatever the number of nodes on it), or a record's own textures (``--atlas
  off``: scale (1, 1), offset (0, 0)); each node's scale/offset is the record's
  ``ahdLightmap:atlas:scaleOffset`` in glTF's top-left texture convention (:func:`placement`).

Instance copies share their prototype's glTF mesh (meshes are deduplicated by content in node
space); PointInstancer copies are ``EXT_mesh_gpu_instancing`` nodes, or a node each with
``instancing="nodes"`` (:mod:`usdahd.export.instancing`).

8-bit lightmap textures are embedded byte for byte as the bake wrote them; float16 textures are
re-encoded as RGBM or RGBE PNG (:mod:`usdahd.export.hdr`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from usdahd.errors import StageError, UsageError
from usdahd.export.instancing import (
    GPU_INSTANCING,
    INSTANCING,
    instanced_node,
    instancer_copies,
)

__all__ = [
    "EXTENSION",
    "LIGHTMAP_TEXCOORD",
    "check_stage",
    "decompose",
    "export",
    "placement",
    "trs_fields",
]

EXTENSION = "USDAHD_lightmap_directional"
#: Vertex attribute of the lightmap tangent (xyz object space, w = handedness sign).
TANGENT_ATTRIBUTE = "_LIGHTMAP_TANGENT"
#: TEXCOORD set holding the lightmap UVs.
LIGHTMAP_TEXCOORD = 1
EXTENSION_VERSION = 1

# glTF constants
_FLOAT, _UINT32 = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_NEAREST, _LINEAR, _LINEAR_MIPMAP_LINEAR = 9728, 9729, 9987
_WRAP = {"repeat": 10497, "mirror": 33648, "clamp": 33071, "black": 33071}
_CLAMP = 33071


@dataclass
class _Builder:
    """Accumulates the glTF JSON and the binary buffer."""

    bin: bytearray = field(default_factory=bytearray)
    doc: dict = field(default_factory=dict)

    def __post_init__(self):
        self.doc = {
            "asset": {"version": "2.0", "generator": _generator()},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [],
            "meshes": [],
            "materials": [],
            "accessors": [],
            "bufferViews": [],
            "buffers": [],
        }

    def _add(self, key: str, item: dict) -> int:
        self.doc.setdefault(key, []).append(item)
        return len(self.doc[key]) - 1

    def view(self, data: bytes, target: int | None = None, stride: int | None = None) -> int:
        while len(self.bin) % 4:
            self.bin.append(0)
        bv = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target is not None:
            bv["target"] = target
        if stride is not None:
            bv["byteStride"] = stride
        self.bin.extend(data)
        return self._add("bufferViews", bv)

    def accessor(
        self, array: np.ndarray, kind: str, *, indices=False, bounds=False, target=_ARRAY_BUFFER
    ) -> int:
        if indices:
            a = np.ascontiguousarray(array, np.uint32).reshape(-1)
            view = self.view(a.tobytes(), _ELEMENT_ARRAY_BUFFER)
            acc = {"bufferView": view, "componentType": _UINT32, "count": int(a.size)}
            acc["type"] = "SCALAR"
            return self._add("accessors", acc)
        a = np.ascontiguousarray(array, np.float32)
        view = self.view(a.tobytes(), target)
        acc = {"bufferView": view, "componentType": _FLOAT, "count": int(len(a)), "type": kind}
        if bounds:
            acc["min"] = [float(x) for x in a.min(axis=0)]
            acc["max"] = [float(x) for x in a.max(axis=0)]
        return self._add("accessors", acc)

    def image(self, png: bytes, name: str) -> int:
        view = self.view(png)
        return self._add("images", {"bufferView": view, "mimeType": "image/png", "name": name})

    def sampler(self, spec: dict) -> int:
        samplers = self.doc.setdefault("samplers", [])
        if spec in samplers:
            return samplers.index(spec)
        return self._add("samplers", spec)

    def texture(self, image: int, sampler: int) -> int:
        return self._add("textures", {"source": image, "sampler": sampler})


def _generator() -> str:
    from usdahd.version import __version__

    return f"usdahd {__version__}"


# ------------------------------------------------------------------------------ transforms


def _axis_rotation(up: str) -> list[float] | None:
    """Quaternion (x, y, z, w) turning the stage's up axis into glTF's +Y (None for Y up)."""
    if up == "Z":  # -90 degrees about X: (x, y, z) -> (x, z, -y)
        s = math.sqrt(0.5)
        return [-s, 0.0, 0.0, s]
    return None


def _quaternion(r: np.ndarray) -> list[float]:
    """Unit quaternion (x, y, z, w) of a proper rotation matrix r (3, 3) (column vectors)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4, (r[1, 0] - r[0, 1]) / s]
    q = np.asarray(q, np.float64)
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    return [float(x) for x in q]


def decompose(m: np.ndarray):
    """USD row-vector matrix (4, 4) -> glTF (translation, rotation xyzw, scale) or None when it
    has shear or a projective part (then the points are exported in world space)."""
    m = np.asarray(m, np.float64)
    if not np.allclose(m[:3, 3], 0.0, atol=1e-12) or abs(m[3, 3] - 1.0) > 1e-12:
        return None
    a = m[:3, :3].T  # column-vector linear part
    scale = np.linalg.norm(a, axis=0)
    if np.any(scale <= 1e-12):
        return None
    r = a / scale
    if np.linalg.det(r) < 0:  # a mirror: one negative scale
        scale[0], r[:, 0] = -scale[0], -r[:, 0]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6):
        return None  # shear
    return [float(x) for x in m[3, :3]], _quaternion(r), [float(x) for x in scale]


# ------------------------------------------------------------------------------ loading


@dataclass
class BakedPrim:
    """One baked mesh ready to export."""

    mesh: object  # usdahd.scene.types.MeshData (world space)
    results: object  # usdahd.usd.schema.BakeResults
    tangent: np.ndarray  # (t, 3, 3) lightmap tangents, world
    sign: np.ndarray  # (t,)
    surfaces: list  # [usdahd.preview.surface.Surface]


def check_stage(layer: str):
    """Everything that can be wrong with the input, before any geometry is read: the layer
    opens, has baked prims, and every texture of every baked prim exists. Returns (stage,
    {prim path: BakeResults})."""
    from usdahd import models
    from usdahd.usd import assets, schema
    from usdahd.usd.stage import open_stage

    if not Path(layer).exists():
        raise StageError(f"{layer}: no such file")
    stage = open_stage(layer)
    # Mesh records and instance entries (each instance copy its own lightmap); a record an
    # instance proxy shows through its prototype is not the copy's and is left out.
    errors: list = []
    records = schema.stage_records(stage, errors=errors)
    if errors:
        path, exc = errors[0]
        raise StageError(
            f"{path}: its bake record cannot be read ({exc}); re-bake with usdahd bake"
        )
    if not records:
        raise StageError(
            f"{layer}: no baked prim (formatVersion 0): this is not a baked stage; run "
            "usdahd bake on the source stage and export its STAGE.lightmaps.usda"
        )
    for path, res in sorted(records.items()):
        for lay in models.get(res.model).layout(res.ratio):
            file = res.textures.get(lay.role)
            if file is None or not assets.exists(file):
                shown = res.asset_paths.get(lay.role, file or "(unauthored)")
                sharing = sum(1 for r in records.values() if r.textures.get(lay.role) == file)
                page = f", the atlas page of {sharing} prims" if res.atlas and file else ""
                raise StageError(
                    f"{path}: lightmap texture {lay.role!r} ({shown}{page}) is missing; restore "
                    "the lightmaps folder beside the layer or re-bake with usdahd bake"
                )
    return stage, records


def load_prims(layer: str, unbaked: bool = False) -> tuple[object, list[BakedPrim], object]:
    """(stage, [BakedPrim] sorted by path, scene of the first UV set: up axis, metersPerUnit,
    time). Raises StageError naming the prim and the fix for every bad input. ``unbaked``:
    also the stage's visible meshes without a bake (occluders: instances, PointInstancer
    copies, ``ahdLightmap:bake = false``), as BakedPrims with ``results`` None and their
    base colour (:func:`plain_surfaces`), after the baked ones."""
    from usdahd.bake import texels
    from usdahd.preview.surface import surfaces
    from usdahd.usd.reader import load_scene

    stage, records = check_stage(layer)
    out, first = [], None
    for uv in sorted({r.uv_primvar for r in records.values()}):
        sc = load_scene(stage, uv_name=uv)
        first = first or sc
        found = {m.path: m for m in sc.meshes}
        for path, res in sorted(records.items()):
            if res.uv_primvar != uv:
                continue
            mesh = found.get(path)
            if mesh is None:
                raise StageError(
                    f"{path}: baked, but not a visible mesh of the stage (deactivated, "
                    "invisible or not a Mesh); make it visible or re-bake"
                )
            if mesh.uv is None:
                raise StageError(
                    f"{path}: has no lightmap UVs (primvar {uv!r}, its baked:uvPrimvar); "
                    "restore the primvar or re-bake with usdahd bake, which unwraps it"
                )
            tangent, sign = texels.tangent_frames(mesh)
            out.append(BakedPrim(mesh, res, tangent, sign, []))
    out.sort(key=lambda p: p.mesh.path)
    groups = surfaces(stage, [(p.mesh, p.results, p.tangent, p.sign) for p in out])
    for p, g in zip(out, groups):
        p.surfaces = g
    if unbaked:
        for k, mesh in enumerate(first.meshes):
            if mesh.path not in records:
                out.append(BakedPrim(mesh, None, None, None, plain_surfaces(first, k)))
    return stage, out, first


def plain_surfaces(scene, k: int) -> list:
    """Surfaces (usdahd.preview.surface.Surface) of the unbaked mesh ``scene.meshes[k]``: per
    bound material its base colour, constant or texture (when the mesh has the texture's
    coordinates), no normal map."""
    from usdahd.preview.surface import Surface

    mesh = scene.meshes[k]
    coords = scene.texcoords[k] if k < len(scene.texcoords) else {}
    out = []
    for mi in np.unique(np.asarray(mesh.material)):
        mat = scene.materials[int(mi)]
        tris = np.nonzero(np.asarray(mesh.material) == mi)[0]
        st = coords.get(mat.texcoord) if mat.albedo_tex is not None else None
        tex = None
        if st is not None:
            a = mat.albedo_tex.outputs()
            tex = np.clip(np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a, 0.0, 1.0)
        albedo = np.ones(3) if tex is not None else np.clip(mat.albedo, 0.0, 1.0)
        zeros = np.zeros((len(tris), 3, 2), np.float32)
        out.append(
            Surface(
                material=mat.name,
                tris=tris,
                albedo=np.asarray(albedo, np.float32),
                albedo_tex=tex,
                albedo_wrap=mat.albedo_tex.wrap if tex is not None else ("repeat", "repeat"),
                normal_tex=None,
                normal_wrap=("repeat", "repeat"),
                st=np.asarray(st, np.float32)[tris] if st is not None else zeros,
                tangent=np.zeros((len(tris), 3, 3)),
                sign=np.ones(len(tris)),
            )
        )
    return out


# ------------------------------------------------------------------------------ export


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(255.0 * s).astype(np.uint8)


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-30, v / np.maximum(n, 1e-30), np.array([0.0, 0.0, 1.0]))


def page_key(res) -> tuple:
    """What identifies a record's page: its model, ratio and the files of its texture roles
    (records of one atlas page name the same files; without an atlas each record is a page)."""
    from usdahd import models

    roles = [lay.role for lay in models.get(res.model).layout(res.ratio)]
    return (res.model, res.ratio, tuple(str(res.textures[r]) for r in roles))


def placement(res) -> tuple[list[float], list[float]]:
    """(scale, offset) of a record in its page for the glTF's TEXCOORD_1, whose origin is the
    top-left (t = 1 - v): from ``ahdLightmap:atlas:scaleOffset`` (sx, sy, ox, oy) (USD's v up,
    ``uv_page = uv * s + o``), ``t_page = t * sy + (1 - oy - sy)``; (1, 1), (0, 0) without an
    atlas."""
    sx, sy, ox, oy = (float(v) for v in res.scale_offset)
    return [sx, sy], [ox, 1.0 - oy - sy]


def _page(b: _Builder, res, hdr: str, name: str, stats: list) -> dict:
    """The extension's page of a texture set (an atlas page, or one record's own textures):
    its textures embedded whole, the decode factors (per page: one encode over the page)."""
    from usdahd import images, models
    from usdahd.export import hdr as hdr_codec
    from usdahd.export import png

    data_sampler = b.sampler(
        {"magFilter": _NEAREST, "minFilter": _NEAREST, "wrapS": _CLAMP, "wrapT": _CLAMP}
    )
    textures = []
    size = None
    for lay in models.get(res.model).layout(res.ratio):
        file = res.textures[lay.role]
        label = f"{name} {lay.role}"
        if lay.format == "unorm8":
            img = images.read(file, channels=lay.channels)
            px = np.asarray(img.pixels)
            entry = {"encoding": "unorm8"}
            blob = png.encode(px.astype(np.uint8), linear=True)
        else:
            values = np.asarray(images.read(file, channels=lay.channels).pixels, np.float64)
            px, params = hdr_codec.encode(values, hdr)
            entry = {"encoding": hdr, **params}
            blob = png.encode(px, linear=True)
            dec = hdr_codec.decode(px, hdr, params)
            stats.append((np.sum((dec - values) ** 2), np.sum(values**2), len(values.flat)))
        size = size or (int(px.shape[1]), int(px.shape[0]))
        tex = b.texture(b.image(blob, label), data_sampler)
        textures.append({"role": lay.role, "index": tex, **entry, "packing": lay.packing})
    return {
        "model": res.model,
        "ratio": res.ratio,
        "tangentFrame": res.tangent_frame,
        "resolution": [int(size[0]), int(size[1])],
        "factors": {k: float(res.factor(k)) for k in _factor_names()},
        "textures": textures,
    }


def _factor_names():
    from usdahd.usd import schema

    return schema.FACTORS


def _material(b: _Builder, surf, cache: dict) -> int:
    """glTF material index of a Surface (deduplicated by content)."""
    from usdahd.export import png

    key = (
        surf.material,
        tuple(np.round(surf.albedo, 7)),
        _digest(surf.albedo_tex),
        _digest(surf.normal_tex),
        tuple(surf.albedo_wrap),
        tuple(surf.normal_wrap),
    )
    if key in cache:
        return cache[key]
    pbr = {"metallicFactor": 0.0, "roughnessFactor": 1.0}
    mat = {"name": surf.material or "default", "pbrMetallicRoughness": pbr}
    if surf.albedo_tex is not None:
        s = b.sampler(_sampler(surf.albedo_wrap))
        img = b.image(png.encode(_srgb8(surf.albedo_tex), linear=False), f"{surf.material} albedo")
        pbr["baseColorTexture"] = {"index": b.texture(img, s), "texCoord": 0}
        pbr["baseColorFactor"] = [float(x) for x in surf.albedo] + [1.0]
    else:
        pbr["baseColorFactor"] = [float(x) for x in surf.albedo] + [1.0]
    if surf.normal_tex is not None:
        s = b.sampler(_sampler(surf.normal_wrap))
        px = np.rint(255.0 * np.clip(surf.normal_tex, 0.0, 1.0)).astype(np.uint8)
        img = b.image(png.encode(px, linear=True), f"{surf.material} normal")
        mat["normalTexture"] = {"index": b.texture(img, s), "texCoord": 0}
    cache[key] = b._add("materials", mat)
    return cache[key]


def _digest(a) -> str | None:
    if a is None:
        return None
    a = np.ascontiguousarray(a)
    return hashlib.sha256(a.tobytes() + repr((a.shape, a.dtype.str)).encode()).hexdigest()


def _sampler(wrap) -> dict:
    return {
        "magFilter": _LINEAR,
        "minFilter": _LINEAR_MIPMAP_LINEAR,
        "wrapS": _WRAP.get(wrap[0], 10497),
        "wrapT": _WRAP.get(wrap[1], 10497),
    }


def _corners(p: BakedPrim, surf, local) -> tuple[np.ndarray, tuple[bool, bool, bool]]:
    """Per-corner vertex rows (3k, 18) float32 of one surface in the node's space (position,
    normal, lightmap UV, lightmap tangent + sign, material UV, material tangent + sign; unused
    columns zero) and (baked, textured, normal-mapped). ``p.results`` None: an unbaked mesh (no
    lightmap UVs or tangent)."""
    m3, m3_inv, tr, inv = local
    tris = surf.tris
    k = len(tris)
    rows = np.zeros((k, 3, 18))
    tri = np.asarray(p.mesh.triangles)[tris]
    pts = np.asarray(p.mesh.points, np.float64)[tri]  # (k, 3, 3) world
    rows[..., 0:3] = (np.concatenate([pts, np.ones(pts.shape[:2] + (1,))], -1) @ inv)[..., :3]
    rows[..., 3:6] = _unit(np.asarray(p.mesh.normals, np.float64)[tris] @ m3.T)
    baked = p.results is not None
    if baked:
        uv = np.asarray(p.mesh.uv, np.float64)[tris]
        rows[..., 6] = uv[..., 0]
        rows[..., 7] = 1.0 - uv[..., 1]
        rows[..., 8:11] = _unit(np.asarray(p.tangent, np.float64)[tris] @ m3_inv)
        rows[..., 11] = np.asarray(p.sign, np.float64)[tris][:, None]
    textured = surf.albedo_tex is not None or surf.normal_tex is not None
    if textured:
        st = np.asarray(surf.st, np.float64)
        rows[..., 12] = st[..., 0]
        rows[..., 13] = 1.0 - st[..., 1]
    mapped = surf.normal_tex is not None
    if mapped:
        rows[..., 14:17] = _unit(np.asarray(surf.tangent, np.float64) @ m3_inv)
        rows[..., 17] = np.asarray(surf.sign, np.float64)[:, None]
    return rows.reshape(-1, 18).astype(np.float32), (baked, textured, mapped)


def _primitive(b: _Builder, corners: np.ndarray, flags, material: int) -> dict:
    """One primitive of :func:`_corners` rows, corners deduplicated into indexed vertices."""
    baked, textured, mapped = flags
    uniq, index = np.unique(corners, axis=0, return_inverse=True)
    attrs = {
        "POSITION": b.accessor(uniq[:, 0:3], "VEC3", bounds=True),
        "NORMAL": b.accessor(uniq[:, 3:6], "VEC3"),
    }
    if baked:
        attrs[f"TEXCOORD_{LIGHTMAP_TEXCOORD}"] = b.accessor(uniq[:, 6:8], "VEC2")
        attrs[TANGENT_ATTRIBUTE] = b.accessor(uniq[:, 8:12], "VEC4")
    if textured:
        attrs["TEXCOORD_0"] = b.accessor(uniq[:, 12:14], "VEC2")
    elif baked:  # glTF requires TEXCOORD_0 when TEXCOORD_1 is present
        attrs["TEXCOORD_0"] = attrs[f"TEXCOORD_{LIGHTMAP_TEXCOORD}"]
    if mapped:
        attrs["TANGENT"] = b.accessor(uniq[:, 14:18], "VEC4")
    return {
        "attributes": attrs,
        "indices": b.accessor(np.asarray(index).reshape(-1), "SCALAR", indices=True),
        "material": material,
        "mode": 4,
    }


def _mesh(b: _Builder, p: BakedPrim, local, materials: dict, meshes: dict) -> int:
    """The glTF mesh of a prim in its node's space; prims with the same vertices and materials
    (scenegraph instances, repeated props) share one mesh."""
    parts = [(*_corners(p, s, local), _material(b, s, materials)) for s in p.surfaces]
    h = hashlib.sha256()
    for corners, flags, mat in parts:
        # transforming to world and back leaves ~1e-8 differences between copies: compare
        # at 1e-6 (the first copy's vertices are the ones written)
        h.update((np.round(corners.astype(np.float64), 6) + 0.0).tobytes())  # no -0.0
        h.update(repr((corners.shape, flags, mat)).encode())
    key = h.hexdigest()
    if key not in meshes:
        prims = [_primitive(b, c, f, m) for c, f, m in parts]
        meshes[key] = b._add("meshes", {"name": p.mesh.path, "primitives": prims})
    return meshes[key]


def trs_fields(node: dict, trs) -> None:
    """Set a node's translation/rotation/scale from :func:`decompose`'s (t, r, s), leaving
    identity parts out."""
    t, r, s = trs
    if any(abs(x) > 0 for x in t):
        node["translation"] = t
    if r != [0.0, 0.0, 0.0, 1.0]:
        node["rotation"] = r
    if s != [1.0, 1.0, 1.0]:
        node["scale"] = s


def build(
    layer: str, *, hdr: str = "rgbm", unbaked: bool = True, instancing: str = "gpu"
) -> tuple[dict, bytes, dict]:
    """(glTF JSON, binary buffer, report) of a baked layer; ``unbaked``: also the visible meshes
    without a bake, as plain nodes (no extension). ``instancing``: "gpu" writes the baked
    copies of a PointInstancer prototype mesh as EXT_mesh_gpu_instancing nodes (one per
    lightmap page, the copies' lightmap scale/offset and page as per-instance attributes);
    "nodes" writes one node per copy (for engines without the extension). Either way copies
    of one prototype mesh share one glTF mesh."""
    from usdahd.usd.transforms import world_matrices

    if hdr not in ("rgbm", "rgbe"):
        raise UsageError(f"--hdr {hdr}: choose rgbm or rgbe")
    if instancing not in INSTANCING:
        raise UsageError(f"--instancing {instancing}: choose gpu or nodes")
    stage, prims, scene = load_prims(layer, unbaked=unbaked)
    b = _Builder()
    root = {"name": "usdahd_stage", "children": []}
    rot = _axis_rotation(scene.up_axis)
    if rot is not None:
        root["rotation"] = rot
    mpu = float(scene.meters_per_unit)
    if mpu != 1.0:
        root["scale"] = [mpu, mpu, mpu]
    b.doc["nodes"].append(root)
    mats = world_matrices(stage, [p.mesh.path for p in prims], scene.time)
    copies = instancer_copies(stage, prims, scene.time)
    pages, stats, cache, mesh_cache = [], [], {}, {}
    page_index: dict = {}  # page_key -> index into pages

    def page_of(p: BakedPrim) -> int:
        key = page_key(p.results)
        if key not in page_index:
            name = f"page {len(pages)}" if p.results.atlas else p.mesh.path
            page_index[key] = len(pages)
            pages.append(_page(b, p.results, hdr, name, stats))
        elif pages[page_index[key]]["factors"] != {
            k: float(p.results.factor(k)) for k in _factor_names()
        }:
            raise StageError(
                f"{p.mesh.path}: its decode factors differ from those of the other records on "
                "its atlas page (factors are per page); re-bake the stage with usdahd bake"
            )
        return page_index[key]

    def add_node(node: dict) -> None:
        root["children"].append(len(b.doc["nodes"]))
        b.doc["nodes"].append(node)

    baked = 0
    groups: dict = {}  # (carrier, prototype mesh, glTF mesh, page) -> [(prim, instance TRS)]
    for p in prims:
        path = p.mesh.path
        m = mats.get(path)
        inst = copies.get(id(p))
        if inst is not None:  # a PointInstancer copy: proto_local @ M_i @ W
            m = inst[1] @ inst[2]
        trs = decompose(m) if m is not None else None
        if trs is None:
            m = np.eye(4)
        inv = np.linalg.inv(m)
        m3 = m[:3, :3]
        local = (m3, np.linalg.inv(m3), m, inv)
        mesh = _mesh(b, p, local, cache, mesh_cache)
        if p.results is not None:
            baked += 1
        if instancing == "gpu" and inst is not None and trs is not None and p.results is not None:
            carrier, mi, world = inst
            itrs, wtrs = decompose(mi), decompose(world)
            # a mirrored instance would need its winding flipped per instance: a node of its own
            if itrs is not None and wtrs is not None and np.linalg.det(mi[:3, :3]) > 0:
                key = (carrier, p.mesh.instance.mesh, mesh, page_of(p))
                groups.setdefault(key, []).append((p, itrs))
                continue
        node = {"name": path, "mesh": mesh}
        if trs is not None:
            trs_fields(node, trs)
        add_node(node)
        if p.results is None:
            continue
        scale, offset = placement(p.results)
        node["extensions"] = {
            EXTENSION: {
                "page": page_of(p),
                "scale": scale,
                "offset": offset,
                "texCoord": LIGHTMAP_TEXCOORD,
                "prim": path,
            }
        }
    instances = 0
    for (carrier, rel, mesh, page), members in groups.items():
        add_node(instanced_node(b, carrier, rel, mesh, page, members, copies))
        instances += len(members)
    for cam in _cameras(stage, scene.up_axis, mpu):
        cam["camera"] = b._add("cameras", cam.pop("_camera"))
        b.doc["scenes"][0]["nodes"].append(len(b.doc["nodes"]))
        b.doc["nodes"].append(cam)
    b.doc["extensionsUsed"] = [EXTENSION] + ([GPU_INSTANCING] if groups else [])
    b.doc["extensions"] = {
        EXTENSION: {
            "version": EXTENSION_VERSION,
            "tangentAttribute": TANGENT_ATTRIBUTE,
            "pages": pages,
        }
    }
    b.doc["buffers"] = [{"byteLength": len(b.bin)}]
    err2 = sum(s[0] for s in stats)
    ref2 = sum(s[1] for s in stats)
    report = {
        "stage": str(layer),
        "nodes": baked,
        "unbaked_nodes": len(prims) - baked,
        "instanced_nodes": len(groups),
        "instances": instances,
        "meshes": len(b.doc["meshes"]),
        "instancing": instancing,
        "pages": len(pages),
        "models": sorted({f"{p['model']}/{p['ratio']}" for p in pages}),
        "hdr": hdr,
        "hdr_relrmse": float(math.sqrt(err2 / ref2)) if ref2 > 0 else 0.0,
        "cameras": len(b.doc.get("cameras", [])),
        "up_axis": scene.up_axis,
        "meters_per_unit": mpu,
    }
    return b.doc, bytes(b.bin), report


def _cameras(stage, up: str, mpu: float) -> list[dict]:
    """glTF camera nodes of the stage's perspective UsdGeomCameras (read as usdahd preview
    reads them: transform, vertical field of view, clipping range, at the default time); the
    horizontal field of view follows the viewport, as in the preview. Both conventions look
    down -Z with +Y up. The nodes are top-level, in glTF's metres and +Y, with no scale:
    engines ignore a camera's scale (three.js does), so an inherited metersPerUnit scale would
    leave the clipping range in the wrong unit; znear/zfar are converted to metres instead."""
    from usdahd.usd.camera import read_camera
    from usdahd.usd.transforms import camera_paths

    conv = np.eye(4)
    if up == "Z":
        conv[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    conv[:3, :3] *= mpu
    nodes = []
    for path in camera_paths(stage):
        view, fov, near, far = read_camera(stage, path)
        world = conv @ np.linalg.inv(view)  # column vectors: camera -> glTF world
        world[:3, :3] /= mpu  # a rotation: the unit conversion goes to the clipping range
        trs = decompose(world.T)  # as a USD row-vector matrix
        if trs is None or not (0 < near < far) or not (0 < fov < 180):
            continue
        t, r, _ = trs
        perspective = {"yfov": math.radians(fov), "znear": near * mpu, "zfar": far * mpu}
        camera = {"name": path, "type": "perspective", "perspective": perspective}
        nodes.append({"name": path, "translation": t, "rotation": r, "_camera": camera})
    return nodes


def glb_bytes(doc: dict, binary: bytes) -> bytes:
    """The GLB container of a JSON document and its one binary buffer."""
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * (-len(js) % 4)
    bn = binary + b"\x00" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(bn)
    out = struct.pack("<III", 0x46546C67, 2, total)
    out += struct.pack("<II", len(js), 0x4E4F534A) + js
    out += struct.pack("<II", len(bn), 0x004E4942) + bn
    return out


def write(doc: dict, binary: bytes, out: Path) -> list[Path]:
    """Write ``out`` (.glb, or .gltf + ``<stem>.bin`` beside it), atomically; returns the files."""
    from usdahd.io_util import atomic_write_bytes

    out = Path(out)
    if out.suffix.lower() == ".glb":
        atomic_write_bytes(out, glb_bytes(doc, binary))
        return [out]
    doc = json.loads(json.dumps(doc))
    bin_name = out.stem + ".bin"
    doc["buffers"] = [{"byteLength": len(binary), "uri": bin_name}]
    atomic_write_bytes(out.parent / bin_name, binary)
    atomic_write_bytes(out, (json.dumps(doc, indent=1) + "\n").encode("utf-8"))
    return [out, out.parent / bin_name]


def export(
    layer: str, out, *, hdr: str = "rgbm", unbaked: bool = True, instancing: str = "gpu"
) -> dict:
    """Export ``layer`` to ``out`` (.glb or .gltf); returns the report (files, counts, error
    the HDR encoding adds)."""
    out = Path(out)
    if out.suffix.lower() not in (".glb", ".gltf"):
        raise UsageError(f"-o {out}: write a .glb (one file) or .gltf (+ .bin) file")
    if not out.parent.exists() if str(out.parent) else False:
        raise UsageError(f"-o {out}: the folder {out.parent} does not exist; create it first")
    if not os.access(out.parent if str(out.parent) else ".", os.W_OK):
        raise UsageError(f"-o {out}: the folder {out.parent} is not writable; choose another -o")
    doc, binary, report = build(layer, hdr=hdr, unbaked=unbaked, instancing=instancing)
    files = write(doc, binary, out)
    report["output"] = str(out)
    report["files"] = [str(f) for f in files]
    report["bytes"] = sum(f.stat().st_size for f in files)
    return report
