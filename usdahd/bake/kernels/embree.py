"""Direct binding to the ``libembree4`` shipped inside the embreex wheel (ctypes + numba).

embreex exposes batched queries only through Python, with tnear fixed at 0 and one Python call
per batch. This module loads the same shared library, builds the BVH through its C API with
ctypes, and makes ``rtcIntersect1`` / ``rtcOccluded1`` callable from numba ``nopython`` code
(``nogil``), so a whole path-tracing kernel runs without returning to Python.

The numba side binds the C symbols by name (``llvmlite.binding.load_library_permanently`` and
an ``@intrinsic`` that declares the external function), not by ctypes function-pointer address,
so kernels that call them can be cached (``cache=True``) across processes.

Ray/hit records use the Embree 4 layout (``embree4/rtcore_ray.h``): ``RTCRay`` is 48 bytes
(org, tnear, dir, time, tfar, mask, id, flags), followed by ``RTCHit`` at byte 48 (Ng, u, v,
primID, geomID, instID[1], instPrimID[1]) - 96 bytes in all. A kernel keeps one such record
per thread in a float32 scratch array (:data:`RAYHIT_FLOATS` floats) and uses :func:`intersect1`
and :func:`occluded1` below.

``available()`` tells whether the library could be found and bound; callers fall back to the
embreex reference path otherwise.
"""

from __future__ import annotations

import ctypes
import glob
import os

import numpy as np

__all__ = [
    "NativeScene",
    "available",
    "hit_normal",
    "intersect1",
    "intersect_batch",
    "intersect_rays",
    "new_packet",
    "new_scratch",
    "occluded1",
    "occluded_batch",
    "occluded_rays",
]

#: Floats of the per-thread RTCRayHit scratch record (96 bytes used; 128 for alignment room).
RAYHIT_FLOATS = 32
#: Rays per packet query (``rtcIntersect16`` / ``rtcOccluded16``; measured faster than 8-wide
#: and than single rays here, most of all for the coherent shadow rays of one texel).
PACKET = 16
#: Floats of the packet scratch: RTCRayHit16 (SOA: 12 ray fields, then Ng x/y/z, u, v, primID,
#: geomID, instID, instPrimID; 21 x 16) padded to 22 x 16, then the int32 valid mask (16).
PACKET_FLOATS = 23 * PACKET
#: Packets with fewer active rays than this are traced one ray at a time (rtcIntersect1).
PACKET_MIN = 3
#: Embree enums (embree4/rtcore_common.h, rtcore_geometry.h, rtcore_buffer.h, rtcore_scene.h).
RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_BUFFER_TYPE_INDEX = 0
RTC_BUFFER_TYPE_VERTEX = 1
RTC_FORMAT_UINT3 = 0x5003
RTC_FORMAT_FLOAT3 = 0x9003
RTC_SCENE_FLAG_ROBUST = 1 << 2
RTC_BUILD_QUALITY_MEDIUM = 1
RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF

_LIB = None
_ERROR = None


def library_path() -> str | None:
    """Path of the libembree4 shipped in the embreex wheel, or None."""
    try:
        import embreex
    except ImportError:  # pragma: no cover - embreex is a hard dependency
        return None
    root = os.path.dirname(os.path.dirname(os.path.abspath(embreex.__file__)))
    hits = sorted(glob.glob(os.path.join(root, "embreex.libs", "libembree4*")))
    hits += sorted(glob.glob(os.path.join(os.path.dirname(embreex.__file__), "libembree4*")))
    return hits[0] if hits else None


def _load():
    global _LIB, _ERROR
    if _LIB is not None or _ERROR is not None:
        return _LIB
    path = library_path()
    if path is None:
        _ERROR = "libembree4 not found next to embreex"
        return None
    try:
        import llvmlite.binding as llvm

        lib = ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
        llvm.load_library_permanently(path)
        vp, u32, sz = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_size_t
        sig = {
            "rtcNewDevice": (vp, [ctypes.c_char_p]),
            "rtcReleaseDevice": (None, [vp]),
            "rtcGetDeviceError": (ctypes.c_int, [vp]),
            "rtcNewScene": (vp, [vp]),
            "rtcReleaseScene": (None, [vp]),
            "rtcSetSceneFlags": (None, [vp, ctypes.c_int]),
            "rtcSetSceneBuildQuality": (None, [vp, ctypes.c_int]),
            "rtcNewGeometry": (vp, [vp, ctypes.c_int]),
            "rtcReleaseGeometry": (None, [vp]),
            "rtcSetSharedGeometryBuffer": (
                None,
                [vp, ctypes.c_int, u32, ctypes.c_int, vp, sz, sz, sz],
            ),
            "rtcCommitGeometry": (None, [vp]),
            "rtcAttachGeometry": (u32, [vp, vp]),
            "rtcCommitScene": (None, [vp]),
        }
        for name, (res, args) in sig.items():
            fn = getattr(lib, name)
            fn.restype = res
            fn.argtypes = args
        _LIB = lib
    except (OSError, AttributeError, ImportError) as exc:  # pragma: no cover - platform
        _ERROR = f"cannot bind {path}: {exc}"
        return None
    return _LIB


def available() -> bool:
    """True when libembree4 was found and its C API bound."""
    return _load() is not None


class NativeScene:
    """One Embree triangle geometry over ``points`` (v,3) and ``triangles`` (t,3).

    ``handle`` is the RTCScene address (an int) to pass to the numba kernels. The vertex and
    index arrays are kept alive here (Embree shares them, no copy). ``robust=False`` as the
    embreex path (measured faster; offsets along the geometric normal handle self-hits).
    """

    def __init__(self, points: np.ndarray, triangles: np.ndarray, robust: bool = False):
        lib = _load()
        if lib is None:
            from usdahd.errors import UsdAhdError

            raise UsdAhdError(f"native Embree backend unavailable: {_ERROR}")
        self._lib = lib
        # Embree reads vertices with 16-byte loads: pad one vertex at the end.
        v = np.zeros((len(points) + 1, 3), np.float32)
        v[: len(points)] = points
        self._verts = v
        self._tris = np.ascontiguousarray(triangles, dtype=np.uint32)
        self._device = lib.rtcNewDevice(None)
        if not self._device:
            raise RuntimeError("rtcNewDevice failed")
        self._scene = lib.rtcNewScene(self._device)
        if robust:
            lib.rtcSetSceneFlags(self._scene, RTC_SCENE_FLAG_ROBUST)
        lib.rtcSetSceneBuildQuality(self._scene, RTC_BUILD_QUALITY_MEDIUM)
        geom = lib.rtcNewGeometry(self._device, RTC_GEOMETRY_TYPE_TRIANGLE)
        lib.rtcSetSharedGeometryBuffer(
            geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, v.ctypes.data, 0, 12, len(points)
        )
        lib.rtcSetSharedGeometryBuffer(
            geom,
            RTC_BUFFER_TYPE_INDEX,
            0,
            RTC_FORMAT_UINT3,
            self._tris.ctypes.data,
            0,
            12,
            len(self._tris),
        )
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(self._scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        err = lib.rtcGetDeviceError(self._device)
        if err:
            raise RuntimeError(f"Embree error {err} while building the scene")
        self.handle = int(self._scene)

    def close(self):
        if getattr(self, "_scene", None):
            self._lib.rtcReleaseScene(self._scene)
            self._scene = None
        if getattr(self, "_device", None):
            self._lib.rtcReleaseDevice(self._device)
            self._device = None
        self.handle = 0

    def __del__(self):  # pragma: no cover - GC timing
        try:
            self.close()
        except Exception:
            pass


# ---------------------------------------------------------------------- numba side
from numba import njit, types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from usdahd.bake.kernels import cache  # noqa: E402, F401  (numba cache locators, before any @njit)
from usdahd.bake.kernels.cache import helper  # noqa: E402
from usdahd.bake.kernels.layout import (  # noqa: E402
    HIT_NG,
    HIT_T,
    HIT_TRI,
    HIT_U,
    HIT_V,
    RAY_D,
    RAY_O,
    RAY_TFAR,
    EmbreeHit,
)


def _extern_call(name):
    @intrinsic
    def call(typingctx, scene, ptr):
        sig = types.void(types.uint64, types.uint64)

        def codegen(context, builder, signature, args):
            from llvmlite import ir

            i8p = ir.IntType(8).as_pointer()
            fnty = ir.FunctionType(ir.VoidType(), [i8p, i8p, i8p])
            fn = cgutils.get_or_insert_function(builder.module, fnty, name)
            s = builder.inttoptr(args[0], i8p)
            p = builder.inttoptr(args[1], i8p)
            builder.call(fn, [s, p, ir.Constant(i8p, None)])
            return context.get_dummy_value()

        return sig, codegen

    return call


def _extern_packet_call(name):
    """``name(valid, scene, packet, NULL)`` (rtcIntersect16 / rtcOccluded16)."""

    @intrinsic
    def call(typingctx, valid, scene, ptr):
        sig = types.void(types.uint64, types.uint64, types.uint64)

        def codegen(context, builder, signature, args):
            from llvmlite import ir

            i8p = ir.IntType(8).as_pointer()
            fnty = ir.FunctionType(ir.VoidType(), [i8p, i8p, i8p, i8p])
            fn = cgutils.get_or_insert_function(builder.module, fnty, name)
            v, s, p = (builder.inttoptr(a, i8p) for a in args)
            builder.call(fn, [v, s, p, ir.Constant(i8p, None)])
            return context.get_dummy_value()

        return sig, codegen

    return call


_rtc_intersect1 = _extern_call("rtcIntersect1")
_rtc_occluded1 = _extern_call("rtcOccluded1")
_rtc_intersect16 = _extern_packet_call("rtcIntersect16")
_rtc_occluded16 = _extern_packet_call("rtcOccluded16")
_load()  # the JIT resolves rtcIntersect1/rtcOccluded1 from the permanently loaded library


def new_scratch() -> np.ndarray:
    """A 16-byte aligned RTCRayHit record, (RAYHIT_FLOATS,) float32 (one per thread)."""
    buf = np.zeros(RAYHIT_FLOATS + 4, np.float32)
    off = ((16 - (buf.ctypes.data % 16)) % 16) // 4
    return buf[off : off + RAYHIT_FLOATS]


@njit(cache=True, nogil=True)
def scratch():
    """:func:`new_scratch` inside numba code."""
    buf = np.empty(RAYHIT_FLOATS + 4, np.float32)
    off = ((16 - (buf.ctypes.data % 16)) % 16) // 4
    return buf[off : off + RAYHIT_FLOATS]


def new_packet() -> np.ndarray:
    """A 64-byte aligned packet scratch, (PACKET_FLOATS,) float32 (one per thread)."""
    buf = np.zeros(PACKET_FLOATS + 16, np.float32)
    off = ((64 - (buf.ctypes.data % 64)) % 64) // 4
    return buf[off : off + PACKET_FLOATS]


@helper
def _set_ray(rec, ox, oy, oz, dx, dy, dz, tfar):
    rec[0] = ox
    rec[1] = oy
    rec[2] = oz
    rec[3] = 0.0  # tnear
    rec[4] = dx
    rec[5] = dy
    rec[6] = dz
    rec[7] = 0.0  # time
    rec[8] = tfar
    iv = rec.view(np.uint32)
    iv[9] = 0xFFFFFFFF  # mask
    iv[10] = 0  # id
    iv[11] = 0  # flags


@helper
def intersect1(scene, rec, ox, oy, oz, dx, dy, dz, tfar):
    """Closest hit. rec : (RAYHIT_FLOATS,) float32 scratch (16-byte aligned).

    returns an :class:`~usdahd.bake.kernels.layout.EmbreeHit` (t float32, inf on miss;
    tri int64, -1 on miss; u, v float32).
    """
    _set_ray(rec, ox, oy, oz, dx, dy, dz, tfar)
    iv = rec.view(np.uint32)
    iv[18] = 0xFFFFFFFF  # geomID
    iv[19] = 0xFFFFFFFF  # instID[0]
    _rtc_intersect1(scene, rec.ctypes.data)
    if iv[18] == 0xFFFFFFFF:
        return EmbreeHit(np.float32(np.inf), np.int64(-1), np.float32(0.0), np.float32(0.0))
    return EmbreeHit(rec[8], np.int64(iv[17]), rec[15], rec[16])


@helper
def hit_normal(rec):
    """Unit geometric normal (Embree's ``Ng``, cross(v1 - v0, v2 - v0) direction) of the hit
    left in ``rec`` by :func:`intersect1` ((0, 0, 1) for a degenerate triangle)."""
    x, y, z = np.float64(rec[12]), np.float64(rec[13]), np.float64(rec[14])
    ln = np.sqrt(x * x + y * y + z * z)
    if ln > 0.0:
        return x / ln, y / ln, z / ln
    return 0.0, 0.0, 1.0


@helper
def occluded1(scene, rec, ox, oy, oz, dx, dy, dz, tfar):
    """True when anything lies along the ray in [0, tfar]."""
    _set_ray(rec, ox, oy, oz, dx, dy, dz, tfar)
    _rtc_occluded1(scene, rec.ctypes.data)
    return rec[8] == -np.inf


_f = np.float64


@njit(cache=True, nogil=True)
def intersect_batch(scene, o, d, tfar, t_out, prim_out, u_out, v_out):
    """Batch of closest hits (float32 arrays; o, d (m,3), tfar (m,)) into the out arrays."""
    rec = scratch()
    for i in range(o.shape[0]):
        # float64 arguments (exact for float32 input): the specialisation the kernels use
        h = intersect1(
            scene, rec, _f(o[i, 0]), _f(o[i, 1]), _f(o[i, 2]), _f(d[i, 0]), _f(d[i, 1]),
            _f(d[i, 2]), _f(tfar[i]),
        )  # fmt: skip
        t_out[i] = h.t
        prim_out[i] = h.tri
        u_out[i] = h.u
        v_out[i] = h.v


@njit(cache=True, nogil=True)
def occluded_batch(scene, o, d, tfar, out):
    """Batch of shadow rays into ``out`` (m,) bool."""
    rec = scratch()
    for i in range(o.shape[0]):
        out[i] = occluded1(
            scene, rec, _f(o[i, 0]), _f(o[i, 1]), _f(o[i, 2]), _f(d[i, 0]), _f(d[i, 1]),
            _f(d[i, 2]), _f(tfar[i]),
        )  # fmt: skip


# ------------------------------------------------------------------ packets
# ``rays`` (m, RAY_COLS) float64 rows (``layout.RAY``): origin, unit direction, tfar (inf:
# unbounded); tnear 0. ``hits`` (m, HIT_COLS) float64 rows (``layout.HIT``).
# Rays are traced PACKET at a time from the packet scratch ``pk`` (:func:`new_packet`); a last
# packet with fewer than PACKET_MIN rays goes through the single-ray calls with ``rec``.


@helper
def _fill_packet(pk, rays, s0, cnt, with_hit):
    W = PACKET
    iv = pk.view(np.uint32)
    vi = pk.view(np.int32)
    for j in range(W):
        if j < cnt:
            r = s0 + j
            pk[j] = rays[r, RAY_O]
            pk[W + j] = rays[r, RAY_O + 1]
            pk[2 * W + j] = rays[r, RAY_O + 2]
            pk[3 * W + j] = 0.0
            pk[4 * W + j] = rays[r, RAY_D]
            pk[5 * W + j] = rays[r, RAY_D + 1]
            pk[6 * W + j] = rays[r, RAY_D + 2]
            pk[7 * W + j] = 0.0
            pk[8 * W + j] = rays[r, RAY_TFAR]
            iv[9 * W + j] = 0xFFFFFFFF
            iv[10 * W + j] = 0
            iv[11 * W + j] = 0
            if with_hit != 0:
                iv[18 * W + j] = 0xFFFFFFFF
                iv[19 * W + j] = 0xFFFFFFFF
            vi[22 * W + j] = -1
        else:
            vi[22 * W + j] = 0


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def intersect_rays(scene, pk, rec, rays, n, hits):
    """Closest hits of ``rays[:n]`` into ``hits[:n]`` ((m, HIT_COLS) float64 rows: t (inf on miss),
    triangle id (-1 on miss), u, v, unit geometric normal (0, 0, 1 on miss))."""
    W = PACKET
    iv = pk.view(np.uint32)
    for s0 in range(0, n, W):
        cnt = min(W, n - s0)
        if cnt < PACKET_MIN:
            for r in range(s0, n):
                h = intersect1(
                    scene, rec, rays[r, RAY_O], rays[r, RAY_O + 1], rays[r, RAY_O + 2],
                    rays[r, RAY_D], rays[r, RAY_D + 1], rays[r, RAY_D + 2], rays[r, RAY_TFAR],
                )  # fmt: skip
                hits[r, HIT_T] = h.t
                hits[r, HIT_TRI] = h.tri
                hits[r, HIT_U] = h.u
                hits[r, HIT_V] = h.v
                if h.tri >= 0:
                    hits[r, HIT_NG], hits[r, HIT_NG + 1], hits[r, HIT_NG + 2] = hit_normal(rec)
                else:
                    hits[r, HIT_NG], hits[r, HIT_NG + 1], hits[r, HIT_NG + 2] = 0.0, 0.0, 1.0
            break
        _fill_packet(pk, rays, s0, cnt, np.int64(1))
        _rtc_intersect16(pk[22 * W :].ctypes.data, scene, pk.ctypes.data)
        for j in range(cnt):
            r = s0 + j
            if iv[18 * W + j] == 0xFFFFFFFF:
                hits[r, HIT_T] = np.inf
                hits[r, HIT_TRI] = -1.0
                hits[r, HIT_U] = hits[r, HIT_V] = hits[r, HIT_NG] = hits[r, HIT_NG + 1] = 0.0
                hits[r, HIT_NG + 2] = 1.0
                continue
            hits[r, HIT_T] = pk[8 * W + j]
            hits[r, HIT_TRI] = iv[17 * W + j]
            hits[r, HIT_U] = pk[15 * W + j]
            hits[r, HIT_V] = pk[16 * W + j]
            x = np.float64(pk[12 * W + j])
            y = np.float64(pk[13 * W + j])
            z = np.float64(pk[14 * W + j])
            ln = np.sqrt(x * x + y * y + z * z)
            if ln > 0.0:
                hits[r, HIT_NG], hits[r, HIT_NG + 1], hits[r, HIT_NG + 2] = x / ln, y / ln, z / ln
            else:
                hits[r, HIT_NG], hits[r, HIT_NG + 1], hits[r, HIT_NG + 2] = 0.0, 0.0, 1.0


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def occluded_rays(scene, pk, rec, rays, n, out):
    """Shadow rays ``rays[:n]``: ``out[:n]`` (bool) True when anything lies in [0, tfar]."""
    W = PACKET
    for s0 in range(0, n, W):
        cnt = min(W, n - s0)
        if cnt < PACKET_MIN:
            for r in range(s0, n):
                out[r] = occluded1(
                    scene, rec, rays[r, RAY_O], rays[r, RAY_O + 1], rays[r, RAY_O + 2],
                    rays[r, RAY_D], rays[r, RAY_D + 1], rays[r, RAY_D + 2], rays[r, RAY_TFAR],
                )  # fmt: skip
            break
        _fill_packet(pk, rays, s0, cnt, np.int64(0))
        _rtc_occluded16(pk[22 * W :].ctypes.data, scene, pk.ctypes.data)
        for j in range(cnt):
            out[s0 + j] = pk[8 * W + j] == -np.inf
