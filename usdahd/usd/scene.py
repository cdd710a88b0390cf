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
- ``failed`` : prim path -> one-line message for meshes that cannot be used (NaN/Inf points,
  inconsistent topology, a bad lightmap UV primvar, zero area, a non-invertible transform,
  coordinates beyond float32 precision). They are dropped from ``meshes`` (they neither bake
  nor occlude); the pipeline reports them as failed prims while the rest of the stage bakes.

Whole-stage problems raise :class:`usdahd.errors.StageError`: an unreadable file, no meshes,
a composition cycle, metersPerUnit <= 0 or non-finite, a light or emissive material with
negative/NaN/Inf or overflowing emission, a DomeLight texture that cannot be read.

Everything is read at one time (``load_scene(time=...)``, :func:`resolve_time`): the stage's
startTimeCode when anything the bake reads is animated, else ``Usd.TimeCode.Default()``; at
the default time, attributes that only have time samples are read at their first sample (with
a warning). Textures are read through USD's asset resolver (usdz packages). docs/lights.md and
docs/usd-semantics.md list what is honoured and what is warned.
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
from usdahd.usd import normals as N

#: UsdPreviewSurface diffuseColor fallback.
DEFAULT_ALBEDO = (0.18, 0.18, 0.18)
#: Largest emitted radiance (or point-light intensity) accepted from a light or an emissive
#: material. The integrator accumulates radiance x sample weights and squares it for variance
#: estimates in float32 (max 3.4e38): 1e15^2 x 1e6 samples still fits. The sun's radiance is
#: ~1.6e9 W/(m^2 sr), so no physical light comes near.
MAX_RADIANCE = 1e15
#: A mesh is unusable when its bounding-box diagonal spans fewer than this many float32 ulps
#: of its largest world coordinate: the tracer stores float32 positions, so its vertices
#: would snap to a grid coarser than 1/32 of its size (normals, texel positions and ray
#: offsets wrong by > 3%). A 1 cm part passes up to ~5 km from the origin.
MIN_SIZE_ULPS = 32.0
#: A mesh whose diagonal is below this fraction of the scene's extent gets a warning: the
#: tracer offsets ray origins by 1e-5 of the extent (trace.OFFSET_REL), i.e. by more than 10%
#: of such a mesh, so its contact shadows and self-occlusion are unreliable.
SMALL_MESH_REL = 1e-4
#: A triangle is degenerate (dropped, with a warning) when twice its area is below this
#: fraction of its mesh's squared bounding-box diagonal: three collinear float32 points give
#: |cross| ~ 6e-8 x diag^2 from rounding, real slivers are far above 1e-10.
DEGENERATE_AREA_REL = 1e-10
#: Transform 3x3 blocks with |det| below this fraction of the product of their row lengths
#: are treated as non-invertible (zero scale or rank < 3).
SINGULAR_DET_REL = 1e-12
#: Value types accepted for a lightmap UV primvar (2 components per value).
UV_TYPES = ("texCoord2f[]", "texCoord2d[]", "texCoord2h[]", "float2[]", "double2[]", "half2[]")


class _MeshFailure(Exception):
    """A mesh cannot be used; the message names the prim and what to do (internal)."""


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
            if t is None:
                parts.append("")
                continue
            sb = repr((np.round(t.scale, 7).tolist(), np.round(t.bias, 7).tolist()))
            # the texels, not the resolved path: moving or packaging the project (usdz)
            # does not make a bake stale
            parts.append(f"{_digest(t.data.tobytes())}:{sb}:{t.channels}:{t.wrap}")
        return "|".join(parts)


@dataclass
class ComputedNormals:
    """Normals the scene computed for a mesh that authors none (usdahd.usd.normals).

    rule : usdahd.usd.normals.RULE_CREASE or RULE_SMOOTH; values : (c, 3) float32 unit
    object-space normals, one per faceVertexIndices entry (faceVarying); attr : the attribute
    to author them in (``normals``, or ``primvars:normals`` when the mesh has that primvar).
    """

    rule: str
    values: np.ndarray
    attr: str = "normals"


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
    failed: dict[str, str] = field(default_factory=dict)
    #: prim path -> ComputedNormals, for meshes without usable authored normals.
    computed_normals: dict[str, ComputedNormals] = field(default_factory=dict)
    #: the time every attribute was read at (None: Usd.TimeCode.Default()), and whether it was
    #: chosen automatically (resolve_time) rather than given.
    time: float | None = None
    time_auto: bool = True

    @property
    def time_setting(self):
        """The bake time as recorded in ``baked:settings``: a number or ``"default"``."""
        return "default" if self.time is None else self.time

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


def load_scene(
    stage, *, uv_name: str = "st", prims=None, bake_instances: bool = False, time=None
) -> Scene:
    """Extract a :class:`Scene` from a ``Usd.Stage`` or a path to one.

    time : the time every attribute is read at: None (default) picks the stage's
        startTimeCode when anything the bake reads is animated, else the default time (see
        :func:`resolve_time`); a number; or ``"default"`` for ``Usd.TimeCode.Default()``.
    uv_name : lightmap UV primvar read per mesh (``MeshData.uv`` None when absent).
    prims : optional iterable of prim paths; only meshes at or under them are baked (all
        others still occlude). Unknown paths raise StageError.
    bake_instances : also mark instance proxies / PointInstancer copies for baking (off by
        default: their primvars cannot be authored without de-instancing).
    Per-mesh problems do not raise: the mesh goes to ``Scene.failed`` (see the module doc).
    Raises StageError for unreadable or non-USD files, stages without meshes, composition
    cycles, a bad metersPerUnit, and broken lights or emissive materials (each message names
    the prim or file and what to do).
    """
    stage, source = _open(stage)
    mpu = _stage_checks(stage, source)
    warnings: list[str] = []
    t, auto = resolve_time(stage, time, warnings.append)
    ex = _Extractor(stage, uv_name, t)
    for w in warnings:
        ex.warn(w)
    _composition_warnings(stage, source, ex.warn)
    ex.run()
    if not ex.meshes and not ex.failed:
        raise StageError(f"{source}: no visible UsdGeom meshes or gprims to bake or trace")
    failed = dict(ex.failed)
    if prims is not None:
        roots = [str(p) for p in prims]
        for r in roots:
            if not stage.GetPrimAtPath(Sdf.Path(r)):
                raise StageError(f"{source}: --prims path {r} does not exist on the stage")

        def selected(path):
            return any(path == r or path.startswith(r.rstrip("/") + "/") for r in roots)

        for m in ex.meshes:
            m.bake = m.bake and selected(m.path)
        for path in [p for p in failed if not selected(p)]:
            ex.warn(f"{failed.pop(path)} (not selected: dropped from the occluders)")
    ex.size_warnings()
    ex.normals_warnings()
    ex.light_warnings()
    ex.material_warnings()
    ex.link_membership()
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
    if not any(m.bake for m in ex.meshes) and not failed:
        ex.warn("no mesh selected for baking (only occluders found)")
    return Scene(
        meshes=ex.meshes,
        materials=ex.materials,
        lights=ex.lights,
        warnings=ex.warnings,
        meters_per_unit=mpu,
        up_axis=ex.up_axis,
        texcoords=ex.texcoords,
        source=source,
        failed=failed,
        computed_normals=ex.computed_normals,
        time=None if t.IsDefault() else float(t.GetValue()),
        time_auto=auto,
    )


#: Prim types whose time samples never change a bake (the scene reader does not read them).
_UNREAD_TYPES = ("Camera", "RenderSettings", "RenderProduct", "RenderVar", "RenderPass")


def animated_attributes(stage) -> list:
    """Attributes with time samples on the prims the scene reader reads (geometry, xforms,
    visibility, lights, materials and shaders, subsets; cameras and render settings excluded),
    prototypes of scenegraph instances included once. returns [Usd.Attribute]."""
    out = []
    roots = [stage.GetPseudoRoot(), *stage.GetPrototypes()]
    for root in roots:
        for prim in Usd.PrimRange(root):
            if prim.GetTypeName() in _UNREAD_TYPES:
                continue
            for attr in prim.GetAttributes():
                if attr.GetNumTimeSamples() > 0:
                    out.append(attr)
    return out


def parse_time(value):
    """A ``--time`` value: None, ``"default"`` or a finite number (str or float) -> None,
    "default" or float. Raises ValueError with the accepted forms."""
    if value is None or value == "default":
        return value
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"--time {value!r}: expected a time code (a number such as 1 or 101.5) or 'default'"
        ) from None
    if not math.isfinite(t):
        raise ValueError(f"--time {value!r}: the time code must be finite")
    return t


def _start_time_code(stage):
    """startTimeCode of the strongest layer of the root layer stack that authors one, or None.

    USD reads it from the root (or session) layer only; a bake's override layer sublayers the
    source without a timeline of its own, so its sublayers count too (the validator opens the
    override layer and must find the time the bake used)."""
    if stage.HasAuthoredMetadata("startTimeCode"):
        return float(stage.GetStartTimeCode())
    for layer in stage.GetLayerStack(includeSessionLayers=True):
        if layer.HasStartTimeCode():
            return float(layer.startTimeCode)
    return None


def resolve_time(stage, time=None, warn=None):
    """The time the bake reads the stage at, and whether it was chosen automatically.

    time : None (automatic), "default" or a number (see :func:`parse_time`).
    Automatic: the stage's startTimeCode when any attribute the bake reads has time samples
    (the first of their samples if startTimeCode is not authored), else the default time. A
    warning names the animated attributes, and one per attribute whose default value and
    time samples disagree at the chosen time (a default plus samples: USD renderers show the
    sample at a numeric time, the default only at the default time).
    returns (Usd.TimeCode, auto: bool).
    """
    warn = warn or (lambda m: None)
    time = parse_time(time)
    anim = animated_attributes(stage)
    auto = time is None
    if time == "default":
        t = Usd.TimeCode.Default()
    elif time is not None:
        t = Usd.TimeCode(time)
    elif not anim:
        t = Usd.TimeCode.Default()
    elif _start_time_code(stage) is not None:
        t = Usd.TimeCode(_start_time_code(stage))
    else:
        first = min(a.GetTimeSamples()[0] for a in anim)
        t = Usd.TimeCode(first)
        warn(
            f"the stage has time samples but no startTimeCode: baked at the first sample, time "
            f"{first:g} (author startTimeCode or pass --time)"
        )
    when = "the default time" if t.IsDefault() else f"time {t.GetValue():g}"
    if anim:
        names = [str(a.GetPath()) for a in anim[:4]]
        more = f" and {len(anim) - 4} more" if len(anim) > 4 else ""
        start = _start_time_code(stage) is not None and not t.IsDefault()
        why = " (the stage's startTimeCode)" if auto and start else ""
        hint = ""
        if t.IsDefault():
            hint = (
                ": animated attributes use their default value, or their schema fallback if "
                "they have none"
            )
        warn(
            f"{len(anim)} attributes have time samples ({', '.join(names)}{more}): baked at "
            f"{when}{why}{hint}; pass --time to bake another time"
        )
    for a in anim:
        # a default authored next to the samples (in any layer of the stack)
        if not any(spec.HasDefaultValue() for spec in a.GetPropertyStack(t)):
            continue
        d = a.Get(Usd.TimeCode.Default())
        v = a.Get(Usd.TimeCode(a.GetTimeSamples()[0]) if t.IsDefault() else t)
        try:
            same = bool(d == v)
        except Exception:  # pragma: no cover - exotic value types
            same = False
        if not same:
            used = "the default" if t.IsDefault() else "the time sample"
            warn(
                f"{a.GetPath()}: its default value and its time samples disagree; {used} is "
                f"used (baked at {when}); remove the one you do not mean"
            )
    return t, auto


def _stage_checks(stage, source) -> float:
    """Stage metadata the bake depends on; returns metersPerUnit. Raises StageError."""
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (math.isfinite(mpu) and mpu > 0):
        raise StageError(
            f"{source}: stage metadata metersPerUnit = {mpu:g} must be a positive finite "
            "number (1 = metres, 0.01 = centimetres); fix it in the root layer"
        )
    return mpu


def _one_line(text: str, limit: int = 300) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _composition_warnings(stage, source, warn) -> None:
    """Composition errors USD recovered from: cycles raise StageError, the rest warn."""
    try:
        errors = stage.GetCompositionErrors()
    except AttributeError:  # pragma: no cover - USD < 23.11
        return
    for err in errors:
        name = type(err).__name__
        msg = _one_line(err)
        if "Cycle" in name:
            raise StageError(
                f"{source}: composition cycle ({msg}); remove the reference, payload or "
                "sublayer that points back to a layer already being composed"
            )
        warn(f"{source}: composition error, that part of the scene is missing: {msg}")


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
    def __init__(self, stage, uv_name, time=None):
        self.stage = stage
        self.uv_name = uv_name
        self.time = Usd.TimeCode.Default() if time is None else time
        self.xf = UsdGeom.XformCache(self.time)
        self.when = (
            "the default time" if self.time.IsDefault() else f"time {self.time.GetValue():g}"
        )
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
        self._tc_transforms: dict = {}  # derived texcoord name -> (primvar, A (2,2), b (2,))
        self.failed: dict[str, str] = {}
        self.computed_normals: dict[str, ComputedNormals] = {}
        self.unauthored_scheme: list[str] = []
        self.unauthored_intensity: list[str] = []
        self.computed_instanced = 0
        self.unhonoured: dict[str, list[str]] = {}  # UsdPreviewSurface input -> materials
        self._link_queries: list = []
        self.link_paths: list[str] = []  # per mesh: the prim path collections are queried by
        self._instancer: str | None = None  # the PointInstancer being expanded
        self.up_axis = str(UsdGeom.GetStageUpAxis(stage))
        if self.up_axis not in ("Y", "Z"):
            self.warn(
                f"stage metadata upAxis = {self.up_axis!r} is not 'Y' or 'Z'; assuming 'Y' "
                "(fix the upAxis metadata in the root layer)"
            )
            self.up_axis = "Y"

    def fail(self, path: str, msg: str, bakeable: bool, key: str | None = None) -> None:
        """A mesh is unusable: a failed prim if it would be baked, else a warning (once per
        ``key``: one warning for all instances of a prototype)."""
        if bakeable:
            self.failed[path] = msg
        else:
            self.warn(f"{msg} (occluder dropped; same for its other instances)", key=key)

    def size_warnings(self) -> None:
        """One warning naming the baked meshes too small for the tracer's ray offsets
        (SMALL_MESH_REL of the scene's extent)."""
        if not self.meshes:
            return
        lo = np.min([m.points.min(axis=0) for m in self.meshes], axis=0)
        hi = np.max([m.points.max(axis=0) for m in self.meshes], axis=0)
        extent = float(np.linalg.norm(hi - lo))
        small = []
        for m in self.meshes:
            d = float(np.linalg.norm(m.points.max(axis=0) - m.points.min(axis=0)))
            if m.bake and d < SMALL_MESH_REL * extent:
                small.append(f"{m.path} ({d:.3g} units)")
        if small:
            more = f" and {len(small) - 5} more" if len(small) > 5 else ""
            self.warn(
                f"{len(small)} baked meshes are very small, under {SMALL_MESH_REL:g} of the "
                f"scene's extent {extent:.3g}: {', '.join(small[:5])}{more}; ray offsets exceed "
                "10% of their size, so their lighting is approximate (a huge ground plane or a "
                "stray far-away prim inflates the extent)"
            )

    def normals_warnings(self) -> None:
        """One warning per stage naming the meshes whose normals were computed, and one for
        those that leave subdivisionScheme unauthored (see docs/schema.md, Normals)."""

        def names(paths):
            more = f" and {len(paths) - 3} more" if len(paths) > 3 else ""
            return ", ".join(paths[:3]) + more

        comp = sorted(self.computed_normals)
        if comp or self.computed_instanced:
            rules = sorted({self.computed_normals[p].rule for p in comp}) or [N.RULE_CREASE]
            copies = (
                f" and {self.computed_instanced} instanced copies"
                if self.computed_instanced
                else ""
            )
            self.warn(
                f"{len(comp)} meshes{copies} author no normals ({names(comp)}): normals "
                f"computed by the {' / '.join(rules)} rule (crease angle "
                f"{N.CREASE_ANGLE_DEG:g} degrees, angle-weighted; smooth for catmullClark/loop) "
                "and authored into the output layer for baked meshes; author normals to choose "
                "the shading yourself (docs/schema.md#normals)",
                key="normals:computed",
            )
        if self.unauthored_scheme:
            p = sorted(set(self.unauthored_scheme))
            self.warn(
                f"{len(p)} meshes leave subdivisionScheme unauthored ({names(p)}): USD's "
                "fallback is catmullClark (a subdividing renderer smooths them and ignores "
                "their authored normals), but usdahd bakes the polygons as they are, with their "
                "normals or, without normals, crease-angle normals (as RTX renders unsubdivided "
                'meshes without normals faceted); author subdivisionScheme = "none" (or '
                '"catmullClark" for smooth normals) to say which you mean',
                key="normals:scheme",
            )

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
        purposes = {}  # prim path -> UsdGeom.Imageable.PurposeInfo, for the children
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
                        f"{self.when} ({vis})"
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
                self._point_instancer(prim)
                it.PruneChildren()
                continue
            if prim.HasAPI(UsdLux.LightAPI):
                self._light(prim)
            elif prim.IsA(UsdLux.PortalLight) or prim.IsA(UsdLux.PluginLight):
                self.warn(f"{prim.GetPath()}: {prim.GetTypeName()} is not supported (ignored)")
            if prim.IsA(UsdGeom.Gprim):
                m = np.array(self.xf.GetLocalToWorldTransform(prim))
                path, inst = str(prim.GetPath()), prim.IsInstanceProxy()
                if prim.IsA(UsdGeom.Mesh):
                    self._guarded(self._mesh, prim, m, path, inst)
                else:
                    self._guarded(self._implicit, prim, m, path, inst)

    def _guarded(self, fn, prim, xform, path, instanced):
        """Run a mesh/gprim extractor; per-mesh problems become failures, not exceptions."""
        try:
            fn(prim, xform, path, instanced)
        except _MeshFailure as exc:
            bakeable = prim.IsA(UsdGeom.Mesh) and not instanced
            src = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
            self.fail(path, str(exc), bakeable, key=f"fail:{src.GetPath()}")

    # --------------------------------------------------------------------- meshes
    def _mesh(self, prim, xform, path, instanced, bake=True):
        mesh = UsdGeom.Mesh(prim)
        pts = self.get(mesh.GetPointsAttr())
        counts = self.get(mesh.GetFaceVertexCountsAttr())
        idx = self.get(mesh.GetFaceVertexIndicesAttr())
        n_pts = 0 if pts is None else len(pts)
        n_faces = 0 if counts is None else len(counts)
        if n_pts == 0 and n_faces == 0:
            self.warn(f"{path}: empty mesh (no points, no faces): skipped")
            return
        if n_faces == 0 or idx is None or len(idx) == 0:
            self.warn(f"{path}: mesh has {n_pts} points but no faces: skipped")
            return
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(idx, dtype=np.int64)
        bad = ~np.all(np.isfinite(pts), axis=1)
        if bad.any():
            first = int(np.argmax(bad))
            kind = "NaN" if np.isnan(pts[bad]).any() else "Inf"
            raise _MeshFailure(
                f"{path}: points contain {kind} ({int(bad.sum())} of {len(pts)}, first at "
                f"index {first}: {tuple(pts[first].tolist())}); fix or re-export the geometry"
            )
        if np.any(counts < 0):
            raise _MeshFailure(
                f"{path}: faceVertexCounts has negative entries; fix or re-export the geometry"
            )
        if counts.sum() != len(idx):
            raise _MeshFailure(
                f"{path}: faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                f"{len(idx)} entries; fix or re-export the geometry"
            )
        if idx.min() < 0 or idx.max() >= len(pts):
            raise _MeshFailure(
                f"{path}: faceVertexIndices out of range [0, {len(pts)}) "
                f"(min {int(idx.min())}, max {int(idx.max())}); fix or re-export the geometry"
            )
        if np.any(counts < 3):
            self.warn(f"{path}: {int((counts < 3).sum())} faces with fewer than 3 vertices ignored")
            if not np.any(counts >= 3):
                self.warn(f"{path}: no face with 3 or more vertices: skipped")
                return
        left = self.get(mesh.GetOrientationAttr()) == UsdGeom.Tokens.leftHanded
        sda = mesh.GetSubdivisionSchemeAttr()
        sd = str(self.get(sda)) if sda.HasAuthoredValue() else None
        if sd not in (None, UsdGeom.Tokens.none):
            self.warn(
                f"{path}: subdivisionScheme {sd}: the control cage is baked as is", key="subdiv"
            )
        try:
            face_mat = self._face_materials(prim, len(counts), path)
        except _SubsetError as exc:
            raise _MeshFailure(str(exc)) from None
        ctx = _Topology(counts, idx)
        if sd is None:
            self.unauthored_scheme.append(path)
        self._emit(prim, xform, path, pts, ctx, left, face_mat, instanced, bake, scheme=sd)

    def _emit(
        self,
        prim,
        xform,
        path,
        pts,
        topo,
        left,
        face_mat,
        instanced,
        bake,
        implicit=False,
        scheme=None,
    ):
        m3 = xform[:3, :3]
        _check_transform(xform, path)
        flip = left ^ (np.linalg.det(m3) < 0)
        corners = topo.corners.copy()
        if flip:
            corners = corners[:, [0, 2, 1]]
        wp = pts @ m3 + xform[3, :3]
        if not np.all(np.isfinite(wp)):
            raise _MeshFailure(
                f"{path}: world-space points overflow to Inf (transform scale too large); "
                "fix the transform"
            )
        _check_precision(wp, path)
        corners, keep = _drop_degenerate(wp, topo, corners, path, self.warn)
        if len(corners) == 0:
            raise _MeshFailure(
                f"{path}: zero surface area (every triangle is degenerate: points coincide or "
                "lie on one line); fix or delete the mesh"
            )
        face = topo.face[keep]
        tri = topo.idx[corners].astype(np.int32)
        normals = None
        if not implicit:
            normals = self._authored_normals(prim, topo, corners, m3, path)
        computed = None
        if normals is None:
            rule = N.rule_for_scheme(scheme)
            fv = N.compute_normals(pts, topo.counts, topo.idx, rule, left_handed=left)
            normals = N.to_world(fv[corners], m3)
            if not implicit and not instanced:
                computed = ComputedNormals(rule, fv, self._normals_attr(prim))
            elif not implicit:
                self.computed_instanced += 1  # copies of a prototype: counted, not authored
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
                    base, a, b = self._tc_transforms.get(name, (name, None, None))
                    tc = (
                        uv
                        if base == self.uv_name
                        else self._primvar2(prim, base, topo, corners, path)
                    )
                    if tc is not None and a is not None:  # UsdTransform2d (affine: exact)
                        tc = (tc.astype(np.float64) @ a.T + b).astype(np.float32)
                    if tc is None:
                        self.warn(
                            f"{path}: material texture reads primvar '{base}' which the "
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
            material=face_mat[face].astype(np.int32),
            face=face.astype(np.int32),
            corner=corners.astype(np.int32),
            bake=bake and not instanced and not implicit,
        )
        self.meshes.append(md)
        self.link_paths.append(self._instancer or str(prim.GetPath()))
        if computed is not None:
            self.computed_normals[path] = computed
        self.texcoords.append(texcoords)
        self.instanced.append(bool(instanced) and not implicit)
        self.implicit[id(md)] = implicit

    def _primvar_corner_values(self, pv, topo, path, width, strict=False):
        """Expand a primvar to per faceVertex (corner) values (len(idx), width) or None.

        strict (the lightmap UV set): a wrong type, interpolation, length or index raises
        _MeshFailure; otherwise (normals, material texcoords) those warn and return None,
        except a too-short array, which always fails the mesh.
        """
        name = pv.GetName()

        def bad(msg):
            if strict:
                raise _MeshFailure(f"{path}: {msg}")
            self.warn(f"{path}: {msg} (ignored)")
            return None

        tname = str(pv.GetTypeName())
        if strict and tname not in UV_TYPES:
            return bad(
                f"lightmap UV primvar {name} is {tname}, expected texCoord2f[] (or float2[]); "
                "re-author it as texCoord2f[] or pick another UV set with --uv"
            )
        if strict and pv.GetInterpolation() in (UsdGeom.Tokens.uniform, UsdGeom.Tokens.constant):
            return bad(
                f"lightmap UV primvar {name} has {pv.GetInterpolation()} interpolation (one UV "
                "per face or per mesh); a lightmap needs faceVarying or vertex UVs: re-author "
                "it or pick another UV set with --uv"
            )
        t = self.time
        if pv.GetAttr().Get(t) is None and pv.GetAttr().GetNumTimeSamples():
            t = Usd.TimeCode(pv.GetAttr().GetTimeSamples()[0])
        raw = pv.GetAttr().Get(t)
        if raw is None or len(raw) == 0:
            return None
        if pv.IsIndexed():
            ind = pv.GetIndices(t)
            ind = np.asarray(ind if ind is not None else [], np.int64)
            if len(ind) and (ind.min() < 0 or ind.max() >= len(raw)):
                return bad(
                    f"primvar {name} indices out of range [0, {len(raw)}) (min {int(ind.min())},"
                    f" max {int(ind.max())}); fix {name}:indices"
                )
        vals = pv.ComputeFlattened(t)
        if vals is None or len(vals) == 0:
            return None
        try:
            v = np.asarray(vals, dtype=np.float64).reshape(len(vals), -1)
        except (TypeError, ValueError):
            return bad(f"primvar {name} of type {tname} is not numeric")
        if v.shape[1] != width:
            return bad(f"primvar {name} ({tname}) has {v.shape[1]} components, expected {width}")
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
            raise _MeshFailure(
                f"{path}: primvar {name} ({interp}) has {len(v)} values, needs {need}; "
                "fix or re-export it"
            )
        return v[sel]

    def _primvar2(self, prim, name, topo, corners, path):
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if not pv or not pv.HasValue():
            return None
        strict = name == self.uv_name
        v = self._primvar_corner_values(pv, topo, path, 2, strict=strict)
        if v is None:
            return None
        v = v[corners]
        bad = ~np.isfinite(v)
        if bad.any():
            kind = "NaN" if np.isnan(v[bad]).any() else "Inf"
            msg = f"{path}: primvar {pv.GetName()} contains {kind} ({int(bad.sum())} values)"
            if strict:
                raise _MeshFailure(f"{msg}; fix the UVs or pick another UV set with --uv")
            self.warn(f"{msg}: texture sampled at 0 there")
            v = np.where(bad, 0.0, v)
        return v.astype(np.float32)

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
        v = v[corners]
        ln = np.linalg.norm(v, axis=-1)
        if not np.all(np.isfinite(v)) or np.any(ln < 1e-12):
            self.warn(f"{path}: degenerate or NaN authored normals; normals recomputed")
            return None
        return N.to_world(v, m3)

    @staticmethod
    def _normals_attr(prim) -> str:
        """The attribute a renderer reads normals from: ``primvars:normals`` when the mesh has
        one (it wins over ``normals``), else ``normals``; the bake authors computed ones there."""
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        return "primvars:normals" if pv and pv.HasAuthoredValue() else "normals"

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
                    rel, _ = self.xf.ComputeRelativeTransform(p, root)
                    local_root = np.array(self.xf.GetLocalTransformation(root)[0])
                    m = np.array(rel) @ local_root @ inst_m
                    name = f"{path}/instance_{i}{str(p.GetPath())[len(str(root.GetPath())) :]}"
                    fn = self._mesh if p.IsA(UsdGeom.Mesh) else self._implicit
                    self._instancer = path
                    try:
                        self._guarded(fn, p, m, name, True)
                    finally:
                        self._instancer = None

    # --------------------------------------------------------------------- materials
    def _face_materials(self, prim, n_faces, path):
        api = UsdShade.MaterialBindingAPI(prim)
        # A baker renders final quality: the "full" binding, else the all-purpose one.
        base = self._material_index(api.ComputeBoundMaterial(UsdShade.Tokens.full)[0], prim)
        fm = np.full(n_faces, base, np.int32)
        for subset in api.GetMaterialBindSubsets():
            ind = self.get(subset.GetIndicesAttr())
            if ind is None or len(ind) == 0:
                continue
            ind = np.asarray(ind, np.int64)
            if ind.min() < 0 or ind.max() >= n_faces:
                raise _SubsetError(
                    f"{path}: GeomSubset {subset.GetPath()} indices out of range [0, {n_faces}); "
                    "fix the subset"
                )
            sub = UsdShade.MaterialBindingAPI(subset.GetPrim())
            mat = sub.ComputeBoundMaterial(UsdShade.Tokens.full)[0]
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
        self._check_material(out)
        self._metallic(shader, out)
        self._unhonoured_inputs(shader, name)
        if tc_names:
            out.texcoord = tc_names[0]
            if len(set(tc_names)) > 1:
                self.warn(
                    f"{name}: textures read different primvars or UsdTransform2d "
                    f"{sorted(set(tc_names))}; using '{tc_names[0]}' for all"
                )
        return out

    def _metallic(self, shader, out: Material) -> None:
        """UsdPreviewSurface metallic workflow: a metal has no diffuse lobe, so the diffuse
        albedo is diffuseColor x (1 - metallic) (constant metallic; a metallic texture is
        warned and ignored). The specular workflow (useSpecularWorkflow = 1) ignores metallic."""
        wf = shader.GetInput("useSpecularWorkflow")
        if wf and int(self.get(wf.GetAttr(), 0) or 0) == 1:
            return
        inp = shader.GetInput("metallic")
        if not inp:
            return
        if inp.HasConnectedSource():
            self.unhonoured.setdefault("metallic (connected)", []).append(out.name)
            return
        m = self.get(inp.GetAttr(), 0.0)
        m = float(np.ravel(np.asarray(m, np.float64))[0]) if m is not None else 0.0
        if not math.isfinite(m):
            raise StageError(f"{out.name}: UsdPreviewSurface inputs:metallic is {m}: fix it")
        if not 0.0 <= m <= 1.0:
            self.warn(f"{out.name}: metallic {m:g} outside [0, 1]; clamped")
            m = min(max(m, 0.0), 1.0)
        if m == 0.0:
            return
        k = np.float32(1.0 - m)
        out.albedo = (out.albedo * k).astype(np.float32)
        if out.albedo_tex is not None:
            tex = out.albedo_tex
            tex.scale = tex.scale.copy()
            tex.bias = tex.bias.copy()
            tex.scale[:3] *= k
            tex.bias[:3] *= k

    def _unhonoured_inputs(self, shader, name) -> None:
        """Record the UsdPreviewSurface inputs that change the diffuse response and that the
        baker ignores (a Lambertian bake of the base layer); see material_warnings."""
        neutral = {
            "normal": (0.0, 0.0, 1.0),
            "displacement": 0.0,
            "occlusion": 1.0,
            "clearcoat": 0.0,
        }
        for inp_name, value in neutral.items():
            inp = shader.GetInput(inp_name)
            if not inp:
                continue
            if inp.HasConnectedSource():
                self.unhonoured.setdefault(f"{inp_name} (connected)", []).append(name)
                continue
            if not inp.GetAttr().HasAuthoredValue():
                continue
            v = self.get(inp.GetAttr())
            if v is not None and not np.allclose(np.asarray(v, np.float64), value):
                self.unhonoured.setdefault(f"{inp_name} = {_fmt(v)}", []).append(name)

    def material_warnings(self) -> None:
        """One warning per stage and unhonoured UsdPreviewSurface input, naming materials."""
        for what, mats in sorted(self.unhonoured.items()):
            mats = sorted(set(mats))
            more = f" and {len(mats) - 3} more" if len(mats) > 3 else ""
            fix = (
                " (the diffuse albedo is not reduced where the texture is metallic; author a "
                "constant metallic)"
                if what.startswith("metallic")
                else " (the bake shades the flat diffuse base layer)"
            )
            self.warn(
                f"UsdPreviewSurface {what} is not honoured by the bake in {len(mats)} "
                f"materials ({', '.join(mats[:3])}{more}){fix}",
                key=f"unhonoured:{what}",
            )

    def _check_material(self, out: Material) -> None:
        """NaN/Inf or negative emission is a broken light source (StageError); non-physical
        albedo and opacity are clamped to [0, 1] with a warning."""
        name = out.name
        values = {
            "emissiveColor": out.emission,
            "diffuseColor": out.albedo,
            "opacity": np.array([out.opacity]),
            "opacityThreshold": np.array([out.opacity_threshold]),
        }
        for key, v in values.items():
            v = np.asarray(v, np.float64)
            if not np.all(np.isfinite(v)):
                kind = "NaN" if np.isnan(v).any() else "Inf"
                raise StageError(
                    f"{name}: UsdPreviewSurface inputs:{key} is {kind} ({_fmt(v)}); it would "
                    "spoil every prim that sees this material: fix the material"
                )
        em = np.asarray(out.emission, np.float64)
        if np.any(em < 0) or em.max(initial=0.0) > MAX_RADIANCE:
            raise StageError(
                f"{name}: UsdPreviewSurface inputs:emissiveColor {_fmt(em)} must be in "
                f"[0, {MAX_RADIANCE:.0e}]: fix the material"
            )
        alb = np.asarray(out.albedo, np.float64)
        if np.any(alb < 0) or np.any(alb > 1):
            clamped = np.clip(alb, 0.0, 1.0)
            self.warn(
                f"{name}: inputs:diffuseColor {_fmt(alb)} is non-physical (outside [0, 1]: "
                f"energy would grow with every bounce); clamped to {_fmt(clamped)}"
            )
            out.albedo = clamped.astype(np.float32)
        for key in ("opacity", "opacity_threshold"):
            v = float(getattr(out, key))
            if not 0.0 <= v <= 1.0:
                self.warn(f"{name}: {key} {v:g} outside [0, 1]; clamped")
                setattr(out, key, min(max(v, 0.0), 1.0))

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
        tc_names.append(self._texcoord_name(tex_shader, mat_name))
        return fb, tex

    def _texcoord_name(self, tex_shader, mat_name) -> str:
        """The texcoord a UsdUVTexture reads: the primvar of its UsdPrimvarReader_float2,
        optionally through a UsdTransform2d (then a derived name ``<primvar>@<transform>``
        whose values :meth:`_emit` computes: out = rotate(scale * in) + translation)."""
        st = tex_shader.GetInput("st")
        if not st or not st.HasConnectedSource():
            return "st"
        node = UsdShade.Shader(st.GetConnectedSources()[0][0].source.GetPrim())
        nid = node.GetIdAttr().Get() if node.GetIdAttr() else None
        xf = None
        if nid == "UsdTransform2d":

            def val(n, d):
                i = node.GetInput(n)
                v = self.get(i.GetAttr()) if i else None
                return np.array(d if v is None else v, np.float64).reshape(-1)

            scale, rot, trans = (
                val("scale", (1, 1)),
                val("rotation", 0.0),
                val("translation", (0, 0)),
            )
            if not (np.all(np.isfinite(scale)) and np.all(np.isfinite(rot))):
                raise StageError(f"{node.GetPath()}: UsdTransform2d inputs are NaN/Inf: fix it")
            xf = (float(scale[0]), float(scale[1]), float(rot[0]), float(trans[0]), float(trans[1]))
            inp = node.GetInput("in")
            if not inp or not inp.HasConnectedSource():
                self.warn(
                    f"{mat_name}: {node.GetPath()} (UsdTransform2d) has no connected 'in'; "
                    "the texture reads primvar 'st'"
                )
                reader = None
            else:
                reader = UsdShade.Shader(inp.GetConnectedSources()[0][0].source.GetPrim())
        else:
            reader = node
        var = "st"
        if reader:
            vn = reader.GetInput("varname")
            if vn:
                var = str(self.get(vn.GetAttr(), "st"))
        if xf is None or xf == (1.0, 1.0, 0.0, 0.0, 0.0):
            return var
        sx, sy, r, tx, ty = (f"{v:.9g}" for v in xf)
        name = f"{var}@scale({sx},{sy})rotate({r})translate({tx},{ty})"
        c, s_ = math.cos(math.radians(xf[2])), math.sin(math.radians(xf[2]))
        a = np.array([[c, -s_], [s_, c]]) @ np.diag([xf[0], xf[1]])
        self._tc_transforms[name] = (var, a, np.array([xf[3], xf[4]]))
        return name

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
        fattr = fin.GetAttr()
        file_cs = str(fattr.GetColorSpace()) if fattr.HasColorSpace() else ""
        data = self._read_image(path, cs, mat_name, file_cs)
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

    def _read_image(self, path, colorspace, owner, file_colorspace=""):
        key = (path, colorspace, file_colorspace)
        if key in self._textures:
            return self._textures[key]
        data = read_image(
            path, colorspace, lambda m: self.warn(f"{owner}: {m}"), file_colorspace=file_colorspace
        )
        if data is not None:
            data = _sanitize_image(data, f"{owner}: {path}", self.warn)
        self._textures[key] = data
        return data

    # --------------------------------------------------------------------- lights
    def _light(self, prim):
        path = str(prim.GetPath())
        api = UsdLux.LightAPI(prim)
        g = lambda a, d=None: self.get(a, d)  # noqa: E731
        intensity = g(api.GetIntensityAttr(), 1.0)
        if not api.GetIntensityAttr().HasAuthoredValue():
            self.unauthored_intensity.append(path)
        exposure = g(api.GetExposureAttr(), 0.0)
        color = np.array(g(api.GetColorAttr(), (1, 1, 1)), np.float64)
        diffuse = g(api.GetDiffuseAttr(), 1.0)
        normalize = bool(g(api.GetNormalizeAttr(), False))
        named = {
            "inputs:intensity": np.array([intensity], np.float64),
            "inputs:exposure": np.array([exposure], np.float64),
            "inputs:color": color,
            "inputs:diffuse": np.array([diffuse], np.float64),
        }
        for name, v in named.items():
            if v.shape[-1:] != (3,) and name == "inputs:color":
                raise StageError(f"{path}: {name} must be a color3f, got {tuple(v.tolist())}")
            if not np.all(np.isfinite(v)):
                kind = "NaN" if np.isnan(v).any() else "Inf"
                raise StageError(
                    f"{path}: light {name} is {kind} ({_fmt(v)}); a broken light spoils every "
                    "prim's bake: fix it or deactivate the light"
                )
            if name != "inputs:exposure" and np.any(v < 0):
                raise StageError(
                    f"{path}: light {name} is negative ({_fmt(v)}); lights cannot emit negative "
                    "energy: fix it or deactivate the light"
                )
        with np.errstate(over="ignore"):
            gain = np.exp2(np.float64(exposure))
        rad = intensity * gain * color * diffuse
        self._emission = (float(intensity), float(exposure))
        if not np.any(rad > 0):
            self.warn(
                f"{path}: light emits nothing (inputs:intensity {float(intensity):g}, "
                f"color {_fmt(color)}, diffuse {float(diffuse):g}): ignored"
            )
            return
        if not np.all(np.isfinite(rad)) or rad.max() > MAX_RADIANCE:
            raise StageError(
                f"{path}: inputs:intensity {float(intensity):g} x 2^inputs:exposure "
                f"{float(exposure):g} = {float(np.max(rad)):.3g} overflows the baker's range "
                f"(max {MAX_RADIANCE:.0e}); lower the exposure or intensity"
            )
        if g(api.GetEnableColorTemperatureAttr(), False):
            t = g(api.GetColorTemperatureAttr(), 6500.0)
            if not (math.isfinite(t) and t > 0):
                raise StageError(
                    f"{path}: light inputs:colorTemperature {t:g} must be a positive finite "
                    "temperature in kelvin: fix it or disable enableColorTemperature"
                )
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
        if sa and sa.HasAuthoredValue() and not self.get(sa, True):
            self.warn(f"{path}: shadow:enable = false is not supported (shadows are cast)")
        self._shadow_warnings(prim, path)
        self._current_light = prim
        m = np.array(self.xf.GetLocalToWorldTransform(prim))
        if not np.all(np.isfinite(m)):
            raise StageError(
                f"{path}: light world transform contains NaN/Inf; fix the xformOps of the light "
                "or its ancestors"
            )
        m3, c = m[:3, :3], m[3, :3].copy()
        rows = np.linalg.norm(m3, axis=1)
        if rows.min() == 0.0 or abs(np.linalg.det(m3)) <= SINGULAR_DET_REL * np.prod(rows):
            self.warn(
                f"{path}: light transform is not invertible (zero scale): the light has no "
                "size or direction and is ignored"
            )
            return
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
                self._add_light(L.PointLight(path, inten, center=c))
            else:
                self._add_light(L.SphereLight(path, rad, center=c, radius=rw))
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
            self._add_light(cls(path, rad, center=c, ex=ex, ey=ey, normal=n))
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
            self._add_light(
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
            self._add_light(L.DistantLight(path, rad, direction=d, half_angle=half))
        elif prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
            self._dome(prim, path, rad, m3)
        else:
            self.warn(
                f"{path}: light type {prim.GetTypeName()} is not supported (ignored)",
                key=f"lt:{prim.GetTypeName()}",
            )

    def _add_light(self, light):
        """Append a light after checking its final (area-normalized) emission."""
        peak = float(np.max(light.radiance))
        img = getattr(light, "image", None)
        if img is not None and img.size:
            peak *= float(np.max(img))
        if not np.isfinite(peak) or peak > MAX_RADIANCE:
            i, e = getattr(self, "_emission", (float("nan"), float("nan")))
            raise StageError(
                f"{light.path}: emitted radiance {peak:.3g} (inputs:intensity {i:g}, exposure "
                f"{e:g}, after normalize/area) overflows the baker's range (max "
                f"{MAX_RADIANCE:.0e}); lower the exposure or intensity, or enlarge the light"
            )
        prim = getattr(self, "_current_light", None)
        if prim is not None and str(prim.GetPath()) == light.path:
            self._link_queries.append((light, prim))
        self.lights.append(light)

    def _shadow_warnings(self, prim, path) -> None:
        """ShadowAPI inputs that change what a renderer shows and that the baker ignores."""
        col = prim.GetAttribute("inputs:shadow:color")
        if col and col.HasAuthoredValue():
            c = np.asarray(self.get(col, (0, 0, 0)), np.float64)
            if np.any(c != 0):
                self.warn(
                    f"{path}: inputs:shadow:color {_fmt(c)} is not supported: shadows are "
                    "black (physically correct); remove it or bake with a fill light"
                )
        for name, neutral in (("inputs:shadow:distance", -1.0), ("inputs:shadow:falloff", -1.0)):
            a = prim.GetAttribute(name)
            if a and a.HasAuthoredValue() and float(self.get(a, neutral)) != neutral:
                self.warn(f"{path}: {name} is not supported (shadows reach any distance)")

    def link_membership(self) -> None:
        """Per light, the baked-scene mesh indices its ``collection:lightLink`` includes
        (``light.lit_meshes``) and whose shadows its ``collection:shadowLink`` includes
        (``light.shadow_meshes``): (k,) int32 sorted, or None when the collection includes
        every mesh (the default). Read through Usd.CollectionAPI membership queries; copies
        of a PointInstancer are queried by the instancer's path. Not yet used by the
        integrators (docs/lights.md)."""
        if not self._link_queries:
            return
        paths = [self.link_paths[i] for i in range(len(self.meshes))]
        for light, prim in self._link_queries:
            api = UsdLux.LightAPI(prim)
            for attr, coll in (
                ("lit_meshes", api.GetLightLinkCollectionAPI()),
                ("shadow_meshes", api.GetShadowLinkCollectionAPI()),
            ):
                query = coll.ComputeMembershipQuery()
                inc = np.array([bool(query.IsPathIncluded(Sdf.Path(p))) for p in paths], bool)
                setattr(light, attr, None if inc.all() else np.flatnonzero(inc).astype(np.int32))

    def light_warnings(self) -> None:
        """Stage-level light warnings: unauthored intensities (the schema fallback 1 is used)
        and DistantLights too dim to contribute next to the other light sources."""
        if self.unauthored_intensity:
            p = sorted(self.unauthored_intensity)
            more = f" and {len(p) - 3} more" if len(p) > 3 else ""
            self.warn(
                f"{len(p)} lights do not author inputs:intensity ({', '.join(p[:3])}{more}): "
                "the UsdLux fallback 1 is used (very dim in physical units); author the "
                "intensity you mean",
                key="lights:intensity",
            )
        if not self.lights:
            return
        # Rough illuminance each light delivers at the scene's centre (a warning only; emissive
        # surfaces are left out: their extent is unknown here, and overrating them would flag
        # a sun as dim).
        pts = [m.points for m in self.meshes]
        centre = np.mean([p.mean(axis=0) for p in pts], axis=0) if pts else np.zeros(3)
        scale = {}
        for light in self.lights:
            rad = float(np.max(light.radiance))
            if isinstance(light, L.DistantLight):
                h = light.half_angle
                scale[light.path] = rad * (np.pi * math.sin(h) ** 2 if h > 0 else 1.0)
            elif isinstance(light, L.DomeLight):
                img = getattr(light, "image", None)
                scale[light.path] = np.pi * rad * (float(np.mean(img)) if img is not None else 1)
            else:
                c = np.asarray(getattr(light, "center", centre), np.float64)
                size = float(getattr(light, "radius", 0.0) or 0.0)
                for k in ("ex", "ey"):
                    if getattr(light, k, None) is not None:
                        size = max(size, float(np.linalg.norm(getattr(light, k))))
                d2 = max(float(np.sum((c - centre) ** 2)), size * size, 1e-12)
                solid = min(np.pi * size * size / d2, np.pi) if size > 0 else 1.0 / d2
                scale[light.path] = rad * solid
        for light in self.lights:
            if not isinstance(light, L.DistantLight):
                continue
            others = [v for k, v in scale.items() if k != light.path]
            if others and scale[light.path] < 1e-3 * max(others):
                ratio = scale[light.path] / max(others)
                hint = ""
                if light.half_angle > 0:
                    solid = np.pi * math.sin(light.half_angle) ** 2
                    hint = (
                        "; with inputs:normalize off, intensity is the radiance of the sun "
                        f"disc (illuminance = intensity x {solid:.2g}): set inputs:normalize "
                        "= 1 to make it the illuminance"
                    )
                self.warn(
                    f"{light.path}: this DistantLight delivers about {ratio:.1e} of the "
                    f"brightest other light's illuminance, so it contributes nothing "
                    f"visible{hint}"
                )

    def _dome(self, prim, path, rad, m3):
        is1 = prim.IsA(UsdLux.DomeLight_1)
        lt = UsdLux.DomeLight_1(prim) if is1 else UsdLux.DomeLight(prim)
        if lt.GetPortalsRel().GetTargets():
            self.warn(f"{path}: DomeLight portals are not supported (ignored)")
        pole = "Y"
        if is1:
            pa = str(self.get(lt.GetPoleAxisAttr(), "scene"))
            pole = self.up_axis if pa == "scene" else pa
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
                problems = []
                file = asset.resolvedPath or asset.path
                if not asset.resolvedPath:
                    problems.append("file not found")
                else:
                    ta = lt.GetTextureFileAttr()
                    fcs = str(ta.GetColorSpace()) if ta.HasColorSpace() else ""
                    image = read_image(file, "auto", problems.append, file_colorspace=fcs)
                if image is None:
                    raise StageError(
                        f"{path}: DomeLight texture:file {asset.path} cannot be read "
                        f"({_one_line('; '.join(problems), 200)}); the environment would be "
                        "wrong for every prim: fix the path or remove texture:file"
                    )
                image = _sanitize_image(_to_rgb(image), f"{path}: {asset.path}", self.warn)
        self._add_light(L.DomeLight(path, rad, image=image, rotation=rot))


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


class _SubsetError(Exception):
    """A GeomSubset of a mesh is invalid (internal; becomes a mesh failure)."""


def _check_transform(xform, path) -> None:
    """Raise _MeshFailure for a NaN/Inf or non-invertible local-to-world transform."""
    if not np.all(np.isfinite(xform)):
        raise _MeshFailure(
            f"{path}: world transform contains NaN/Inf; fix the xformOps of the prim or its "
            "ancestors"
        )
    m3 = xform[:3, :3]
    rows = np.linalg.norm(m3, axis=1)
    det = abs(float(np.linalg.det(m3)))
    if rows.min() == 0.0 or det <= SINGULAR_DET_REL * float(np.prod(rows)):
        what = "a zero scale" if rows.min() == 0.0 else "rank < 3"
        raise _MeshFailure(
            f"{path}: world transform is not invertible ({what}, determinant {det:.3g}), so "
            "the mesh is flattened and its normals are undefined; fix the xformOps of the prim "
            "or its ancestors"
        )


def _check_precision(wp, path) -> None:
    """Raise _MeshFailure when float32 cannot resolve the mesh at its position."""
    far = float(np.abs(wp).max())
    size = float(np.linalg.norm(wp.max(axis=0) - wp.min(axis=0)))
    ulp = float(np.spacing(np.float32(far)))
    if size < MIN_SIZE_ULPS * ulp and far > 0:
        raise _MeshFailure(
            f"{path}: {size:.3g} units across at coordinate {far:.3g}: beyond float32 "
            f"ray-tracing precision (ulp {ulp:.3g} there); move it nearer the origin "
            "(re-centre the stage)"
        )


def _drop_degenerate(wp, topo, corners, path, warn):
    """Drop zero-area triangles (DEGENERATE_AREA_REL); returns (corners, keep mask)."""
    tri = topo.idx[corners]
    a, b, c = wp[tri[:, 0]], wp[tri[:, 1]], wp[tri[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    diag = float(np.linalg.norm(wp.max(axis=0) - wp.min(axis=0)))
    keep = area2 > DEGENERATE_AREA_REL * diag * diag
    n_bad = int((~keep).sum())
    if n_bad and keep.any():
        faces = len(np.unique(topo.face[~keep]))
        warn(
            f"{path}: {n_bad} degenerate (zero-area) triangles in {faces} faces dropped "
            "(repeated or collinear points)"
        )
    return corners[keep], keep


def _fmt(v) -> str:
    a = np.ravel(np.asarray(v, np.float64))
    return f"{a[0]:g}" if a.size == 1 else "(" + ", ".join(f"{x:g}" for x in a) + ")"


def _sanitize_image(data, label, warn):
    """Replace NaN/Inf and negative texels by 0 (with a warning); data : (h, w, c) float32."""
    bad = ~np.isfinite(data)
    neg = np.isfinite(data) & (data < 0)
    if bad.any() or neg.any():
        warn(
            f"{label}: {int(bad.sum())} NaN/Inf and {int(neg.sum())} negative texel values "
            "replaced by 0"
        )
        data = np.where(bad | neg, np.float32(0), data).astype(np.float32)
    return data


def _channels(out_name: str) -> tuple[int, ...]:
    return {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}.get(out_name, (0, 1, 2))


def _to_rgb(img):
    if img.shape[2] >= 3:
        return img[..., :3]
    return np.repeat(img[..., :1], 3, axis=2)


#: The colour space the baker works in (Gf.ColorSpaceNames / OpenImageIO's built-in config).
LINEAR_SPACE = "lin_rec709_scene"
#: Source colour spaces that need no conversion (data, or already the working space).
_NO_CONVERSION = ("raw", "data", "lin_rec709_scene", "lin_rec709", "linear", "lin_srgb")


def source_color_space(colorspace: str, file_colorspace: str, fmt: str, nchannels: int):
    """The colour space a texture's texels are in, or None for data (no conversion).

    colorspace : UsdUVTexture ``inputs:sourceColorSpace`` (``raw``, ``sRGB`` or ``auto``);
    file_colorspace : ``colorSpace`` metadata authored on ``inputs:file`` (or "");
    fmt : OpenImageIO pixel format of the file; nchannels : its channel count.
    ``raw`` and ``sRGB`` are explicit. ``auto`` takes the file's colorSpace metadata when
    authored, else Hydra's rule (HioImage): an 8-bit image with 3 or 4 channels is sRGB,
    anything else (1- or 2-channel masks, 16-bit, float) is linear.
    """
    if colorspace == "raw":
        return None
    if colorspace == "sRGB":
        return "srgb_rec709_scene"
    if file_colorspace:
        return None if file_colorspace in _NO_CONVERSION else file_colorspace
    if fmt == "uint8" and nchannels in (3, 4):
        return "srgb_rec709_scene"
    return None


def _colorconvert(data, space: str, warn, path: str):
    """Convert the colour channels of (h, w, c) float32 texels from ``space`` to LINEAR_SPACE
    with OpenImageIO's colour management (alpha and the second channel of grey+alpha stay)."""
    import OpenImageIO as oiio

    h, w, c = data.shape
    rgb = data[..., :3] if c >= 3 else np.repeat(data[..., :1], 3, axis=2)
    buf = oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32))
    out = oiio.ImageBufAlgo.colorconvert(buf, space, LINEAR_SPACE)
    if out.has_error or not out.initialized:
        if warn:
            warn(
                f"texture {path}: OpenImageIO cannot convert colour space {space!r} to "
                f"{LINEAR_SPACE} ({_one_line(out.geterror(), 150)}); texels read unconverted"
            )
        return data
    conv = np.asarray(out.get_pixels(oiio.FLOAT), np.float32).reshape(h, w, 3)
    data = data.copy()
    if c >= 3:
        data[..., :3] = conv
    else:
        data[..., 0] = conv[..., 0]
    return data


def read_image(path: str, colorspace: str = "auto", warn=None, file_colorspace: str = ""):
    """Read an image as linear float32 (h, w, c) through OpenImageIO, or None (with a warning).

    path : a resolved asset path: a file, or an asset inside a usdz package / from a studio
    resolver (read through USD's asset resolver, usdahd.usd.assets).
    colorspace, file_colorspace : see :func:`source_color_space`; the conversion to
    lin_rec709_scene is OpenImageIO's (``ImageBufAlgo.colorconvert``).
    """
    import OpenImageIO as oiio

    from usdahd.usd import assets
    from usdahd.usd.checks import asset_problem  # regular file, size limit (issue 18)

    problem = asset_problem(path)
    if problem:
        if warn:
            warn(f"cannot read texture {path}: it {problem}; fallback used")
        return None
    try:
        with assets.local_file(path) as local:
            inp = oiio.ImageInput.open(local)
            if inp is None:
                if warn:
                    warn(f"cannot read texture {path} ({oiio.geterror()[:200]}); fallback used")
                return None
            try:
                spec = inp.spec()
                data = inp.read_image(0, 0, 0, spec.nchannels, "float")
                fmt = str(spec.format)
            finally:
                inp.close()
    except OSError as exc:
        if warn:
            warn(f"cannot read texture {path} ({_one_line(exc, 200)}); fallback used")
        return None
    if data is None:
        if warn:
            warn(f"cannot decode texture {path}; fallback used")
        return None
    data = np.asarray(data, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if colorspace not in ("raw", "sRGB", "auto") and warn:
        warn(f"texture {path}: unknown sourceColorSpace {colorspace!r}; treated as auto")
    space = source_color_space(colorspace, file_colorspace, fmt, spec.nchannels)
    if space is not None:
        data = _colorconvert(data, space, warn, path)
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
