"""Bake records of instance copies: ``AhdInstanceLightmapAPI`` (docs/schema.md, "Instances").

Records of instance copies are authored on the instanceable prim of a scenegraph instance or
on a PointInstancer, never inside a prototype, as arrays with one element per (instance,
prototype mesh) entry: element ``i * M + j`` is instance ``i`` (the PointInstancer's
``positions`` index; 0 for a scenegraph instance) and prototype mesh ``j`` of
``ahdInstances:meshes``. The property names are the record's with ``ahdInstances`` for
``ahdLightmap``. :func:`stage_records` is the one enumeration of a stage's records (mesh prims
and instance entries). The names are re-exported by :mod:`usdahd.usd.schema`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from pxr import Gf, Sdf, Usd

from usdahd.errors import SchemaError
from usdahd.models.base import ROLES
from usdahd.usd.schema import (
    COLOR_SPACES,
    FACTORS,
    FILE_ROLES,
    SIDECAR_ROLE,
    BakeResults,
    edit_layer_dir,
    json_text,
    layout_packing,
    prims_with_api,
    read_results,
    relative_asset_path,
    result_problems,
)

__all__ = [
    "INSTANCE_API_NAME",
    "INSTANCE_NAMESPACE",
    "instance_carrier",
    "instance_carriers",
    "instance_key",
    "instance_layout",
    "instance_property_name",
    "read_instance_records",
    "stage_records",
    "write_instance_records",
    "point_instancer_time",
]

#: Schema identifier of the API that holds instance records.
INSTANCE_API_NAME = "AhdInstanceLightmapAPI"
#: Property namespace of the instance records.
INSTANCE_NAMESPACE = "ahdInstances"
_NO_SCALE_OFFSET = (1.0, 1.0, 0.0, 0.0)


def instance_property_name(key: str) -> str:
    """``"baked:izScale"`` -> ``ahdInstances:baked:izScale`` (the array twin of a record key)."""
    return f"{INSTANCE_NAMESPACE}:{key}"


def instance_key(carrier: str, index: int, mesh: str, point_instancer: bool) -> str:
    """The key of an instance entry, as the scene reader names the copy: a scenegraph
    instance's proxy path (``/World/tree_3/Leaves``), or ``<PointInstancer>/instance_<i>`` and
    the mesh path in the prototype (``/World/pawns/instance_5/Body``), ``i`` the index into
    ``positions``."""
    tail = "" if mesh == "." else "/" + mesh
    if point_instancer:
        return f"{carrier.rstrip('/')}/instance_{int(index)}{tail}"
    return carrier.rstrip("/") + tail if tail else carrier


def _mesh_columns(root, proto: int, origin) -> list[tuple[int, str]]:
    from pxr import UsdGeom

    pred = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    out = []
    for p in Usd.PrimRange(root, pred):
        if p.IsA(UsdGeom.Mesh):
            out.append((proto, str(p.GetPath().MakeRelativePath(origin.GetPath()))))
    return out


def point_instancer_time(pi) -> Usd.TimeCode:
    """The time a PointInstancer's arrays are read at for its records: the default time, or
    its first time sample when ``positions`` / ``protoIndices`` are only sampled (as the
    scene reader reads attributes that only have time samples)."""
    for attr in (pi.GetPositionsAttr(), pi.GetProtoIndicesAttr()):
        if attr.Get() is None and attr.GetNumTimeSamples():
            return Usd.TimeCode(attr.GetTimeSamples()[0])
    return Usd.TimeCode.Default()


def instance_layout(carrier: Usd.Prim) -> tuple[int, list[tuple[int, str]]]:
    """(count, columns) of a carrier's entry arrays: the number of instances (a
    PointInstancer's ``positions`` length, else 1) and the prototype meshes as (prototype
    index, path relative to the prototype root), in prototype then traversal order."""
    from pxr import UsdGeom

    if carrier.IsA(UsdGeom.PointInstancer):
        pi = UsdGeom.PointInstancer(carrier)
        t = point_instancer_time(pi)
        ids = pi.GetProtoIndicesAttr().Get(t) or []
        pos = pi.GetPositionsAttr().Get(t)
        count = len(pos) if pos is not None and len(pos) else len(ids)
        cols = []
        for k, target in enumerate(pi.GetPrototypesRel().GetTargets()):
            root = carrier.GetStage().GetPrimAtPath(target)
            if root:
                cols += _mesh_columns(root, k, root)
        return count, cols
    return 1, _mesh_columns(carrier, 0, carrier)


def _array_layout(carrier):
    from pxr import UsdGeom

    count, cols = instance_layout(carrier)
    is_pi = carrier.IsA(UsdGeom.PointInstancer)
    path = str(carrier.GetPath())
    return count, cols, is_pi, path


def write_instance_records(
    carrier: Usd.Prim, records: dict, layer_dir: str | os.PathLike | None = None
) -> None:
    """Author the instance entries ``records`` ({:func:`instance_key` -> BakeResults}) on a
    carrier prim (an instance prim or a PointInstancer) in the edit target: applies
    ``AhdInstanceLightmapAPI`` and writes every ``ahdInstances:*`` array (elements without a
    record get formatVersion 0). Raises SchemaError naming the key for a key that is not an
    entry of ``carrier`` or for invalid results (nothing is authored then)."""
    from pxr import Vt

    layer_dir = Path(layer_dir) if layer_dir is not None else edit_layer_dir(carrier)
    count, cols, is_pi, path = _array_layout(carrier)
    m = len(cols)
    where = {}
    for i in range(count):
        for j, (_, rel) in enumerate(cols):
            where[instance_key(path, i, rel, is_pi)] = i * m + j
    n = count * m
    for key, res in records.items():
        if key not in where:
            raise SchemaError(
                f"<{path}>: {key} is not an instance entry of this prim (its prototypes changed "
                "since the bake?); re-bake the stage"
            )
        problems = result_problems(res)
        if problems:
            raise SchemaError(f"<{key}>: invalid bake results: " + "; ".join(problems))
    strings = {
        k: [""] * n
        for k in (
            "baked:model",
            "baked:ratio",
            "baked:solver",
            "baked:uvPrimvar",
            "baked:tangentFrame",
            "baked:normals",
            "baked:contentHash",
            "baked:partHashes",
            "baked:settings",
            "baked:generator",
            *(f"texture:{r}:packing" for r in ROLES),
            *(f"texture:{r}:digest" for r in ROLES),
            "sidecar:sh:digest",
        )
    }
    assets = {role: [""] * n for role in FILE_ROLES}
    version = [0] * n
    res_wh = [(0, 0)] * n
    factors = {name: [float(v)] * n for name, v in FACTORS.items()}
    page = [0] * n
    scale_offset = [_NO_SCALE_OFFSET] * n
    for key, res in records.items():
        e = where[key]
        try:
            packing = layout_packing(res.model, res.ratio)
        except Exception:
            packing = {}
        version[e] = int(res.format_version)
        res_wh[e] = tuple(int(r) for r in res.resolution)
        for k, v in (
            ("baked:model", res.model),
            ("baked:ratio", res.ratio),
            ("baked:solver", res.solver),
            ("baked:uvPrimvar", res.uv_primvar),
            ("baked:tangentFrame", res.tangent_frame),
            ("baked:normals", res.normals),
            ("baked:contentHash", res.content_hash),
            ("baked:partHashes", json_text(res.part_hashes, "part hashes")),
            ("baked:settings", json_text(res.settings, "bake settings")),
            ("baked:generator", res.generator),
        ):
            strings[k][e] = str(v)
        for role, file in res.textures.items():
            assets[role][e] = relative_asset_path(file, layer_dir)
            dkey = "sidecar:sh:digest" if role == SIDECAR_ROLE else f"texture:{role}:digest"
            strings[dkey][e] = res.digests.get(role, "")
            if role != SIDECAR_ROLE:
                strings[f"texture:{role}:packing"][e] = packing.get(role, "")
        for name in FACTORS:
            factors[name][e] = res.factor(name)
        page[e] = int(getattr(res, "page", 0))
        scale_offset[e] = tuple(float(x) for x in getattr(res, "scale_offset", _NO_SCALE_OFFSET))
    if not carrier.HasAPI(INSTANCE_API_NAME) and not carrier.ApplyAPI(INSTANCE_API_NAME):
        raise SchemaError(f"ApplyAPI({INSTANCE_API_NAME}) failed on <{path}>")

    def put(key, value):
        attr = carrier.GetAttribute(instance_property_name(key))
        if not attr or not attr.Set(value):
            raise SchemaError(f"could not author {instance_property_name(key)} on <{path}>")
        return attr

    put("count", int(count))
    put("meshes", Vt.StringArray([rel for _, rel in cols]))
    put("prototypes", Vt.IntArray([k for k, _ in cols]))
    put("baked:formatVersion", Vt.IntArray(version))
    put("baked:resolution", Vt.Vec2iArray([Gf.Vec2i(*wh) for wh in res_wh]))
    for k, values in strings.items():
        if k.endswith(("model", "ratio", "tangentFrame", "normals")) and k.startswith("baked:"):
            put(k, Vt.TokenArray(values))
        else:
            put(k, Vt.StringArray(values))
    for role, values in assets.items():
        key = "sidecar:sh" if role == SIDECAR_ROLE else f"texture:{role}"
        put(key, Sdf.AssetPathArray([Sdf.AssetPath(a) for a in values])).SetColorSpace(
            COLOR_SPACES[role]
        )
    for name, values in factors.items():
        put(f"baked:{name}", Vt.FloatArray(values))
    put("atlas:page", Vt.IntArray(page))
    put("atlas:scaleOffset", Vt.Vec4fArray([Gf.Vec4f(*so) for so in scale_offset]))


def read_instance_records(carrier: Usd.Prim, *, validate: bool = True) -> dict:
    """{:func:`instance_key` -> BakeResults} of the entries authored on a carrier prim (those
    with formatVersion != 0); empty when the prim has no ``AhdInstanceLightmapAPI``. With
    ``validate`` an invalid entry raises SchemaError naming its key. The entries'
    ``textures`` are resolved absolute paths, ``asset_paths`` the authored strings."""
    if not carrier or not carrier.HasAPI(INSTANCE_API_NAME):
        return {}
    from pxr import UsdGeom

    path = str(carrier.GetPath())
    is_pi = carrier.IsA(UsdGeom.PointInstancer)

    def get(key, default=()):
        attr = carrier.GetAttribute(instance_property_name(key))
        v = attr.Get() if attr else None
        return default if v is None else v

    count = int(get("count", 0))
    meshes = list(get("meshes"))
    m = len(meshes)
    version = list(get("baked:formatVersion"))
    n = min(len(version), count * m)
    arrays = {}
    for key in (
        "baked:resolution",
        "baked:model",
        "baked:ratio",
        "baked:solver",
        "baked:uvPrimvar",
        "baked:tangentFrame",
        "baked:normals",
        "baked:contentHash",
        "baked:partHashes",
        "baked:settings",
        "baked:generator",
        "atlas:page",
        "atlas:scaleOffset",
        *(f"baked:{f}" for f in FACTORS),
        *(f"texture:{r}" for r in ROLES),
        *(f"texture:{r}:digest" for r in ROLES),
        *(f"texture:{r}:packing" for r in ROLES),
        "sidecar:sh",
        "sidecar:sh:digest",
    ):
        arrays[key] = list(get(key))

    def at(key, e, default):
        a = arrays[key]
        return a[e] if e < len(a) else default

    out = {}
    for e in range(n):
        if not version[e]:
            continue
        key = instance_key(path, e // m, meshes[e % m], is_pi)
        textures, assets, digests, packing = {}, {}, {}, {}
        for role in FILE_ROLES:
            akey = "sidecar:sh" if role == SIDECAR_ROLE else f"texture:{role}"
            a = at(akey, e, None)
            if a is None or not a.path:
                continue
            assets[role] = a.path
            textures[role] = a.resolvedPath or a.path
            d = at(f"{akey}:digest", e, "")
            if d:
                digests[role] = str(d)
            if role != SIDECAR_ROLE:
                pk = at(f"texture:{role}:packing", e, "")
                if pk:
                    packing[role] = str(pk)

        def js(k, e=e, key=key):
            try:
                v = json.loads(at(k, e, "") or "{}")
            except ValueError as exc:
                what = f"<{key}>: {instance_property_name(k)} is not JSON: {exc}"
                raise SchemaError(what) from None
            if not isinstance(v, dict):
                raise SchemaError(f"<{key}>: {instance_property_name(k)} must hold JSON objects")
            return v

        wh = at("baked:resolution", e, (0, 0))
        res = BakeResults(
            model=str(at("baked:model", e, "")),
            ratio=str(at("baked:ratio", e, "")),
            solver=str(at("baked:solver", e, "")),
            uv_primvar=str(at("baked:uvPrimvar", e, "")),
            resolution=(int(wh[0]), int(wh[1])),
            textures=textures,
            factors={f: float(at(f"baked:{f}", e, FACTORS[f])) for f in FACTORS},
            tangent_frame=str(at("baked:tangentFrame", e, "")),
            content_hash=str(at("baked:contentHash", e, "")),
            part_hashes=js("baked:partHashes"),
            settings=js("baked:settings"),
            generator=str(at("baked:generator", e, "")),
            format_version=int(version[e]),
            asset_paths=assets,
            normals=str(at("baked:normals", e, "")),
            digests=digests,
            packing=packing,
        )
        so = at("atlas:scaleOffset", e, _NO_SCALE_OFFSET)
        res.page = int(at("atlas:page", e, 0))
        res.scale_offset = tuple(float(x) for x in so)
        # An entry lives in an atlas page when it has a rectangle of one: a record alone on a
        # page of its own size reads the same either way (its rectangle is the whole file).
        res.atlas = res.scale_offset != _NO_SCALE_OFFSET or res.page != 0
        if validate:
            problems = result_problems(res)
            if problems:
                raise SchemaError(f"<{key}>: invalid bake record: " + "; ".join(problems))
        out[key] = res
    return out


def instance_carriers(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every prim of ``stage`` with ``AhdInstanceLightmapAPI`` (instance proxies included:
    a PointInstancer inside a prototype)."""
    rng = Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
    return [p for p in rng if p.HasAPI(INSTANCE_API_NAME)]


def stage_records(stage: Usd.Stage, *, validate: bool = True, errors: list | None = None) -> dict:
    """Every bake record of a stage: {key -> BakeResults} for baked mesh prims (key: the prim
    path) and instance entries (key: :func:`instance_key`). A record seen through an
    instance proxy (or on a PointInstancer's prototype, through a reference) is the
    prototype's, not the copy's, and is left out (the copy's own record is its instance
    entry). With ``errors`` (a list) an unreadable record is appended as
    (key, message) and skipped; else its exception (SchemaError for an invalid record)
    propagates."""
    from usdahd.usd.instances import in_point_instancer_prototype

    out = {}
    for prim in prims_with_api(stage):
        if prim.IsInstanceProxy() or in_point_instancer_prototype(prim):
            continue
        try:
            res = read_results(prim, validate=validate)
        except Exception as exc:  # a hand-edited value of the wrong type raises TypeError too
            if errors is None:
                raise
            errors.append((str(prim.GetPath()), str(exc)))
            continue
        if res is not None:
            out[str(prim.GetPath())] = res
    for carrier in instance_carriers(stage):
        try:
            out.update(read_instance_records(carrier, validate=validate))
        except Exception as exc:
            if errors is None:
                raise
            errors.append((str(carrier.GetPath()), str(exc)))
    return out


def instance_carrier(stage: Usd.Stage, key: str) -> str | None:
    """The carrier prim path of an instance entry key (:func:`instance_key`): the instance
    prim above an instance proxy, or the PointInstancer of ``<PI>/instance_<i>/...``; None
    when ``key`` is no instance entry of ``stage`` (an ordinary prim path)."""
    from pxr import UsdGeom

    if not Sdf.Path.IsValidPathString(key):
        return None
    path = Sdf.Path(key)
    prim = stage.GetPrimAtPath(path)
    if prim and prim.IsInstanceProxy():
        while prim and prim.IsInstanceProxy():
            prim = prim.GetParent()
        return str(prim.GetPath())
    if prim:
        return None
    for anc in path.GetAncestorsRange():
        p = stage.GetPrimAtPath(anc.GetParentPath()) if anc.GetParentPath() else None
        if p and p.IsA(UsdGeom.PointInstancer) and anc.name.startswith("instance_"):
            return str(p.GetPath())
    return None
