"""Stage -> flat world-space arrays: meshes, materials and lights (the only pxr geometry reader).

``load_scene(stage)`` walks the composed stage once (instance proxies included, so scenegraph
instances are flattened; PointInstancers are expanded; implicit gprims are tessellated as
occluders) and returns a :class:`Scene`:

- ``meshes`` : list of :class:`usdahd.bake.types.MeshData` (triangulated, counter-clockwise
  front faces, world space). ``bake`` is True for visible default/render-purpose UsdGeom.Mesh
  prims (narrowed by ``prims``); instances and implicit gprims are occluders.
- ``materials`` : list of :class:`Material` (UsdPreviewSurface diffuse/emission/opacity,
  constant or a texture read through OpenImageIO).
- ``texcoords`` : per mesh, ``{varname: (t, 3, 2) float32}`` texture coordinates the materials
  of that mesh read (the lightmap set is ``MeshData.uv``).
- ``lights`` : :mod:`usdahd.bake.lights` objects in UsdLux units (see that module).
- ``warnings`` : one string per unsupported feature met; never silent.

Everything is evaluated at ``Usd.TimeCode.Default()``; attributes that only have time samples
are read at their first sample (with a warning).
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from usdahd.bake import lights as L
from usdahd.bake.types import MeshData
from usdahd.errors import StageError

#: Corners whose smooth normal deviates more than this from the face normal use the face
#: normal instead (keeps boxes flat-shaded while smoothing tessellated curves).
SMOOTH_COS_LIMIT = math.cos(math.radians(45.0))
#: UsdPreviewSurface diffuseColor fallback.
DEFAULT_ALBEDO = (0.18, 0.18, 0.18)


@dataclass
class Texture:
    """A texture read into memory. data : (h, w, c) float32, linear; row 0 = top (v = 1)."""

    path: str
    data: np.ndarray
    scale: np.ndarray  # (4,) UsdUVTexture inputs:scale
    bias: np.ndarray  # (4,) inputs:bias
    channels: tuple[int, ...]  # output channels selected (rgb -> (0,1,2), a -> (3,), ...)
    wrap: tuple[str, str] = ("repeat", "repeat")

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear lookup. uv : (m, 2) -> (m, len(channels)) float32 (scale*tex+bias)."""
        h, w, c = self.data.shape
        x = uv[:, 0] * w - 0.5
        y = (1.0 - uv[:, 1]) * h - 0.5
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = (x - x0)[:, None]
        fy = (y - y0)[:, None]

        def wrapi(i, n, mode):
            i = i.astype(np.int64)
            if mode in ("clamp", "black"):
                return np.clip(i, 0, n - 1)
            if mode == "mirror":
                i = np.mod(i, 2 * n)
                return np.where(i >= n, 2 * n - 1 - i, i)
            return np.mod(i, n)

        xs = [wrapi(x0, w, self.wrap[0]), wrapi(x0 + 1, w, self.wrap[0])]
        ys = [wrapi(y0, h, self.wrap[1]), wrapi(y0 + 1, h, self.wrap[1])]
        d = self.data
        v = (
            d[ys[0], xs[0]] * (1 - fx) * (1 - fy)
            + d[ys[0], xs[1]] * fx * (1 - fy)
            + d[ys[1], xs[0]] * (1 - fx) * fy
            + d[ys[1], xs[1]] * fx * fy
        )
        if c < 4:  # missing channels: alpha = 1, grey replicated
            pad = np.ones((v.shape[0], 4 - c), v.dtype)
            if c == 1:
                pad[:, :2] = v[:, :1]
            v = np.concatenate([v, pad], axis=1)
        v = v * self.scale[None, :] + self.bias[None, :]
        return v[:, list(self.channels)].astype(np.float32)


@dataclass
class Material:
    """Lambertian surface. Constants are used where the texture is None.

    albedo, emission : (3,) float32 linear; opacity : float; opacity_threshold : float
    (> 0: cut-out, opacity < threshold lets light through; 0 with opacity < 1: stochastic
    transmission); texcoord : primvar name the textures read.
    """

    name: str
    albedo: np.ndarray
    emission: np.ndarray
    opacity: float = 1.0
    opacity_threshold: float = 0.0
    albedo_tex: Texture | None = None
    emission_tex: Texture | None = None
    opacity_tex: Texture | None = None
    texcoord: str = "st"

    @property
    def emissive(self) -> bool:
        return bool(np.any(self.emission > 0) or self.emission_tex is not None)

    @property
    def transmissive(self) -> bool:
        return self.opacity_tex is not None or self.opacity < 1.0

    def key(self) -> str:
        parts = [
            self.name,
            repr(np.round(self.albedo, 7).tolist()),
            repr(np.round(self.emission, 7).tolist()),
            repr((self.opacity, self.opacity_threshold, self.texcoord)),
        ]
        for t in (self.albedo_tex, self.emission_tex, self.opacity_tex):
            parts.append("" if t is None else f"{t.path}:{_digest(t.data.tobytes())}")
        return "|".join(parts)


@dataclass
class Scene:
    meshes: list[MeshData]
    materials: list[Material]
    lights: list
    warnings: list[str]
    meters_per_unit: float
    up_axis: str
    texcoords: list[dict[str, np.ndarray]] = field(default_factory=list)
    source: str = ""

    @property
    def baked_meshes(self) -> list[MeshData]:
        return [m for m in self.meshes if m.bake]

    @property
    def triangle_count(self) -> int:
        return int(sum(len(m.triangles) for m in self.meshes))

    def hash_parts(self) -> dict[str, str]:
        """Content hashes for staleness checks.

        Keys: each baked mesh's prim path (geometry + normals + lightmap UVs + materials
        indices), ``"occluders"`` (all non-baked geometry), ``"lights"``, ``"materials"``.
        """
        out = {}
        occ = hashlib.sha256()
        for m in self.meshes:
            h = hashlib.sha256()
            for a in (m.points, m.triangles, m.normals, m.material, m.uv):
                h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
            if m.bake:
                out[m.path] = h.hexdigest()
            else:
                occ.update(m.path.encode() + h.digest())
        out["occluders"] = occ.hexdigest()
        lh = hashlib.sha256()
        for light in self.lights:
            lh.update(type(light).__name__.encode())
            for k, v in sorted(vars(light).items()):
                if k.startswith("_"):
                    continue
                lh.update(k.encode())
                a = None if v is None or isinstance(v, str) else np.asarray(v)
                if a is None or a.dtype == object:
                    lh.update(repr(v).encode())
                else:
                    lh.update(np.ascontiguousarray(a).tobytes())
        out["lights"] = lh.hexdigest()
        out["materials"] = _digest("\n".join(m.key() for m in self.materials).encode())
        return out


def _digest(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()


# ----------------------------------------------------------------------------- entry point


def load_scene(stage, *, uv_name: str = "st", prims=None, bake_instances: bool = False) -> Scene:
    """Extract a :class:`Scene` from a ``Usd.Stage`` or a path to one.

    uv_name : lightmap UV primvar read per mesh (``MeshData.uv`` None when absent).
    prims : optional iterable of prim paths; only meshes at or under them are baked (all
        others still occlude). Unknown paths raise StageError.
    bake_instances : also mark instance proxies / PointInstancer copies for baking (off by
        default: their primvars cannot be authored without de-instancing).
    Raises StageError for unreadable or non-USD files, stages without meshes, NaN/Inf points,
    inconsistent topology, and negative/NaN light intensities (each message names the prim).
    """
    stage, source = _open(stage)
    ex = _Extractor(stage, uv_name)
    ex.run()
    if not any(isinstance(m, MeshData) for m in ex.meshes) or not ex.meshes:
        raise StageError(f"{source}: no visible UsdGeom meshes or gprims to bake or trace")
    if prims is not None:
        roots = [str(p) for p in prims]
        for r in roots:
            if not stage.GetPrimAtPath(Sdf.Path(r)):
                raise StageError(f"{source}: --prims path {r} does not exist on the stage")
        for m in ex.meshes:
            m.bake = m.bake and any(
                m.path == r or m.path.startswith(r.rstrip("/") + "/") for r in roots
            )
    if bake_instances:
        for m, inst in zip(ex.meshes, ex.instanced):
            if inst and not ex.implicit.get(id(m), False):
                m.bake = True if prims is None else m.bake
    elif any(ex.instanced):
        n = sum(ex.instanced)
        ex.warn(
            f"{n} instanced mesh copies are traced as occluders only (not baked): "
            "their primvars cannot be authored without de-instancing"
        )
    if not any(m.bake for m in ex.meshes):
        ex.warn("no mesh selected for baking (only occluders found)")
    return Scene(
        meshes=ex.meshes,
        materials=ex.materials,
        lights=ex.lights,
        warnings=ex.warnings,
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        texcoords=ex.texcoords,
        source=source,
    )


def _open(stage):
    if isinstance(stage, Usd.Stage):
        return stage, str(stage.GetRootLayer().identifier)
    path = os.fspath(stage)
    if not os.path.isfile(path):
        raise StageError(f"{path}: no such file")
    try:
        st = Usd.Stage.Open(path)
    except Exception as e:  # pxr raises Tf.ErrorException with a long message
        msg = str(e).splitlines()[0][:200] if str(e) else type(e).__name__
        raise StageError(f"{path}: not a readable USD stage ({msg})") from None
    if st is None:
        raise StageError(f"{path}: not a readable USD stage")
    return st, path


# ----------------------------------------------------------------------------- extraction


class _Extractor:
    def __init__(self, stage, uv_name):
        self.stage = stage
        self.uv_name = uv_name
        self.time = Usd.TimeCode.Default()
        self.xf = UsdGeom.XformCache(self.time)
        self.meshes: list[MeshData] = []
        self.texcoords: list[dict] = []
        self.instanced: list[bool] = []
        self.implicit: dict[int, bool] = {}
        self.materials: list[Material] = []
        self._mat_index: dict[str, int] = {}
        self.lights: list = []
        self.warnings: list[str] = []
        self._warned: set[str] = set()
        self._textures: dict = {}

    def warn(self, msg: str, key: str | None = None):
        key = key or msg
        if key not in self._warned:
            self._warned.add(key)
            self.warnings.append(msg)

    # attribute access at the default time, falling back to the first time sample
    def get(self, attr, default=None):
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

    def run(self):
        pred = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        it = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), pred))
        for prim in it:
            if prim.IsPseudoRoot():
                continue
            img = UsdGeom.Imageable(prim)
            if img:
                vis = self.get(img.GetVisibilityAttr(), UsdGeom.Tokens.inherited)
                purpose = self.get(img.GetPurposeAttr(), UsdGeom.Tokens.default_)
                if vis == UsdGeom.Tokens.invisible or purpose in (
                    UsdGeom.Tokens.guide,
                    UsdGeom.Tokens.proxy,
                ):
                    it.PruneChildren()
                    continue
            if prim.IsA(UsdGeom.PointInstancer):
                self._point_instancer(prim)
                it.PruneChildren()
                continue
            if prim.HasAPI(UsdLux.LightAPI):
                self._light(prim)
            elif prim.IsA(UsdLux.PortalLight) or prim.IsA(UsdLux.PluginLight):
                self.warn(f"{prim.GetPath()}: {prim.GetTypeName()} is not supported (ignored)")
            if prim.IsA(UsdGeom.Mesh):
                m = self.xf.GetLocalToWorldTransform(prim)
                self._mesh(prim, np.array(m), str(prim.GetPath()), prim.IsInstanceProxy())
            elif prim.IsA(UsdGeom.Gprim) and not prim.IsA(UsdGeom.Mesh):
                m = self.xf.GetLocalToWorldTransform(prim)
                self._implicit(prim, np.array(m), str(prim.GetPath()), prim.IsInstanceProxy())

    # --------------------------------------------------------------------- meshes
    def _mesh(self, prim, xform, path, instanced, bake=True):
        mesh = UsdGeom.Mesh(prim)
        pts = self.get(mesh.GetPointsAttr())
        counts = self.get(mesh.GetFaceVertexCountsAttr())
        idx = self.get(mesh.GetFaceVertexIndicesAttr())
        if pts is None or counts is None or idx is None or len(pts) == 0 or len(counts) == 0:
            self.warn(f"{path}: mesh without points or faces (skipped)")
            return
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(idx, dtype=np.int64)
        if not np.all(np.isfinite(pts)):
            bad = int(np.argwhere(~np.all(np.isfinite(pts), axis=1))[0, 0])
            raise StageError(f"{path}: points contain NaN/Inf (first at index {bad})")
        if counts.sum() != len(idx):
            raise StageError(
                f"{path}: faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                f"{len(idx)} entries"
            )
        if len(idx) and (idx.min() < 0 or idx.max() >= len(pts)):
            raise StageError(
                f"{path}: faceVertexIndices out of range [0, {len(pts)}) "
                f"(min {int(idx.min())}, max {int(idx.max())})"
            )
        if np.any(counts < 3):
            self.warn(f"{path}: {int((counts < 3).sum())} faces with < 3 vertices ignored")
        left = self.get(mesh.GetOrientationAttr()) == UsdGeom.Tokens.leftHanded
        sda = mesh.GetSubdivisionSchemeAttr()
        sd = self.get(sda) if sda.HasAuthoredValue() else None
        if sd not in (None, UsdGeom.Tokens.none):
            self.warn(
                f"{path}: subdivisionScheme {sd}: the control cage is baked as is", key="subdiv"
            )
        face_mat = self._face_materials(prim, len(counts), path)
        ctx = _Topology(counts, idx)
        self._emit(prim, xform, path, pts, ctx, left, face_mat, instanced, bake)

    def _emit(self, prim, xform, path, pts, topo, left, face_mat, instanced, bake, implicit=False):
        m3 = xform[:3, :3]
        flip = left ^ (np.linalg.det(m3) < 0)
        corners = topo.corners.copy()
        if flip:
            corners = corners[:, [0, 2, 1]]
        tri = topo.idx[corners].astype(np.int32)
        wp = pts @ m3 + xform[3, :3]
        normals = None
        if not implicit:
            normals = self._authored_normals(prim, topo, corners, m3, path)
        if normals is None:
            normals = _smooth_normals(wp, tri)
        uv = None
        texcoords = {}
        if not implicit:
            uv = self._primvar2(prim, self.uv_name, topo, corners, path)
            for mi in np.unique(face_mat):
                name = self.materials[mi].texcoord
                if (
                    any(
                        t is not None
                        for t in (
                            self.materials[mi].albedo_tex,
                            self.materials[mi].emission_tex,
                            self.materials[mi].opacity_tex,
                        )
                    )
                    and name not in texcoords
                ):
                    tc = (
                        uv
                        if name == self.uv_name
                        else self._primvar2(prim, name, topo, corners, path)
                    )
                    if tc is None:
                        self.warn(
                            f"{path}: material texture reads primvar '{name}' which the "
                            "mesh lacks; texture sampled at (0, 0)"
                        )
                    else:
                        texcoords[name] = tc
        md = MeshData(
            path=path,
            points=wp,
            triangles=tri,
            normals=normals.astype(np.float32),
            uv=uv,
            uv_name=self.uv_name,
            material=face_mat[topo.face].astype(np.int32),
            face=topo.face.astype(np.int32),
            corner=corners.astype(np.int32),
            bake=bake and not instanced and not implicit,
        )
        self.meshes.append(md)
        self.texcoords.append(texcoords)
        self.instanced.append(bool(instanced) and not implicit)
        self.implicit[id(md)] = implicit

    def _primvar_corner_values(self, pv, topo, path, width):
        """Expand a primvar to per faceVertex (corner) values (len(idx), width) or None."""
        vals = pv.ComputeFlattened(self.time)
        if vals is None and pv.GetAttr().GetNumTimeSamples():
            vals = pv.ComputeFlattened(Usd.TimeCode(pv.GetAttr().GetTimeSamples()[0]))
        if vals is None or len(vals) == 0:
            return None
        v = np.asarray(vals, dtype=np.float64).reshape(len(vals), -1)
        if v.shape[1] != width:
            self.warn(
                f"{path}: primvar {pv.GetName()} has {v.shape[1]} components, "
                f"expected {width} (ignored)"
            )
            return None
        interp = pv.GetInterpolation()
        n_corner = len(topo.idx)
        if interp == UsdGeom.Tokens.faceVarying:
            need, sel = n_corner, np.arange(n_corner)
        elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            need, sel = int(topo.idx.max()) + 1, topo.idx
        elif interp == UsdGeom.Tokens.uniform:
            need, sel = len(topo.counts), np.repeat(np.arange(len(topo.counts)), topo.counts)
        else:  # constant
            need, sel = 1, np.zeros(n_corner, np.int64)
        if len(v) < need:
            raise StageError(
                f"{path}: primvar {pv.GetName()} ({interp}) has {len(v)} values, needs {need}"
            )
        return v[sel]

    def _primvar2(self, prim, name, topo, corners, path):
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if not pv or not pv.HasValue():
            return None
        v = self._primvar_corner_values(pv, topo, path, 2)
        if v is None:
            return None
        if not np.all(np.isfinite(v)):
            raise StageError(f"{path}: primvar {name} contains NaN/Inf")
        return v[corners].astype(np.float32)

    def _authored_normals(self, prim, topo, corners, m3, path):
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        if pv and pv.HasValue():
            v = self._primvar_corner_values(pv, topo, path, 3)
        else:
            attr = UsdGeom.Mesh(prim).GetNormalsAttr()
            vals = self.get(attr)
            if vals is None or len(vals) == 0:
                return None
            interp = UsdGeom.Mesh(prim).GetNormalsInterpolation()
            v = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
            n_corner = len(topo.idx)
            if interp == UsdGeom.Tokens.faceVarying:
                need, sel = n_corner, np.arange(n_corner)
            elif interp == UsdGeom.Tokens.uniform:
                need, sel = len(topo.counts), np.repeat(np.arange(len(topo.counts)), topo.counts)
            elif interp == UsdGeom.Tokens.constant:
                need, sel = 1, np.zeros(n_corner, np.int64)
            else:
                need, sel = int(topo.idx.max()) + 1, topo.idx
            if len(v) < need:
                self.warn(
                    f"{path}: {len(v)} normals for {interp} interpolation (needs {need}); "
                    "normals recomputed"
                )
                return None
            v = v[sel]
        if v is None:
            return None
        n = v[corners] @ np.linalg.inv(m3).T
        ln = np.linalg.norm(n, axis=-1, keepdims=True)
        if not np.all(np.isfinite(n)) or np.any(ln < 1e-12):
            self.warn(f"{path}: degenerate or NaN authored normals; normals recomputed")
            return None
        return n / ln

    # --------------------------------------------------------------------- implicit gprims
    def _implicit(self, prim, xform, path, instanced):
        pts, tris = _tessellate(prim, self)
        if pts is None:
            self.warn(
                f"{path}: {prim.GetTypeName()} gprims are not supported (ignored)",
                key=f"gprim:{prim.GetTypeName()}",
            )
            return
        counts = np.full(len(tris), 3, np.int64)
        topo = _Topology(counts, tris.reshape(-1).astype(np.int64))
        face_mat = self._face_materials(prim, len(tris), path)
        self._emit(prim, xform, path, pts, topo, False, face_mat, instanced, False, implicit=True)

    # --------------------------------------------------------------------- point instancers
    def _point_instancer(self, prim):
        pi = UsdGeom.PointInstancer(prim)
        path = str(prim.GetPath())
        protos = pi.GetPrototypesRel().GetTargets()
        ids = self.get(pi.GetProtoIndicesAttr())
        if not protos or ids is None or len(ids) == 0:
            return
        xfs = pi.ComputeInstanceTransformsAtTime(self.time, self.time)
        if not xfs:
            self.warn(f"{path}: PointInstancer transforms could not be computed (ignored)")
            return
        world = np.array(self.xf.GetLocalToWorldTransform(prim))
        mask = pi.ComputeMaskAtTime(self.time)
        pred = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        for i, (pid, ixf) in enumerate(zip(ids, xfs)):
            if mask and not mask[i]:
                continue
            if pid < 0 or pid >= len(protos):
                raise StageError(f"{path}: protoIndices[{i}] = {pid} out of range")
            root = self.stage.GetPrimAtPath(protos[pid])
            if not root:
                continue
            inst_m = np.array(ixf) @ world
            for p in Usd.PrimRange(root, pred):
                if p.IsA(UsdGeom.Gprim):
                    rel, _ = self.xf.ComputeRelativeTransform(p, root)
                    local_root = np.array(self.xf.GetLocalTransformation(root)[0])
                    m = np.array(rel) @ local_root @ inst_m
                    name = f"{path}/instance_{i}{str(p.GetPath())[len(str(root.GetPath())) :]}"
                    if p.IsA(UsdGeom.Mesh):
                        self._mesh(p, m, name, True)
                    else:
                        self._implicit(p, m, name, True)

    # --------------------------------------------------------------------- materials
    def _face_materials(self, prim, n_faces, path):
        api = UsdShade.MaterialBindingAPI(prim)
        base = self._material_index(api.ComputeBoundMaterial()[0], prim)
        fm = np.full(n_faces, base, np.int32)
        for subset in api.GetMaterialBindSubsets():
            ind = self.get(subset.GetIndicesAttr())
            if ind is None or len(ind) == 0:
                continue
            ind = np.asarray(ind, np.int64)
            if ind.min() < 0 or ind.max() >= n_faces:
                raise StageError(
                    f"{subset.GetPath()}: GeomSubset indices out of range [0, {n_faces})"
                )
            mat = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
            fm[ind] = self._material_index(mat, prim)
        return fm

    def _material_index(self, mat, prim):
        if not mat:
            color = DEFAULT_ALBEDO
            dc = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
            if dc and dc.HasValue():
                v = dc.ComputeFlattened(self.time)
                if v is not None and len(v):
                    color = tuple(np.asarray(v, np.float64).reshape(-1, 3).mean(axis=0))
            key = f"<displayColor {np.round(color, 6).tolist()}>"
            if key not in self._mat_index:
                self._mat_index[key] = len(self.materials)
                self.materials.append(
                    Material(key, np.array(color, np.float32), np.zeros(3, np.float32))
                )
            return self._mat_index[key]
        key = str(mat.GetPath())
        if key not in self._mat_index:
            self._mat_index[key] = len(self.materials)
            self.materials.append(self._read_material(mat))
        return self._mat_index[key]

    def _read_material(self, mat):
        name = str(mat.GetPath())
        out = Material(name, np.array(DEFAULT_ALBEDO, np.float32), np.zeros(3, np.float32))
        shader = mat.ComputeSurfaceSource()[0]
        if not shader:
            self.warn(f"{name}: no surface shader; albedo {DEFAULT_ALBEDO}")
            return out
        sid = shader.GetIdAttr().Get() if shader.GetIdAttr() else None
        if sid != "UsdPreviewSurface":
            self.warn(
                f"{name}: surface shader {sid} is not UsdPreviewSurface; albedo {DEFAULT_ALBEDO}",
                key=f"shader:{name}",
            )
            return out
        tc_names = []
        out.albedo, out.albedo_tex = self._input(
            shader, "diffuseColor", DEFAULT_ALBEDO, name, tc_names
        )
        out.emission, out.emission_tex = self._input(
            shader, "emissiveColor", (0, 0, 0), name, tc_names
        )
        op, out.opacity_tex = self._input(shader, "opacity", 1.0, name, tc_names)
        out.opacity = float(np.ravel(op)[0])
        thr = shader.GetInput("opacityThreshold")
        out.opacity_threshold = float(self.get(thr.GetAttr(), 0.0)) if thr else 0.0
        if tc_names:
            out.texcoord = tc_names[0]
            if len(set(tc_names)) > 1:
                self.warn(
                    f"{name}: textures read different primvars {sorted(set(tc_names))}; "
                    f"using '{tc_names[0]}'"
                )
        return out

    def _input(self, shader, inp_name, fallback, mat_name, tc_names):
        inp = shader.GetInput(inp_name)
        fb = np.array(fallback, np.float32)
        if not inp:
            return fb, None
        src = inp.GetConnectedSources()[0] if inp.HasConnectedSource() else []
        if not src:
            v = self.get(inp.GetAttr())
            return (fb if v is None else np.array(v, np.float32)), None
        info = src[0]
        tex_shader = UsdShade.Shader(info.source.GetPrim())
        out_name = str(info.sourceName)
        sid = tex_shader.GetIdAttr().Get() if tex_shader.GetIdAttr() else None
        if sid != "UsdUVTexture":
            self.warn(
                f"{mat_name}: {inp_name} connected to {sid}; using its fallback",
                key=f"conn:{mat_name}:{inp_name}",
            )
            return fb, None
        tex = self._texture(tex_shader, out_name, mat_name)
        if tex is None:
            fbi = tex_shader.GetInput("fallback")
            f4 = np.array(
                self.get(fbi.GetAttr(), (0, 0, 0, 1)) if fbi else (0, 0, 0, 1), np.float32
            )
            ch = _channels(out_name)
            return (f4[list(ch)] if len(ch) == fb.size else fb), None
        st = tex_shader.GetInput("st")
        var = "st"
        if st and st.HasConnectedSource():
            rd = UsdShade.Shader(st.GetConnectedSources()[0][0].source.GetPrim())
            vn = rd.GetInput("varname")
            if vn:
                var = str(self.get(vn.GetAttr(), "st"))
        tc_names.append(var)
        return fb, tex

    def _texture(self, tex_shader, out_name, mat_name):
        fin = tex_shader.GetInput("file")
        asset = self.get(fin.GetAttr()) if fin else None
        if asset is None:
            return None
        path = asset.resolvedPath or asset.path
        if "<UDIM>" in (asset.path or ""):
            self.warn(f"{mat_name}: UDIM textures are not supported ({asset.path}); fallback used")
            return None
        cs = tex_shader.GetInput("sourceColorSpace")
        cs = str(self.get(cs.GetAttr(), "auto")) if cs else "auto"
        data = self._read_image(path, cs, mat_name)
        if data is None:
            return None

        def vec4(n, d):
            i = tex_shader.GetInput(n)
            v = self.get(i.GetAttr()) if i else None
            return np.array(d if v is None else v, np.float32)

        wrap = []
        for w in ("wrapS", "wrapT"):
            i = tex_shader.GetInput(w)
            v = str(self.get(i.GetAttr(), "useMetadata")) if i else "useMetadata"
            wrap.append("repeat" if v == "useMetadata" else v)
        return Texture(
            path,
            data,
            vec4("scale", (1, 1, 1, 1)),
            vec4("bias", (0, 0, 0, 0)),
            _channels(out_name),
            (wrap[0], wrap[1]),
        )

    def _read_image(self, path, colorspace, owner):
        key = (path, colorspace)
        if key in self._textures:
            return self._textures[key]
        data = read_image(path, colorspace, lambda m: self.warn(f"{owner}: {m}"))
        self._textures[key] = data
        return data

    # --------------------------------------------------------------------- lights
    def _light(self, prim):
        path = str(prim.GetPath())
        api = UsdLux.LightAPI(prim)
        g = lambda a, d=None: self.get(a, d)  # noqa: E731
        intensity = g(api.GetIntensityAttr(), 1.0)
        exposure = g(api.GetExposureAttr(), 0.0)
        color = np.array(g(api.GetColorAttr(), (1, 1, 1)), np.float64)
        diffuse = g(api.GetDiffuseAttr(), 1.0)
        normalize = bool(g(api.GetNormalizeAttr(), False))
        vals = np.array([intensity, exposure, diffuse, *color], np.float64)
        if not np.all(np.isfinite(vals)):
            raise StageError(f"{path}: light intensity/exposure/color/diffuse is NaN or Inf")
        if intensity < 0 or diffuse < 0 or np.any(color < 0):
            raise StageError(
                f"{path}: negative light intensity ({intensity}), diffuse "
                f"({diffuse}) or color ({tuple(color)})"
            )
        rad = intensity * 2.0**exposure * color * diffuse
        if g(api.GetEnableColorTemperatureAttr(), False):
            t = g(api.GetColorTemperatureAttr(), 6500.0)
            rad = rad * np.array(UsdLux.BlackbodyTemperatureAsRgb(float(t)), np.float64)
        if api.GetFiltersRel().GetTargets():
            self.warn(f"{path}: light filters are not supported (ignored)")
        if prim.HasAPI(UsdLux.ShapingAPI):
            sh = UsdLux.ShapingAPI(prim)
            cone = g(sh.GetShapingConeAngleAttr(), 90.0)
            focus = g(sh.GetShapingFocusAttr(), 0.0)
            ies = g(sh.GetShapingIesFileAttr())
            planar = prim.IsA(UsdLux.RectLight) or prim.IsA(UsdLux.DiskLight)
            limit = (
                90.0
                if planar or prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight)
                else 180.0
            )  # cones at least this wide restrict nothing
            if cone < limit or focus != 0.0:
                self.warn(f"{path}: shaping (cone/focus) not supported (ignored)")
            if ies is not None and (ies.path or ""):
                self.warn(f"{path}: IES profiles not supported (ignored)")
        sa = prim.GetAttribute("inputs:shadow:enable")
        if sa and sa.HasAuthoredValue() and not sa.Get():
            self.warn(f"{path}: shadow:enable = false is not supported (shadows are cast)")
        m = np.array(self.xf.GetLocalToWorldTransform(prim))
        m3, c = m[:3, :3], m[3, :3].copy()
        inv_t = np.linalg.inv(m3).T
        if prim.IsA(UsdLux.SphereLight):
            lt = UsdLux.SphereLight(prim)
            r = float(g(lt.GetRadiusAttr(), 0.5))
            sc = np.linalg.norm(m3, axis=1)
            if np.ptp(sc) > 1e-4 * sc.max():
                self.warn(f"{path}: non-uniform scale on a SphereLight; mean scale used")
            rw = r * float(sc.mean())
            if normalize and rw > 0:
                rad = rad / (4.0 * np.pi * rw * rw)
            if g(lt.GetTreatAsPointAttr(), False) or rw <= 0:
                if rw <= 0:
                    self.warn(
                        f"{path}: SphereLight radius 0: treated as a point light of "
                        "radiant intensity = its radiance"
                    )
                    inten = rad
                else:
                    inten = rad * np.pi * rw * rw
                self.lights.append(L.PointLight(path, inten, center=c))
            else:
                self.lights.append(L.SphereLight(path, rad, center=c, radius=rw))
        elif prim.IsA(UsdLux.RectLight) or prim.IsA(UsdLux.DiskLight):
            is_rect = prim.IsA(UsdLux.RectLight)
            n = -(np.array([0, 0, 1.0]) @ inv_t)
            n /= np.linalg.norm(n)
            if is_rect:
                lt = UsdLux.RectLight(prim)
                w = float(g(lt.GetWidthAttr(), 1.0))
                h = float(g(lt.GetHeightAttr(), 1.0))
                ex, ey = 0.5 * w * m3[0], 0.5 * h * m3[1]
                area = 4.0 * np.linalg.norm(np.cross(ex, ey))
                tf = lt.GetTextureFileAttr()
                if tf and tf.HasAuthoredValue() and self.get(tf):
                    self.warn(f"{path}: RectLight texture is not supported (uniform emission)")
            else:
                lt = UsdLux.DiskLight(prim)
                r = float(g(lt.GetRadiusAttr(), 0.5))
                ex, ey = r * m3[0], r * m3[1]
                area = np.pi * np.linalg.norm(np.cross(ex, ey))
            if area <= 0:
                self.warn(f"{path}: zero-area light ignored")
                return
            if normalize:
                rad = rad / area
            cls = L.RectLight if is_rect else L.DiskLight
            self.lights.append(cls(path, rad, center=c, ex=ex, ey=ey, normal=n))
        elif prim.IsA(UsdLux.CylinderLight):
            lt = UsdLux.CylinderLight(prim)
            r = float(g(lt.GetRadiusAttr(), 0.5))
            ln = float(g(lt.GetLengthAttr(), 1.0))
            ax = m3[0]
            hl = 0.5 * ln * np.linalg.norm(ax)
            rw = r * 0.5 * (np.linalg.norm(m3[1]) + np.linalg.norm(m3[2]))
            if g(lt.GetTreatAsLineAttr(), False):
                self.warn(f"{path}: CylinderLight treatAsLine ignored (traced as a cylinder)")
            area = 2 * np.pi * rw * 2 * hl
            if area <= 0:
                self.warn(f"{path}: zero-area light ignored")
                return
            if normalize:
                rad = rad / area
            self.lights.append(
                L.CylinderLight(
                    path, rad, center=c, axis=ax / np.linalg.norm(ax), half_length=hl, radius=rw
                )
            )
        elif prim.IsA(UsdLux.DistantLight):
            lt = UsdLux.DistantLight(prim)
            angle = float(g(lt.GetAngleAttr(), 0.53))
            if not np.isfinite(angle) or angle < 0:
                raise StageError(f"{path}: DistantLight angle {angle} must be >= 0")
            half = math.radians(min(angle, 180.0)) / 2.0
            d = np.array([0, 0, 1.0]) @ m3
            d /= np.linalg.norm(d)
            if half > 0:
                if normalize:  # intensity is the illuminance at normal incidence
                    rad = rad / (np.pi * math.sin(half) ** 2)
            elif not normalize:
                self.warn(
                    f"{path}: DistantLight angle 0 without normalize: intensity taken "
                    "as illuminance at normal incidence"
                )
            self.lights.append(L.DistantLight(path, rad, direction=d, half_angle=half))
        elif prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
            self._dome(prim, path, rad, m3)
        else:
            self.warn(
                f"{path}: light type {prim.GetTypeName()} is not supported (ignored)",
                key=f"lt:{prim.GetTypeName()}",
            )

    def _dome(self, prim, path, rad, m3):
        is1 = prim.IsA(UsdLux.DomeLight_1)
        lt = UsdLux.DomeLight_1(prim) if is1 else UsdLux.DomeLight(prim)
        if lt.GetPortalsRel().GetTargets():
            self.warn(f"{path}: DomeLight portals are not supported (ignored)")
        pole = "Y"
        if is1:
            pa = str(self.get(lt.GetPoleAxisAttr(), "scene"))
            pole = str(UsdGeom.GetStageUpAxis(self.stage)) if pa == "scene" else pa
        p = np.eye(3) if pole == "Y" else np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
        u, _, vt = np.linalg.svd(m3)
        rot = (u @ vt).T @ p  # world = rot @ local (column vectors)
        image = None
        asset = self.get(lt.GetTextureFileAttr())
        if asset is not None and (asset.path or ""):
            fmt = str(self.get(lt.GetTextureFormatAttr(), "automatic"))
            if fmt not in ("automatic", "latlong"):
                self.warn(f"{path}: DomeLight textureFormat {fmt} not supported; uniform colour")
            else:
                image = read_image(
                    asset.resolvedPath or asset.path, "auto", lambda m: self.warn(f"{path}: {m}")
                )
                if image is not None:
                    image = _to_rgb(image)
        self.lights.append(L.DomeLight(path, rad, image=image, rotation=rot))


# ----------------------------------------------------------------------------- helpers


class _Topology:
    """Fan triangulation of a polygon mesh in faceVertex (corner) index space."""

    def __init__(self, counts, idx):
        self.counts = counts
        self.idx = idx
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        ntri = np.maximum(counts - 2, 0)
        face = np.repeat(np.arange(len(counts)), ntri)
        first = np.concatenate([[0], np.cumsum(ntri)[:-1]])
        k = np.arange(len(face)) - first[face]
        s = start[face]
        self.face = face
        self.corners = np.stack([s, s + k + 1, s + k + 2], axis=1)


def _smooth_normals(wp, tri):
    """Area-weighted vertex normals; corners deviating > 45 deg from their face use the face
    normal. wp : (v,3) float64, tri : (t,3) int. returns (t,3,3) float64 unit."""
    a, b, c = wp[tri[:, 0]], wp[tri[:, 1]], wp[tri[:, 2]]
    fn = np.cross(b - a, c - a)  # length = 2 * area
    vn = np.zeros_like(wp)
    for j in range(3):
        np.add.at(vn, tri[:, j], fn)  # once per mesh at load time, not per ray
    fl = np.linalg.norm(fn, axis=1, keepdims=True)
    fu = np.where(fl > 0, fn / np.where(fl > 0, fl, 1), [0, 0, 1.0])
    vl = np.linalg.norm(vn, axis=1, keepdims=True)
    vu = np.where(vl > 0, vn / np.where(vl > 0, vl, 1), 0.0)
    n = vu[tri]  # (t,3,3)
    cosang = np.einsum("tcj,tj->tc", n, fu)
    use_face = cosang < SMOOTH_COS_LIMIT
    return np.where(use_face[..., None], fu[:, None, :], n)


def _channels(out_name: str) -> tuple[int, ...]:
    return {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}.get(out_name, (0, 1, 2))


def _to_rgb(img):
    if img.shape[2] >= 3:
        return img[..., :3]
    return np.repeat(img[..., :1], 3, axis=2)


def _srgb_to_linear(x):
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def read_image(path: str, colorspace: str = "auto", warn=None):
    """Read an image as linear float32 (h, w, c) through OpenImageIO, or None (with a warning).

    colorspace : UsdUVTexture sourceColorSpace: ``raw`` (no conversion), ``sRGB`` (decode) or
    ``auto`` (decode 8-bit images and those tagged sRGB).
    """
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        if warn:
            warn(f"cannot read texture {path} ({oiio.geterror()[:200]}); fallback used")
        return None
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        fmt = str(spec.format)
        tagged = str(spec.get_string_attribute("oiio:ColorSpace", "")).lower()
    finally:
        inp.close()
    if data is None:
        if warn:
            warn(f"cannot decode texture {path}; fallback used")
        return None
    data = np.asarray(data, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    decode = colorspace == "sRGB" or (
        colorspace == "auto"
        and ("srgb" in tagged or fmt in ("uint8", "uint16") and "lin" not in tagged)
    )
    if decode:
        c = min(3, data.shape[2])
        data = data.copy()
        data[..., :c] = _srgb_to_linear(data[..., :c])
    return data


# ----------------------------------------------------------------------------- tessellation


def _tessellate(prim, ex):
    """Local-space (points (v,3), triangles (t,3)) of an implicit gprim, CCW outward."""
    g = ex.get
    if prim.IsA(UsdGeom.Cube):
        s = 0.5 * float(g(UsdGeom.Cube(prim).GetSizeAttr(), 2.0))
        p = np.array([[x, y, z] for x in (-s, s) for y in (-s, s) for z in (-s, s)], float)
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        t = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
        return p, np.array(t, np.int64)
    if prim.IsA(UsdGeom.Sphere):
        r = float(g(UsdGeom.Sphere(prim).GetRadiusAttr(), 1.0))
        return _revolve(
            np.linspace(0, np.pi, 13), lambda th: (r * np.sin(th), -r * np.cos(th)), "Z"
        )
    if prim.IsA(UsdGeom.Capsule):
        c = UsdGeom.Capsule(prim)
        r = float(g(c.GetRadiusAttr(), 0.5))
        h = float(g(c.GetHeightAttr(), 1.0))
        ax = str(g(c.GetAxisAttr(), "Z"))
        th = np.linspace(0, np.pi, 13)
        rr = np.concatenate([r * np.sin(th[:7]), r * np.sin(th[6:])])
        zz = np.concatenate([-0.5 * h - r * np.cos(th[:7]), 0.5 * h - r * np.cos(th[6:])])
        return _revolve_profile(rr, zz, ax)
    if prim.IsA(UsdGeom.Cylinder) or prim.IsA(UsdGeom.Cone):
        is_cyl = prim.IsA(UsdGeom.Cylinder)
        sch = UsdGeom.Cylinder(prim) if is_cyl else UsdGeom.Cone(prim)
        r = float(g(sch.GetRadiusAttr(), 1.0))
        h = float(g(sch.GetHeightAttr(), 2.0))
        ax = str(g(sch.GetAxisAttr(), "Z"))
        rtop = r if is_cyl else 0.0
        return _revolve_profile(
            np.array([0, r, rtop, 0]), np.array([-h / 2, -h / 2, h / 2, h / 2]), ax
        )
    if prim.IsA(UsdGeom.Plane):
        pl = UsdGeom.Plane(prim)
        w = 0.5 * float(g(pl.GetWidthAttr(), 2.0))
        ln = 0.5 * float(g(pl.GetLengthAttr(), 2.0))
        ax = str(g(pl.GetAxisAttr(), "Z"))
        p = np.array([[-w, -ln, 0], [w, -ln, 0], [w, ln, 0], [-w, ln, 0]], float)
        p = _axis(p, ax)
        return p, np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return None, None


def _axis(p, ax):
    if ax == "X":
        return p[:, [2, 0, 1]]
    if ax == "Y":
        return p[:, [1, 2, 0]]
    return p


def _revolve(th, fn, ax):
    r, z = fn(th)
    return _revolve_profile(np.asarray(r), np.asarray(z), ax)


def _revolve_profile(r, z, ax, n_phi=24):
    """Surface of revolution of the profile (r_i, z_i) (bottom to top) about z."""
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    p = np.stack(
        [
            r[:, None] * np.cos(phi)[None, :],
            r[:, None] * np.sin(phi)[None, :],
            np.broadcast_to(z[:, None], (len(r), n_phi)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    tris = []
    for i in range(len(r) - 1):
        for j in range(n_phi):
            a = i * n_phi + j
            b = i * n_phi + (j + 1) % n_phi
            c = (i + 1) * n_phi + j
            d = (i + 1) * n_phi + (j + 1) % n_phi
            tris += [(a, b, d), (a, d, c)]
    t = np.array(tris, np.int64)
    pa, pb, pc = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    good = np.linalg.norm(np.cross(pb - pa, pc - pa), axis=1) > 1e-12
    return _axis(p, ax), t[good]


__all__ = ["Material", "Scene", "Texture", "load_scene", "read_image", "Gf"]
