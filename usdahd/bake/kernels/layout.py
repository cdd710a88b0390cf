"""Named slots of the flat arrays the numba kernels read (the ``_BLK_*`` style of ``_irradz``).

numba kernels take plain arrays and tuples; every position in them has a name here, so a kernel
reads ``p[PAR_RADIUS]`` and ``tb.mat_const[m, MAT_EMISSION]`` instead of ``p[15]`` and
``tb[5][m, 3]``. Module-level integers are compile-time constants in numba, so naming a slot
changes no generated arithmetic.

Light parameter rows ``par`` (L, N_PAR) float64 (:func:`usdahd.bake.kernels.lights.pack_lights`);
a slot holding a 3-vector or matrix is named by its first element (``p[PAR_CENTER + 1]`` is the
centre's y). Slots are shared between kinds that never use them together:

========================  =====  ===============================================================
slot                      width  kinds
========================  =====  ===============================================================
PAR_RADIANCE              3      all (emitted radiance; delta lights: see scene.lights)
PAR_CENTER                3      sphere, point, rect, disk, cylinder
PAR_EX / PAR_EY           3      rect, disk (half-extent edge vectors)
PAR_AXIS                  3      cylinder (unit axis; same slot as PAR_EX)
PAR_DIRECTION             3      distant (unit direction *towards* the light; slot of PAR_EX)
PAR_NORMAL                3      rect, disk (emitting side)
PAR_RADIUS                1      sphere, cylinder
PAR_AREA                  1      rect, disk, cylinder (world-space emitting area)
PAR_GINV                  4      rect, disk (inverse Gram of (ex, ey), row major)
PAR_HALF_LENGTH           1      cylinder (slot of PAR_GINV + 1)
PAR_OMC / PAR_COS_MAX     1      distant: 1 - cos(half angle), cos(half angle) (PAR_GINV + 2, 3)
PAR_PLANE_N               3      rect, disk (plane normal of the hit test)
PAR_CYL_E1 / PAR_CYL_E2   3      cylinder (unit vectors across the axis; E1 = PAR_PLANE_N)
PAR_RECT_ORTHO            1      rect: 1 when its edges are orthogonal (solid-angle sampling)
PAR_DOME_*                       dome: textured flag, pmf/cdf offset, pixel offset, rotation
                                 (9), inverse rotation (9), image height, width
PAR_EM_*                  1      emissive triangles: pmf/cdf block offset, pdf_area offset,
                                 global triangle id offset, emitter count
PAR_IMP_*                        all: the light's selection bound (scene.lights.Bound):
                                 falloff, scale, r2, cap (1 each), center (3), normal (3)
========================  =====  ===============================================================
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# ----------------------------------------------------------------------------- lights
KIND_SPHERE, KIND_POINT, KIND_RECT, KIND_DISK, KIND_CYLINDER, KIND_DISTANT, KIND_DOME = range(7)
KIND_EMISSIVE = 7

PAR_RADIANCE = 0
PAR_CENTER = 3
PAR_EX = PAR_AXIS = PAR_DIRECTION = 6
PAR_EY = 9
PAR_NORMAL = 12
PAR_RADIUS = 15
PAR_AREA = 16
PAR_GINV = 17
PAR_HALF_LENGTH = 18
PAR_OMC, PAR_COS_MAX = 19, 20
PAR_PLANE_N = PAR_CYL_E1 = 21
PAR_RECT_ORTHO = PAR_CYL_E2 = 24
PAR_DOME_TEXTURED, PAR_DOME_PMF, PAR_DOME_PIX = 25, 26, 27
PAR_DOME_ROT, PAR_DOME_INV_ROT = 28, 37
PAR_DOME_H, PAR_DOME_W = 46, 47
#: emissive triangles: offset of the per-emitter pmf/cdf block (E entries), offset of the
#: global-triangle ``pdf_area`` block (T entries, in ``pmf``), offset of the global triangle ids
#: (E entries, float64 in ``pmf``), E.
PAR_EM_TABLE, PAR_EM_PDF_AREA, PAR_EM_TRI, PAR_EM_COUNT = 26, 27, 28, 29
#: the selection bound (usdahd.scene.lights.Bound) of every light
PAR_IMP_FALLOFF, PAR_IMP_SCALE, PAR_IMP_R2, PAR_IMP_CAP = 48, 49, 50, 51
PAR_IMP_CENTER, PAR_IMP_NORMAL = 52, 55
#: Parameters per light (float64).
N_PAR = 58


class LightArrays(NamedTuple):
    """The light tables as the kernels take them (:class:`~usdahd.bake.kernels.lights.LightTable`
    without the Python object): ``kind`` (L,) int64, ``par`` (L, N_PAR) f64, dome images ``img``
    (P,3) f64, ``pmf``/``cdf`` (P,) f64, flags ``delta``/``infinite``/``sampled`` (L,) bool."""

    kind: np.ndarray
    par: np.ndarray
    img: np.ndarray
    pmf: np.ndarray
    cdf: np.ndarray
    delta: np.ndarray
    infinite: np.ndarray
    sampled: np.ndarray


class LightLists(NamedTuple):
    """Light indices (into :class:`LightArrays`) per role, each (k,) int64: ``nee`` lights of
    next-event estimation at path vertices, ``visible`` lights a ray can hit, ``delta`` lights
    handled exactly at the texel, ``area`` lights sampled at the texel."""

    nee: np.ndarray
    visible: np.ndarray
    delta: np.ndarray
    area: np.ndarray


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
    then bias."""

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


# ----------------------------------------------------------------------------- integrator
#: Slots of the integrator configuration ``cfg`` (CFG_LEN,) float64 (one array so the kernel
#: signature stays fixed): bounces (int), the scene's largest ray offset (``Tracer.offset_eps``,
#: informational: the kernels offset by the hit triangle's ``tri_offset`` or the texel's own),
#: the scene has transmissive materials (0/1), has emission (0/1), the estimator is
#: "regression" (0/1), index of the emissive-triangles light (-1: none), strategy (index in
#: ``integrate.STRATEGIES``).
CFG_BOUNCES, CFG_EPS, CFG_TRANSMISSION, CFG_EMISSION, CFG_REGRESSION = 0, 1, 2, 3, 4
CFG_EMISSIVE_LIGHT, CFG_STRATEGY, CFG_LEN = 5, 6, 7
#: ``cfg[CFG_STRATEGY]`` values (the order of ``integrate.STRATEGIES``).
MODE_MIS, MODE_BSDF, MODE_NEE = 0, 1, 2

#: Columns of the per-path state rows ``ps`` (s, PATH_COLS) float64 of the wavefront: origin
#: (3), direction (3), throughput (3), pdf of the direction, selection probability of the NEE
#: light it is paired with (-1: the vertex selection of ``_nee_pick`` over ``lists.nee`` at the
#: surface point the ray left, PATH_X (3); -2: the texel's, over ``lists.area``, when it has
#: more than ALL_LIGHTS_MAX lights), reflections so far, sample index.
PATH_O, PATH_D, PATH_BETA, PATH_PDF, PATH_SEL, PATH_DEPTH, PATH_SAMPLE = 0, 3, 6, 9, 10, 11, 12
PATH_X = 13
PATH_COLS = 16
#: Columns of the hit rows ``hits`` (s, 7) f64 of :func:`usdahd.bake.kernels.embree
#: .intersect_rays`: t, triangle (-1: miss), u, v, geometric normal (3). (Ray rows are origin,
#: direction, tfar, written positionally by ``kernels.integrate._set_row``.)
HIT_T, HIT_TRI, HIT_U, HIT_V, HIT_NG = 0, 1, 2, 3, 4
