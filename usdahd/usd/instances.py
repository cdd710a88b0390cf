"""Instance records seen as mesh records: the view ``usdahd validate`` checks them through.

The bake records each instance copy outside its prototype (on the instance prim or the
PointInstancer: :func:`usdahd.usd.schema.write_instance_records`), so the validator's rules,
written against a mesh prim with ``AhdLightmapAPI``, have no prim to run on. :func:`record_view`
gives them one in the stage's session layer for the duration of a validation, without touching
any file: scenegraph instances holding records are made non-instanceable (their copies become
real prims at the same paths), each PointInstancer instance becomes a prim
``<PI>/instance_<i>`` (its prototype referenced, at its instance transform; the scene reader
never reads a PointInstancer's children, so the scene the Staleness rule hashes is unchanged),
and every entry is authored there as an ordinary ``AhdLightmapAPI`` record (texture paths
absolute). A copy that should have a record and has none (its prototype mesh has records on
other copies, or the copy sees the prototype's own record through the instance) is blocked
(``ahdLightmap:bake = false``) and returned as a missing record.
"""

from __future__ import annotations

import contextlib

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

from usdahd.usd import schema
from usdahd.usd.instance_records import point_instancer_time

__all__ = ["in_point_instancer_prototype", "record_view"]


def in_point_instancer_prototype(prim) -> bool:
    """Whether ``prim`` is (under) a prototype of a PointInstancer: not scene geometry (the
    reader expands the instances instead), so a record it shows came through a reference."""
    anc = prim.GetParent()
    path = prim.GetPath()
    while anc and not anc.IsPseudoRoot():
        if anc.IsA(UsdGeom.PointInstancer):
            targets = UsdGeom.PointInstancer(anc).GetPrototypesRel().GetTargets()
            if any(path.HasPrefix(t) for t in targets):
                return True
        anc = anc.GetParent()
    return False


def _deinstance(stage, path: Sdf.Path) -> None:
    """Make every instance on the way to ``path`` non-instanceable (session layer)."""
    for anc in reversed(list(path.GetAncestorsRange())):
        prim = stage.GetPrimAtPath(anc)
        if prim and prim.IsInstance():
            prim.SetInstanceable(False)


def _point_instancer_prims(stage, carrier, count: int) -> dict[str, Usd.Prim]:
    """Define ``<PI>/instance_<i>`` for every unmasked instance: its prototype referenced, at
    its instance transform (prototype root's own transform included, as the reader does)."""
    pi = UsdGeom.PointInstancer(carrier)
    protos = pi.GetPrototypesRel().GetTargets()
    t = point_instancer_time(pi)
    ids = pi.GetProtoIndicesAttr().Get(t) or []
    xfs = pi.ComputeInstanceTransformsAtTime(t, t) or []
    mask = pi.ComputeMaskAtTime(t)
    cache = UsdGeom.XformCache(t)
    out = {}
    for i in range(count):
        name = carrier.GetPath().AppendChild(f"instance_{i}")
        known = i < len(ids) and i < len(xfs) and 0 <= ids[i] < len(protos)
        root = stage.GetPrimAtPath(protos[ids[i]]) if known else None
        # the prototype root's own type: a prototype that is a mesh itself stays a Mesh
        prim = stage.DefinePrim(name, root.GetTypeName() if root else "Xform")
        prim.SetInstanceable(False)
        if not known:
            out[str(name)] = prim
            continue
        if mask and not mask[i]:
            prim.SetActive(False)
            continue
        prim.GetReferences().AddInternalReference(protos[ids[i]])
        local = np.array(cache.GetLocalTransformation(root)[0]) if root else np.eye(4)
        m = Gf.Matrix4d((local @ np.array(xfs[i])).tolist())
        xf = UsdGeom.Xformable(prim)
        xf.ClearXformOpOrder()
        xf.AddTransformOp().Set(m)
        out[str(name)] = prim
    return out


def _author(prim, res) -> None:
    """An entry as an AhdLightmapAPI record on ``prim`` with absolute texture paths."""
    schema.write_results(prim, res, layer_dir="/")
    for role, file in res.textures.items():
        prim.GetAttribute(schema.file_property_name(role)).Set(Sdf.AssetPath(str(file)))


@contextlib.contextmanager
def record_view(stage):
    """Within the block, every instance entry of ``stage`` is an AhdLightmapAPI record on a
    prim at its key (see the module doc); yields [(key, message)] of copies that should have
    a record and have none. The session layer is restored afterwards."""
    session = stage.GetSessionLayer()
    carriers = schema.instance_carriers(stage)
    inherited = {}  # instance root -> proxies that see a prototype's record
    in_prototypes = []  # PointInstancer prototype prims that see a referenced prim's record
    for p in schema.prims_with_api(stage):
        if in_point_instancer_prototype(p):
            in_prototypes.append(p.GetPath())
        elif p.IsInstanceProxy():
            root = p
            while root.IsInstanceProxy():
                root = root.GetParent()
            inherited.setdefault(str(root.GetPath()), []).append(str(p.GetPath()))
    if not carriers and not inherited and not in_prototypes:
        yield []
        return
    saved = session.ExportToString()
    missing = []
    try:
        with Usd.EditContext(stage, session):
            for path in in_prototypes:  # not scene geometry: its copies carry the records
                _deinstance(stage, path)
                prim = stage.GetPrimAtPath(path)
                if prim and not prim.IsInstanceProxy():
                    schema.write_inputs(prim, bake=False)
                    prim.GetAttribute(schema.property_name("baked:formatVersion")).Set(0)
            missing = _build(stage, carriers, inherited)
        yield missing
    finally:
        session.ImportFromString(saved)


def _build(stage, carriers, inherited) -> list[tuple[str, str]]:
    missing: list[tuple[str, str]] = []
    entries: dict[str, tuple] = {}  # key -> (carrier path, BakeResults or None)
    baked_protos: dict[str, set] = {}  # prototype identity -> mesh rels with records
    sg_roots = {}
    for carrier in carriers:
        path = str(carrier.GetPath())
        try:
            records = schema.read_instance_records(carrier, validate=False)
        except schema.SchemaError as exc:
            missing.append((path, f"the instance records cannot be read: {exc}"))
            continue
        count, cols = schema.instance_layout(carrier)
        is_pi = carrier.IsA(UsdGeom.PointInstancer)
        if is_pi:
            pi = UsdGeom.PointInstancer(carrier)
            t = point_instancer_time(pi)
            ids = pi.GetProtoIndicesAttr().Get(t) or []
            mask = pi.ComputeMaskAtTime(t)
            done = {
                (k, rel)
                for i in range(count)
                for k, rel in cols
                if schema.instance_key(path, i, rel, True) in records
            }
            for i in range(count):
                if mask and not mask[i]:
                    continue
                for k, rel in cols:
                    key = schema.instance_key(path, i, rel, True)
                    if i < len(ids) and ids[i] == k and (k, rel) in done:
                        entries[key] = (path, records.get(key))
            for key in records:
                entries.setdefault(key, (path, records[key]))
        else:
            sg_roots[path] = carrier
            proto = str(carrier.GetPrototype().GetPath()) if carrier.IsInstance() else path
            for key, res in records.items():
                entries[key] = (path, res)
                rel = key[len(path) :].lstrip("/") or "."
                baked_protos.setdefault(proto, set()).add(rel)
    # Scenegraph copies of a prototype mesh that other copies have records for, and copies
    # that see a prototype's own record through the instance: each needs its own entry.
    for proto in stage.GetPrototypes():
        rels = baked_protos.get(str(proto.GetPath()), set())
        for inst in proto.GetInstances():
            ip = str(inst.GetPath())
            for rel in rels:
                key = schema.instance_key(ip, 0, rel, False)
                entries.setdefault(key, (ip, None))
    for root, proxies in inherited.items():
        for key in proxies:
            entries.setdefault(key, (root, None))
    by_carrier: dict[str, list] = {}
    for key, (carrier, res) in entries.items():
        by_carrier.setdefault(carrier, []).append((key, res))
    for carrier, items in sorted(by_carrier.items()):
        cprim = stage.GetPrimAtPath(carrier)
        if cprim.IsA(UsdGeom.PointInstancer):
            count, _ = schema.instance_layout(cprim)
            _point_instancer_prims(stage, cprim, count)
        for key, res in sorted(items, key=lambda kv: kv[0]):
            path = Sdf.Path(key)
            _deinstance(stage, path)
            prim = stage.GetPrimAtPath(path)
            if not prim:  # an entry beyond the instances the stage has now
                prim = stage.DefinePrim(path, "Mesh")
            if prim.IsInstanceProxy() or not prim.IsA(UsdGeom.Mesh):
                missing.append((key, "the instance entry names no mesh of its prototype"))
                continue
            if res is None:
                schema.apply(prim)
                schema.write_inputs(prim, bake=False)  # not validated as the prototype's
                prim.GetAttribute(schema.property_name("baked:formatVersion")).Set(0)
                missing.append((key, "the instance copy has no bake record of its own"))
                continue
            _author(prim, res)
    return missing
