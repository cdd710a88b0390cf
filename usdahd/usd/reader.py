"""Stage -> :class:`usdahd.scene.types.Scene`: the traversal that calls the readers.

``load_scene(stage)`` walks the composed stage once at the bake time (:mod:`usdahd.usd.time`):
instance proxies included, so scenegraph instances are flattened; invisible subtrees pruned;
guide and proxy purpose skipped (``ComputePurposeInfo``: a render child of a guide parent is
read); PointInstancers expanded (:meth:`SceneReader.point_instancer`). Each prim goes to the
reader of its concept, and each returns pxr-free :mod:`usdahd.scene` types:

- :mod:`usdahd.usd.geometry` : UsdGeom.Mesh and implicit gprims -> ``Scene.meshes``
  (triangulated, counter-clockwise front faces, world space; ``bake`` is True for visible
  default/render-purpose meshes, narrowed by ``prims``; instances and implicit gprims are
  occluders), ``texcoords``, ``computed_normals``, ``failed``;
- :mod:`usdahd.usd.materials` : bound UsdPreviewSurface materials -> ``Scene.materials``;
- :mod:`usdahd.usd.lights` : UsdLux lights in physical units -> ``Scene.lights``
  (docs/lights.md).

Whole-stage problems raise :class:`usdahd.errors.StageError`: an unreadable file, no meshes,
a composition cycle, metersPerUnit <= 0 or non-finite, a light or emissive material with
negative/NaN/Inf or overflowing emission, a DomeLight texture that cannot be read. Per-mesh
problems put the mesh in ``Scene.failed`` (the rest of the stage bakes). Nothing unsupported
is silent: each case is one string in ``Scene.warnings``. docs/usd-semantics.md and
docs/lights.md list what is honoured and what is warned.
"""

from __future__ import annotations

import numpy as np
from pxr import Pcp, Sdf, Usd, UsdGeom, UsdLux

from usdahd.errors import StageError
from usdahd.scene.types import InstanceRef, Scene
from usdahd.usd import stage as S
from usdahd.usd.geometry import GeometryReader
from usdahd.usd.lights import LightReader
from usdahd.usd.materials import MaterialReader
from usdahd.usd.time import resolve_time, time_label

__all__ = [
    "ReadContext",
    "SceneReader",
    "instance_ref",
    "instance_root",
    "load_scene",
    "no_instance_uv_message",
]


def no_instance_uv_message(origin: str, uv_name: str, copies: int) -> str:
    """Why the instance copies of a prototype mesh are not baked: it has no lightmap UVs."""
    return (
        f"{origin}: prototype mesh has no lightmap UV set {uv_name!r}, so its {copies} "
        "instance copies are traced as occluders only (not baked): xatlas cannot author UVs "
        "inside a prototype. Fix: author the UV set in the asset (or bake the asset file on "
        "its own with usdahd bake, which unwraps it into its output layer, and reference that "
        "layer instead), or make the instances non-instanceable (instanceable = false)"
    )


class ReadContext:
    """What every reader of one stage shares: the stage, the time code every attribute is
    read at, the transform cache at that time, the upAxis, and the warnings (one list, in the
    order they arise, each message once per ``key``)."""

    def __init__(self, stage, time=None):
        self.stage = stage
        self.time = Usd.TimeCode.Default() if time is None else time
        self.xf = UsdGeom.XformCache(self.time)
        self.when = time_label(self.time)
        self.warnings: list[str] = []
        self._warned: set[str] = set()
        self.up_axis = S.up_axis(stage, self.warn)

    def warn(self, msg: str, key: str | None = None):
        key = key or msg
        if key not in self._warned:
            self._warned.add(key)
            self.warnings.append(msg)

    def get(self, attr, default=None):
        """The attribute's value at the bake time; an attribute that only has time samples
        at the default time is read at its first sample (warned once); ``default`` when it
        is invalid or has no value."""
        if not attr or not attr.IsValid():
            return default
        v = attr.Get(self.time)
        if v is None and attr.GetNumTimeSamples() > 0:
            t = attr.GetTimeSamples()[0]
            self.warn(
                f"{attr.GetPath()}: only time samples authored; read at time {t}",
                key=f"ts:{attr.GetPath()}",
            )
            v = attr.Get(Usd.TimeCode(t))
        return default if v is None else v


class SceneReader:
    """One traversal of a stage (see the module docstring): ``geometry``, ``materials`` and
    ``lights`` readers sharing one :class:`ReadContext`."""

    def __init__(self, stage, uv_name, time=None):
        self.ctx = ReadContext(stage, time)
        self.stage = stage
        self.warn = self.ctx.warn
        self.get = self.ctx.get
        self.materials = MaterialReader(self.ctx)
        self.geometry = GeometryReader(self.ctx, self.materials, uv_name)
        self.lights = LightReader(self.ctx)

    def run(self):
        """Traverse the stage: visibility, purpose, PointInstancers, lights, gprims."""
        pred = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        it = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), pred))
        purposes = {}  # prim path -> UsdGeom.Imageable.PurposeInfo, for the children
        geo = self.geometry
        for prim in it:
            if prim.IsPseudoRoot():
                continue
            img = UsdGeom.Imageable(prim)
            if img:
                va = img.GetVisibilityAttr()
                vis = self.get(va, UsdGeom.Tokens.inherited)
                if va.GetNumTimeSamples() > 0:
                    self.warn(
                        f"{prim.GetPath()}: visibility is animated; baked as it is at "
                        f"{self.ctx.when} ({vis})"
                    )
                if vis == UsdGeom.Tokens.invisible:  # invisibility is inherited: prune
                    it.PruneChildren()
                    continue
                # Purpose is inherited unless a descendant authors its own: a render child
                # of a guide parent is rendered (UsdGeomImageable::ComputePurposeInfo).
                parent = purposes.get(prim.GetParent().GetPath())
                info = img.ComputePurposeInfo(parent) if parent else img.ComputePurposeInfo()
                purposes[prim.GetPath()] = info
                if info.purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                    if prim.IsA(UsdGeom.PointInstancer):
                        it.PruneChildren()  # its prototypes are not scene geometry
                    continue
            if prim.IsA(UsdGeom.PointInstancer):
                self.point_instancer(prim)
                it.PruneChildren()
                continue
            if prim.HasAPI(UsdLux.LightAPI):
                self.lights.read(prim)
            elif prim.IsA(UsdLux.PortalLight) or prim.IsA(UsdLux.PluginLight):
                self.warn(f"{prim.GetPath()}: {prim.GetTypeName()} is not supported (ignored)")
            if prim.IsA(UsdGeom.Gprim):
                m = np.array(self.ctx.xf.GetLocalToWorldTransform(prim))
                path, inst = str(prim.GetPath()), prim.IsInstanceProxy()
                geo.instance_ref = instance_ref(prim) if inst else None
                try:
                    if prim.IsA(UsdGeom.Mesh):
                        geo.guarded(geo.mesh, prim, m, path, inst)
                    else:
                        geo.guarded(geo.implicit_gprim, prim, m, path, inst)
                finally:
                    geo.instance_ref = None

    def point_instancer(self, prim):
        """Expand a PointInstancer: every (unmasked) instance's prototype gprims as instanced
        occluders named ``<instancer>/instance_<i>/<path in prototype>``."""
        pi = UsdGeom.PointInstancer(prim)
        path = str(prim.GetPath())
        time, xf, geo = self.ctx.time, self.ctx.xf, self.geometry
        protos = pi.GetPrototypesRel().GetTargets()
        ids = self.get(pi.GetProtoIndicesAttr())
        if not protos or ids is None or len(ids) == 0:
            return
        xfs = pi.ComputeInstanceTransformsAtTime(time, time)
        if not xfs:
            self.warn(f"{path}: PointInstancer transforms could not be computed (ignored)")
            return
        world = np.array(xf.GetLocalToWorldTransform(prim))
        mask = pi.ComputeMaskAtTime(time)
        pred = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        for i, (pid, ixf) in enumerate(zip(ids, xfs)):
            if mask and not mask[i]:
                continue
            if pid < 0 or pid >= len(protos):
                self.warn(
                    f"{path}: protoIndices[{i}] = {pid} out of range [0, {len(protos)}): "
                    "instance skipped",
                    key=f"pi:{path}",
                )
                continue
            root = self.stage.GetPrimAtPath(protos[pid])
            if not root:
                continue
            inst_m = np.array(ixf) @ world
            for p in Usd.PrimRange(root, pred):
                if p.IsA(UsdGeom.Gprim):
                    rel, _ = xf.ComputeRelativeTransform(p, root)
                    local_root = np.array(xf.GetLocalTransformation(root)[0])
                    m = np.array(rel) @ local_root @ inst_m
                    name = f"{path}/instance_{i}{str(p.GetPath())[len(str(root.GetPath())) :]}"
                    fn = geo.mesh if p.IsA(UsdGeom.Mesh) else geo.implicit_gprim
                    geo.instancer = path
                    rel = p.GetPath().MakeRelativePath(root.GetPath())
                    geo.instance_ref = InstanceRef(
                        carrier=path,
                        index=i,
                        prototype=int(pid),
                        mesh=str(rel),
                        source=str(p.GetPath()),
                        origin=_in_prototype(prototype_origin(root, f"<{root.GetPath()}>"), rel),
                    )
                    try:
                        geo.guarded(fn, p, m, name, True)
                    finally:
                        geo.instancer = None
                        geo.instance_ref = None


def instance_root(prim):
    """The outermost instance prim above an instance proxy (the prim that is an instance and
    not itself a proxy): where the proxy's bake record lives (docs/schema.md, "Instances")."""
    while prim and prim.IsInstanceProxy():
        prim = prim.GetParent()
    return prim


def prototype_origin(root, fallback: str | None = None) -> str:
    """The prototype of the instance (or PointInstancer prototype) ``root`` as a user finds
    it: ``@layer@</Proto>`` of its first reference or payload, else ``fallback`` (default: the
    first arc's path, else the stage's prototype path)."""
    nodes = list(root.GetPrimIndex().rootNode.children)
    for node in nodes:
        if node.arcType in (Pcp.ArcTypeReference, Pcp.ArcTypePayload):
            layer = node.layerStack.identifier.rootLayer.identifier
            return f"@{layer}@<{node.path}>"
    if fallback is not None:
        return fallback
    if nodes:
        return f"<{nodes[0].path}>"
    return f"<{root.GetPrototype().GetPath()}>"


def _in_prototype(origin: str, rel) -> str:
    """``@l@</Proto>`` and ``Box`` -> ``@l@</Proto/Box>`` (rel "." -> the origin itself)."""
    rel = str(rel)
    inner = "" if rel == "." else "/" + rel
    return origin[:-1] + inner + ">" if origin.endswith(">") else origin + inner


def instance_ref(proxy) -> InstanceRef:
    """The :class:`~usdahd.scene.types.InstanceRef` of a mesh seen through an instance proxy."""
    root = instance_root(proxy)
    rel = str(proxy.GetPath().MakeRelativePath(root.GetPath()))
    return InstanceRef(
        carrier=str(root.GetPath()),
        index=0,
        prototype=0,
        mesh=rel,
        source=str(proxy.GetPath()),
        origin=_in_prototype(prototype_origin(root), rel),
    )


def load_scene(
    stage, *, uv_name: str = "st", prims=None, bake_instances: bool = True, time=None
) -> Scene:
    """Extract a :class:`~usdahd.scene.types.Scene` from a ``Usd.Stage`` or a path to one.

    time : the time every attribute is read at: None (default) picks the stage's
        startTimeCode when anything the bake reads is animated, else the default time (see
        :func:`usdahd.usd.time.resolve_time`); a number; or ``"default"`` for
        ``Usd.TimeCode.Default()``.
    uv_name : lightmap UV primvar read per mesh (``MeshData.uv`` None when absent).
    prims : optional iterable of prim paths; only meshes at or under them are baked (all
        others still occlude). Unknown paths raise StageError.
    bake_instances : mark instance copies (scenegraph instance proxies, PointInstancer
        instances) for baking, each on its prototype's lightmap UVs (default); a prototype
        mesh without the UV set ``uv_name`` gives one warning and its copies stay occluders
        (xatlas cannot author UVs inside a prototype). False: every copy is an occluder.
    Per-mesh problems do not raise: the mesh goes to ``Scene.failed`` (see the module doc).
    Raises StageError for unreadable or non-USD files, stages without meshes, composition
    cycles, a bad metersPerUnit, and broken lights or emissive materials (each message names
    the prim or file and what to do).
    """
    stage, source = S.as_stage(stage)
    mpu = S.meters_per_unit(stage, source)
    warnings: list[str] = []
    t, auto = resolve_time(stage, time, warnings.append)
    rd = SceneReader(stage, uv_name, t)
    geo, mats, lights = rd.geometry, rd.materials, rd.lights
    for w in warnings:
        rd.warn(w)
    S.composition_warnings(stage, source, rd.warn)
    rd.run()
    if not geo.meshes and not geo.failed:
        raise StageError(f"{source}: no visible UsdGeom meshes or gprims to bake or trace")
    failed = dict(geo.failed)
    if prims is not None:
        roots = [str(p) for p in prims]
        for r in roots:
            if not stage.GetPrimAtPath(Sdf.Path(r)):
                raise StageError(f"{source}: --prims path {r} does not exist on the stage")

        def selected(path):
            return any(path == r or path.startswith(r.rstrip("/") + "/") for r in roots)

        for m in geo.meshes:
            m.bake = m.bake and selected(m.path)
        for path in [p for p in failed if not selected(p)]:
            rd.warn(f"{failed.pop(path)} (not selected: dropped from the occluders)")
    geo.size_warnings()
    geo.normals_warnings()
    lights.light_warnings(geo.meshes)
    mats.material_warnings()
    lights.link_membership(geo.link_paths[: len(geo.meshes)])
    if bake_instances:
        no_uv: dict[str, int] = {}
        for m, inst in zip(geo.meshes, geo.instanced):
            if not inst or geo.implicit.get(id(m), False) or m.instance is None:
                continue
            m.bake = prims is None or selected(m.path) or selected(m.instance.carrier)
            if m.bake and m.uv is None:
                m.bake = False
                no_uv[m.instance.origin] = no_uv.get(m.instance.origin, 0) + 1
        for origin, n in sorted(no_uv.items()):
            rd.warn(no_instance_uv_message(origin, uv_name, n))
    elif any(geo.instanced):
        n = sum(geo.instanced)
        rd.warn(
            f"{n} instanced mesh copies are traced as occluders only (not baked): "
            "their primvars cannot be authored without de-instancing"
        )
    if not any(m.bake for m in geo.meshes) and not failed:
        rd.warn("no mesh selected for baking (only occluders found)")
    return Scene(
        meshes=geo.meshes,
        materials=mats.materials,
        lights=lights.lights,
        warnings=rd.ctx.warnings,
        meters_per_unit=mpu,
        up_axis=rd.ctx.up_axis,
        texcoords=geo.texcoords,
        source=source,
        failed=failed,
        computed_normals=geo.computed_normals,
        time=None if t.IsDefault() else float(t.GetValue()),
        time_auto=auto,
    )
