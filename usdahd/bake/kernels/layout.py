"""Records the numba kernels read, each declared once as a field list (pbrt-v4 ``soa`` style).

numba kernels take plain arrays and tuples. Every record they share with Python is declared
here (or, for a light's own parameters, on its class in :mod:`usdahd.scene.lights`) as a list
of named fields; slot offsets, module-level constants, allocators and named views are
generated from that one declaration:

- :class:`Row`: a flat float64 row of named slots (light parameters ``par``, the path state
  ``ps``, ray and hit rows). Its constants (``PAR_CENTER``, ``PATH_BETA``, ...) are
  module-level integers, which numba compiles as constants, so a kernel reads
  ``p[PAR_RADIUS]`` with no generated arithmetic. A slot holding a 3-vector or matrix is named
  by its first element (``p[PAR_CENTER + 1]`` is the centre's y). :meth:`Row.view` writes a
  row by name and refuses a field its variant does not declare (a wrong slot is an error,
  not plausible wrong light); :meth:`Row.pack` checks that every declared field was written.
- :func:`array_record`: a ``NamedTuple`` of arrays (native work arrays, the accumulator, the
  light tables) with an allocator, so kernels unpack nothing by position.

Light parameter rows ``par`` (L, N_PAR) float64 (:func:`usdahd.bake.kernels.lights
.pack_lights`): the fields common to every light (:data:`LIGHT_COMMON`: radiance and the
selection bound) and, per kind, the fields its class declares (``FIELDS`` of each class in
:data:`usdahd.scene.lights.PACKED_LIGHTS`, in ``KIND_*`` order). Kinds share slots: a field
name means one offset in every kind that declares it (``center``), and different kinds'
fields overlap (:meth:`Row.union`).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from usdahd.scene import lights as _scene_lights

__all__ = [
    "AccumArrays",
    "CFG_LEN",
    "CONFIG",
    "EmbreeHit",
    "GRAM_SUMS",
    "LIGHT_KINDS",
    "LIGHT_PARAMS",
    "LightArrays",
    "LightLists",
    "LightSample",
    "MAT_ALBEDO",
    "MAT_EMISSION",
    "MAT_OPACITY",
    "MAT_THRESHOLD",
    "MODE_BSDF",
    "MODE_MIS",
    "MODE_NEE",
    "N_PAR",
    "NativeTables",
    "NativeWork",
    "PassPoints",
    "TEX_ALBEDO",
    "TEX_EMISSION",
    "TEX_OPACITY",
    "TexelArrays",
    "TraceHit",
]


# ----------------------------------------------------------------------------- declarations
@dataclass(frozen=True)
class Row:
    """A float64 row of named slots: ``offset[name]``, ``width[name]``, ``size`` slots;
    ``variants`` maps a variant (light kind) to the names it uses (None: one variant, all)."""

    name: str
    prefix: str
    offset: dict
    width: dict
    size: int
    variants: dict | None = None

    @classmethod
    def of(cls, name: str, prefix: str, fields) -> Row:
        """Consecutive slots for ``fields`` ((name, width) pairs) in order."""
        offset, width, at = {}, {}, 0
        for f, w in fields:
            offset[f], width[f] = at, w
            at += w
        return cls(name, prefix, offset, width, at)

    @classmethod
    def union(cls, name: str, prefix: str, common, variants: dict) -> Row:
        """``common`` fields first, then each variant's own fields over one shared area: a
        name gets one offset for every variant declaring it (same width required), placed at
        the lowest offset free in all of them."""
        base = cls.of(name, prefix, common)
        offset, width = dict(base.offset), dict(base.width)
        used = {v: [] for v in variants}  # per variant: (start, end) intervals
        owners: dict = {}
        for v, fields in variants.items():
            for f, w in fields:
                if f in width and width[f] != w:
                    raise ValueError(f"{name}: field {f!r} declared with widths {width[f]}, {w}")
                owners.setdefault(f, []).append(v)
                width[f] = w
        end = base.size
        for fields in variants.values():
            for f, w in fields:
                if f not in offset:
                    at = base.size
                    while any(
                        at < e and s < at + w for o in owners[f] for s, e in used[o]
                    ):  # first gap free in every variant that declares f
                        at += 1
                    offset[f] = at
                    for o in owners[f]:
                        used[o].append((at, at + w))
                    end = max(end, at + w)
        names = {
            v: tuple(n for n, _ in common) + tuple(f for f, _ in fs) for v, fs in variants.items()
        }
        for v, fs in names.items():  # no two fields of one variant share a slot
            slots = sorted((offset[f], offset[f] + width[f], f) for f in fs)
            for (_, e0, f0), (s1, _, f1) in zip(slots, slots[1:], strict=False):
                if s1 < e0:
                    raise ValueError(f"{name} ({v}): fields {f0!r} and {f1!r} overlap")
        return cls(name, prefix, offset, width, end, names)

    def constants(self) -> dict:
        """``{PREFIX_FIELD: offset}`` for module globals (numba compile-time constants)."""
        return {self.prefix + f.upper(): o for f, o in self.offset.items()}

    def view(self, row: np.ndarray, variant=None) -> RowView:
        """A named view writing ``row`` (size,) float64 (fields of ``variant`` only)."""
        allowed = self.offset.keys() if self.variants is None else self.variants[variant]
        return RowView(self, row, frozenset(allowed))

    def pack(self, row: np.ndarray, variant, fill) -> None:
        """``fill(view)`` writes the fields of ``variant`` into ``row``; raises when a
        declared field stays unwritten."""
        v = self.view(row, variant)
        fill(v)
        missing = v._allowed - v._written
        if missing:
            raise ValueError(f"{self.name} ({variant}): fields not written: {sorted(missing)}")


class RowView:
    """Named access to one row of a :class:`Row` (``view.center = c``; ``view.center``)."""

    __slots__ = ("_rec", "_row", "_allowed", "_written")

    def __init__(self, rec: Row, row: np.ndarray, allowed: frozenset):
        object.__setattr__(self, "_rec", rec)
        object.__setattr__(self, "_row", row)
        object.__setattr__(self, "_allowed", allowed)
        object.__setattr__(self, "_written", set())

    def _slot(self, name):
        if name not in self._allowed:
            raise AttributeError(
                f"{self._rec.name}: no field {name!r} here ({sorted(self._allowed)})"
            )
        o = self._rec.offset[name]
        return o, self._rec.width[name]

    def __setattr__(self, name, value):
        o, w = self._slot(name)
        if w == 1:
            self._row[o] = value
        else:
            self._row[o : o + w] = np.asarray(value, np.float64).reshape(-1)
        self._written.add(name)

    def __getattr__(self, name):
        o, w = self._slot(name)
        return self._row[o] if w == 1 else self._row[o : o + w]


def array_record(name: str, fields, doc: str):
    """A ``NamedTuple`` class of arrays from ``fields`` ((name, shape, dtype, what) with
    ``shape`` a tuple whose str entries are sizes given to ``alloc``), with
    ``alloc(given, **sizes)`` (zeros, except the arrays in the dict ``given``) and
    ``FIELDS``. numba takes it as a heterogeneous tuple with named fields."""
    cls = namedtuple(name, [f[0] for f in fields], module=__name__)
    cls.FIELDS = tuple(fields)
    lines = [f"``{f}`` {_shape(s)} {np.dtype(dt).name}: {what}" for f, s, dt, what in fields]
    cls.__doc__ = doc + "\n\n" + "\n".join(f"- {ln}" for ln in lines)

    def alloc(given=None, **sizes):
        given = given or {}
        return cls(*(given[f] if f in given else
                     np.zeros(tuple(sizes[d] if isinstance(d, str) else d for d in s), dt)
                     for f, s, dt, _ in fields))  # fmt: skip

    cls.alloc = staticmethod(alloc)
    return cls


def _shape(s):
    return "(" + ", ".join(str(d) for d in s) + ("," if len(s) == 1 else "") + ")"


# ----------------------------------------------------------------------------- lights
#: Fields every light row has: emitted radiance (delta lights: see scene.lights) and the
#: light's selection bound (scene.lights.Bound: falloff, scale, r2, cap, center, normal).
LIGHT_COMMON = (
    ("radiance", 3),
    ("imp_falloff", 1),
    ("imp_scale", 1),
    ("imp_r2", 1),
    ("imp_cap", 1),
    ("imp_center", 3),
    ("imp_normal", 3),
)
#: The light classes with a native form, in ``KIND_*`` order (``KIND_SPHERE`` = 0, ...).
LIGHT_KINDS = _scene_lights.PACKED_LIGHTS
LIGHT_PARAMS = Row.union(
    "light parameters",
    "PAR_",
    LIGHT_COMMON,
    {cls.KIND: cls.FIELDS for cls in LIGHT_KINDS},
)
#: Parameters per light (float64).
N_PAR = LIGHT_PARAMS.size
globals().update({"KIND_" + cls.KIND.upper(): i for i, cls in enumerate(LIGHT_KINDS)})
globals().update(LIGHT_PARAMS.constants())

LightArrays = array_record(
    "LightArrays",
    [
        ("kind", ("L",), np.int64, "KIND_* of each light"),
        ("par", ("L", N_PAR), np.float64, "parameter rows (LIGHT_PARAMS, PAR_* slots)"),
        ("img", ("P", 3), np.float64, "dome images, concatenated (offsets in par)"),
        ("pmf", ("P",), np.float64, "sampling tables of the blocks in img"),
        ("cdf", ("P",), np.float64, "their cumulative sums"),
        ("delta", ("L",), np.bool_, "delta lights"),
        ("infinite", ("L",), np.bool_, "distant and dome lights"),
        ("sampled", ("L",), np.bool_, "lights NEE samples"),
        ("recv", ("L", "M"), np.bool_, "light linking: the light lights receivers of mesh m"),
        ("shadow_linked", ("L",), np.bool_, "the light's shadowLink excludes some mesh"),
        ("cast", ("L", "M"), np.bool_, "shadow linking: mesh m casts the light's shadows"),
    ],
    "The light tables the kernels take (:func:`usdahd.bake.kernels.lights.pack_lights`; L "
    "lights, P pixels of the shared blocks, M = max(1, scene meshes)).",
)


class LightLists(NamedTuple):
    """Light indices (into :class:`LightArrays`) per role, each (k,) int64: ``nee`` lights of
    next-event estimation at path vertices, ``visible`` lights a ray can hit, ``delta`` lights
    handled exactly at the texel, ``area`` lights sampled at the texel."""

    nee: np.ndarray
    visible: np.ndarray
    delta: np.ndarray
    area: np.ndarray


#: A light sample (``light_sample``, ``shading.nee_sample``): unit direction towards the light,
#: distance (inf: infinite lights), the radiance arriving (delta lights: the irradiance at
#: normal incidence) and the solid-angle pdf (1 for delta lights, 0: invalid).
LightSample = namedtuple("LightSample", "dx dy dz dist r g b pdf", module=__name__)
#: Embree's closest hit of one ray (``kernels.embree.intersect1``): t float32 (inf: miss),
#: primitive id int64 (-1: miss), barycentrics u, v float32.
EmbreeHit = namedtuple("EmbreeHit", "t tri u v", module=__name__)
#: A ray's closest hit (``kernels.trace.nb_trace``): t (inf: miss), triangle (-1: miss),
#: Embree barycentrics u, v, unit geometric normal, rays traced for it.
TraceHit = namedtuple("TraceHit", "t tri u v gx gy gz rays", module=__name__)


# ----------------------------------------------------------------------------- tracer tables
#: Columns of ``mat_const`` (M, 8) f64: albedo rgb, emission rgb, opacity, opacity threshold.
MAT_ALBEDO, MAT_EMISSION, MAT_OPACITY, MAT_THRESHOLD = 0, 3, 6, 7
#: Columns of ``mat_tex`` (M, 3) i64: texture index of albedo / emission / opacity (-1: none).
TEX_ALBEDO, TEX_EMISSION, TEX_OPACITY = 0, 1, 2
#: Columns of ``tex_info`` (K, 8) i64 (:func:`usdahd.bake.trace.pack_textures`).
TI_OFFSET, TI_H, TI_W, TI_C, TI_WRAP_S, TI_WRAP_T, TI_NCHAN = 0, 1, 2, 3, 4, 5, 6


class NativeTables(NamedTuple):
    """Per-triangle, material and texture tables for the numba kernels
    (:meth:`usdahd.bake.trace.Tracer.native_tables`; T triangles, M materials, K textures).

    ``verts`` (T,3,3) f64, ``geom_normal`` (T,3) f64, ``corner_normal`` (T,3,3) f32,
    ``tri_material`` (T,) i32 (narrow: read once per hit, where cache misses dominate),
    ``tri_one_sided`` (T,) u8 (0 on doubleSided meshes: their back faces are surfaces),
    ``tri_offset`` (T,) f64 ray-origin offset of points on the triangle
    (:func:`usdahd.numerics.offsets.triangle_offset_scale`), ``tri_texcoord`` (T,3,2) f64,
    ``mat_const`` (M,8) f64 (``MAT_*`` columns), ``mat_tex`` (M,3) i64 (``TEX_*`` columns),
    ``tex_data`` (D,) f32 texels, ``tex_info`` (K,8) i64
    (``TI_*`` columns), ``tex_chan`` (K,4) i64 selected channels, ``tex_sb`` (K,8) f64 scale
    then bias, ``tri_mesh`` (T,) i32 scene mesh of each triangle (light linking)."""

    verts: np.ndarray
    geom_normal: np.ndarray
    corner_normal: np.ndarray
    tri_material: np.ndarray
    tri_one_sided: np.ndarray
    tri_offset: np.ndarray
    tri_texcoord: np.ndarray
    mat_const: np.ndarray
    mat_tex: np.ndarray
    tex_data: np.ndarray
    tex_info: np.ndarray
    tex_chan: np.ndarray
    tex_sb: np.ndarray
    tri_mesh: np.ndarray


# ----------------------------------------------------------------------------- integrator
#: The integrator configuration ``cfg`` (CFG_LEN,) float64 (one array so the kernel
#: signature stays fixed): bounces (int), the scene's largest ray offset (``Tracer.offset_eps``,
#: informational: the kernels offset by the hit triangle's ``tri_offset`` or the texel's own),
#: the scene has transmissive materials (0/1), has emission (0/1), the estimator is
#: "regression" (0/1), index of the emissive-triangles light (-1: none), strategy (index in
#: ``integrate.STRATEGIES``), some light is linked (0/1: light or shadow linking, checked only
#: then), some light is shadow-linked (0/1: shadow rays one at a time), the scene mesh of the
#: texels (-1: none; the receiver for light linking).
CONFIG = Row.of(
    "integrator configuration",
    "CFG_",
    [
        ("bounces", 1),
        ("eps", 1),
        ("transmission", 1),
        ("emission", 1),
        ("regression", 1),
        ("emissive_light", 1),
        ("strategy", 1),
        ("linked", 1),
        ("shadow_linked", 1),
        ("texel_mesh", 1),
    ],
)
CFG_LEN = CONFIG.size
globals().update(CONFIG.constants())
#: ``cfg[CFG_STRATEGY]`` values (the order of ``integrate.STRATEGIES``).
MODE_MIS, MODE_BSDF, MODE_NEE = 0, 1, 2

#: The per-path state rows ``ps`` (s, PATH_COLS) float64 of the wavefront: origin, direction,
#: throughput, pdf of the direction, selection probability of the NEE light it is paired with
#: (-1: the vertex selection of ``shading.nee_pick`` over ``lists.nee`` at the surface point the ray
#: left, PATH_X; -2: the texel's, over ``lists.area``, when it has more than ALL_LIGHTS_MAX
#: lights), reflections so far, sample index, the point the ray left, the scene mesh of that
#: point (the receiver for light linking; -1: none).
PATH = Row.of(
    "path state",
    "PATH_",
    [("o", 3), ("d", 3), ("beta", 3), ("pdf", 1), ("sel", 1), ("depth", 1), ("sample", 1),
     ("x", 3), ("mesh", 1)],
)  # fmt: skip
PATH_COLS = PATH.size
globals().update(PATH.constants())
#: Ray rows ``rays`` (s, RAY_COLS) f64 read by :mod:`usdahd.bake.kernels.embree`: origin,
#: direction, tfar.
RAY = Row.of("ray", "RAY_", [("o", 3), ("d", 3), ("tfar", 1)])
RAY_COLS = RAY.size
globals().update(RAY.constants())
#: Hit rows ``hits`` (s, HIT_COLS) f64 of :func:`usdahd.bake.kernels.embree.intersect_rays`:
#: t, triangle (-1: miss), u, v, unit geometric normal.
HIT = Row.of("hit", "HIT_", [("t", 1), ("tri", 1), ("u", 1), ("v", 1), ("ng", 3)])
HIT_COLS = HIT.size
globals().update(HIT.constants())
#: Rows of the queued shadow rays' values ``sval`` (s, SVAL_COLS) f64: the weighted radiance
#: and the direction in the texel frame (texel light samples; vertex NEE uses ``rgb`` only).
SVAL = Row.of("shadow-ray value", "SVAL_", [("rgb", 3), ("dir", 3)])
SVAL_COLS = SVAL.size
globals().update(SVAL.constants())

#: The per-texel Gram sums of the native pass (``kernels.integrate``, scratch ``G``): the 8
#: first sums sum w Y_a (a = 1..8), the 36 pairs sum w Y_a Y_b (1 <= a <= b <= 8, row by
#: row), the weight sum.
GRAM = Row.of("Gram sums", "GRAM_", [("first", 8), ("pairs", 36), ("wsum", 1)])
GRAM_SUMS = GRAM.size
globals().update(GRAM.constants())

#: The per-texel sums both integrators fill (:class:`usdahd.bake.reference.Accum`).
AccumArrays = array_record(
    "AccumArrays",
    [
        ("gram", ("n", 9, 9), np.float64, "sum Y Y^T / p over hemisphere samples"),
        ("hemi", ("n", 3, 9), np.float64, "sum L Y / p over hemisphere samples"),
        ("nee", ("n", 3, 9), np.float64, "sum of light-sample contributions"),
        ("delta", ("n", 3, 9), np.float64, "exact delta-light terms (not divided by S)"),
        ("count", ("n",), np.int32, "samples taken"),
        ("back", ("n",), np.int64, "hemisphere rays that hit a back face"),
        ("y_sum", ("n",), np.float64, "sum of per-sample luminance Iz estimates"),
        ("y_sq", ("n",), np.float64, "sum of their squares"),
        ("y_half", ("n",), np.float64, "sum over the even-numbered samples of every pass"),
        ("n_half", ("n",), np.int32, "count of those samples"),
    ],
    "Per-texel running sums (n texels), so passes and estimators combine.",
)

#: The texels of one chunk (n texels) as ``kernels.integrate.native_pass`` reads them.
TexelArrays = array_record(
    "TexelArrays",
    [
        ("P", ("n", 3), np.float64, "positions"),
        ("NG", ("n", 3), np.float64, "geometric normals"),
        ("F", ("n", 3, 3), np.float64, "tangent frames (rows tangent, bitangent, normal)"),
        ("E", ("n",), np.float64, "ray-origin offsets (Tracer.texel_offsets)"),
    ],
    "The texels of one chunk, float64.",
)
#: The low-discrepancy points of one pass of s samples.
PassPoints = array_record(
    "PassPoints",
    [
        ("r2h", ("s", 4), np.float64, "R2 points of the hemisphere, then cos, sin of 2 pi u1"),
        ("r2n", ("s", 2), np.float64, "R2 points of the texel light samples"),
    ],
    "The sample points of one pass, shared by every texel (each rotates them).",
)

#: Per-thread scratch of ``kernels.integrate.native_pass`` for passes of s samples
#: (``rec``/``pk``: :func:`usdahd.bake.kernels.embree.new_scratch` / ``new_packet``).
NativeWork = array_record(
    "NativeWork",
    [
        ("rec", (), np.float32, "RTCRayHit record (embree.new_scratch)"),
        ("pk", (), np.float32, "16-ray packet (embree.new_packet)"),
        ("st", (1,), np.uint64, "splitmix64 random state of the texel"),
        ("Y", (9,), np.float64, "SH basis scratch"),
        ("G", (GRAM_SUMS,), np.float64, "register-fed Gram sums (zeroed between texels)"),
        ("H", (27,), np.float64, "hemisphere SH sums (zeroed between texels)"),
        ("ps", ("s", PATH_COLS), np.float64, "path state rows (PATH_*)"),
        ("rays", ("s", RAY_COLS), np.float64, "continuation rays (RAY_*)"),
        ("hits", ("s", HIT_COLS), np.float64, "their hits (HIT_*)"),
        ("srays", ("s", RAY_COLS), np.float64, "queued shadow rays (RAY_*)"),
        ("sval", ("s", SVAL_COLS), np.float64, "their values (SVAL_*)"),
        ("sidx", ("s",), np.int64, "their sample index"),
        ("slight", ("s",), np.int64, "their light (light linking)"),
        ("occ", ("s",), np.float64, "shadow-ray transmittance"),
        ("R", ("s", 3), np.float64, "radiance per hemisphere sample"),
        ("loc", ("s", 3), np.float64, "hemisphere sample directions, texel frame"),
        ("yl", ("s",), np.float64, "light-sample luminance Iz per sample"),
    ],
    "Per-thread scratch arrays of the native pass.",
)


# The slot constants generated above (KIND_*, PAR_*, CFG_*, PATH_*, RAY_*, HIT_*, SVAL_*, GRAM_*).
__all__ += sorted(
    {"KIND_" + cls.KIND.upper() for cls in LIGHT_KINDS}.union(
        *(row.constants() for row in (LIGHT_PARAMS, CONFIG, PATH, RAY, HIT, SVAL, GRAM))
    )
)
