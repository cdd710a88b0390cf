"""Native (libembree4 from numba) and reference (embreex + numpy) backends agree.

- Hits: the same random rays give the same triangle ids and distances (same library, same
  build flags; distances to float32 precision).
- Scalar numba ports (lights, textures) equal the numpy methods they mirror, to 1e-9 relative
  (float64 arithmetic in a different order; texture values are rounded to float32 by both).
- Bakes: the two backends use different random streams, so their per-texel estimates are
  independent; the difference of the means over N texels must be below
  SIGMAS * sqrt(se_a^2 + se_b^2) with se the measured standard errors (``stats.SIGMAS`` = 5:
  false failure < 1e-6; ``stats.assert_same_mean``).
"""

import numpy as np
import pytest
from numba import njit
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade
from stats import assert_same_mean

from usdahd.bake import embree_native
from usdahd.bake.integrate import bake_texels
from usdahd.bake.kernels import lights as K
from usdahd.bake.kernels.layout import NativeTables
from usdahd.bake.trace import Tracer, nb_texture, pack_textures
from usdahd.bake.types import Texels
from usdahd.errors import UsageError
from usdahd.numerics import sh
from usdahd.scene import lights as L
from usdahd.scene.types import Texture
from usdahd.usd.reader import load_scene

REL = 1e-9  # float64 scalar vs vectorized numpy: rounding-order differences only

pytestmark = pytest.mark.skipif(
    not embree_native.available(), reason="libembree4 not found next to embreex"
)


def _stage():
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    return st


def _quad(st, path, corners, material=None, st_uv=None):
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if st_uv is not None:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        pv.Set([Gf.Vec2f(*uv) for uv in st_uv])
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def _material(st, path, albedo=(0.5, 0.5, 0.5), emission=(0, 0, 0)):
    mat = UsdShade.Material.Define(st, path)
    s = UsdShade.Shader.Define(st, path + "/pbr")
    s.CreateIdAttr("UsdPreviewSurface")
    s.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*albedo))
    s.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emission))
    mat.CreateSurfaceOutput().ConnectToSource(s.ConnectableAPI(), "surface")
    return mat


def _box(st, path, lo, hi, material=None):
    """Closed outward-facing box."""
    m = UsdGeom.Mesh.Define(st, path)
    p = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    m.CreatePointsAttr(p)
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([i for q in quads for i in q])
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def _texels(points, normal=(0.0, 0.0, 1.0)):
    from usdahd.numerics.sampling import orthonormal_basis

    p = np.asarray(points, np.float32).reshape(-1, 3)
    n = len(p)
    nrm = np.asarray(normal, np.float64)
    frame = orthonormal_basis(nrm[None])[0]
    return Texels(
        (n, 1),
        np.zeros((n, 2), np.int32),
        p,
        np.tile(nrm, (n, 1)).astype(np.float32),
        np.tile(frame, (n, 1, 1)).astype(np.float32),
        np.zeros(n, np.int32),
        np.ones(n, bool),
    )


def _cluttered_stage():
    """Ground, two boxes and one light of every kind (uniform dome)."""
    st = _stage()
    grey = _material(st, "/mat/grey", albedo=(0.6, 0.5, 0.4))
    _quad(st, "/ground", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], grey)
    _box(st, "/b1", (0.5, -0.5, 0.0), (1.5, 0.5, 1.2), grey)
    _box(st, "/b2", (-2.0, 0.5, 0.0), (-1.0, 2.0, 0.6), _material(st, "/mat/w", (0.9,) * 3))
    r = UsdLux.RectLight.Define(st, "/rect")  # large and close: MIS weights far from 0/1
    r.CreateIntensityAttr(0.5)
    r.CreateWidthAttr(4.0)
    r.CreateHeightAttr(3.0)
    UsdGeom.Xformable(r).AddTranslateOp().Set(Gf.Vec3d(-0.5, -0.5, 1.3))
    k = UsdLux.DiskLight.Define(st, "/disk")
    k.CreateIntensityAttr(2.0)
    UsdGeom.Xformable(k).AddTranslateOp().Set(Gf.Vec3d(2.5, -1.0, 2.0))
    c = UsdLux.CylinderLight.Define(st, "/tube")
    c.CreateIntensityAttr(1.0)
    UsdGeom.Xformable(c).AddTranslateOp().Set(Gf.Vec3d(-1.5, -2.0, 0.8))
    p = UsdLux.SphereLight.Define(st, "/point")
    p.CreateTreatAsPointAttr(True)
    p.CreateIntensityAttr(5.0)
    UsdGeom.Xformable(p).AddTranslateOp().Set(Gf.Vec3d(-1.0, 1.0, 1.5))
    d = UsdLux.DistantLight.Define(st, "/delta_sun")
    d.CreateAngleAttr(0.0)
    d.CreateIntensityAttr(0.7)
    UsdGeom.Xformable(d).AddRotateXOp().Set(-30.0)
    s = UsdLux.SphereLight.Define(st, "/bulb")
    s.CreateRadiusAttr(0.2)
    s.CreateIntensityAttr(20.0)
    UsdGeom.Xformable(s).AddTranslateOp().Set(Gf.Vec3d(1.5, 1.5, 1.5))
    sun = UsdLux.DistantLight.Define(st, "/sun")
    sun.CreateIntensityAttr(2.0)
    UsdGeom.Xformable(sun).AddRotateYOp().Set(-35.0)
    UsdLux.DomeLight.Define(st, "/sky").CreateIntensityAttr(0.2)
    return st


# ----------------------------------------------------------------------------- hits


def test_backends_give_the_same_hits():
    scene = load_scene(_cluttered_stage())
    nat = Tracer(scene, backend="native")
    ref = Tracer(scene, backend="embreex")
    assert nat.backend == "native" and ref.backend == "embreex"
    rng = np.random.default_rng(0)
    m = 40000  # above THREAD_MIN_RAYS: both thread halves are exercised
    o = rng.uniform([-4, -4, 0.01], [4, 4, 3], (m, 3))
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tfar = np.where(rng.random(m) < 0.5, np.inf, rng.uniform(0.1, 5, m))
    a, b = nat.intersect(o, d, tfar), ref.intersect(o, d, tfar)
    np.testing.assert_array_equal(a["tri"], b["tri"])
    hit = a["tri"] >= 0
    assert 0.2 < hit.mean() < 0.95
    np.testing.assert_array_equal(a["t"][hit], b["t"][hit])
    np.testing.assert_array_equal(a["u"][hit], b["u"][hit])
    np.testing.assert_array_equal(nat.occluded(o, d, tfar), ref.occluded(o, d, tfar))
    assert nat.rays_traced == ref.rays_traced == 2 * m


@pytest.mark.parametrize("m", [1, 2, 3, 16, 17, 18, 35, 4099])
def test_packets_give_the_same_hits_as_single_rays(m):
    """16-ray packets (and their single-ray tails) against rtcIntersect1 / rtcOccluded1: the
    same triangles; distances, barycentrics and normals to float32 rounding (Embree's packet
    and single-ray kernels order the float operations differently)."""
    scene = load_scene(_cluttered_stage())
    tr = Tracer(scene, backend="native")
    rng = np.random.default_rng(m)
    o = rng.uniform([-4, -4, 0.01], [4, 4, 3], (m, 3))
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tfar = np.where(rng.random(m) < 0.5, np.inf, rng.uniform(0.1, 5, m))
    rays = np.c_[o, d, tfar]
    hits = np.full((m, 7), np.nan)
    pk, rec = embree_native.new_packet(), embree_native.new_scratch()
    assert pk.ctypes.data % 64 == 0 and len(pk) == embree_native.PACKET_FLOATS
    embree_native.intersect_rays(tr.native_handle, pk, rec, rays, m, hits)
    ref = tr.intersect(o, d, tfar)
    np.testing.assert_array_equal(hits[:, 1].astype(np.int64), ref["tri"])
    hit = ref["tri"] >= 0
    assert np.all(np.isinf(hits[~hit, 0]))
    np.testing.assert_allclose(hits[hit, 0], ref["t"][hit], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(hits[hit, 2], ref["u"][hit], atol=1e-5)
    np.testing.assert_allclose(hits[hit, 3], ref["v"][hit], atol=1e-5)
    gn = tr.geom_normal[ref["tri"][hit]]
    np.testing.assert_allclose(hits[hit, 4:7], gn, atol=1e-5)
    occ = np.zeros(m, bool)
    embree_native.occluded_rays(tr.native_handle, pk, rec, rays, m, occ)
    np.testing.assert_array_equal(occ, tr.occluded(o, d, tfar))


def test_unknown_backend_is_a_usage_error():
    scene = load_scene(_cluttered_stage())
    with pytest.raises(UsageError, match="backend"):
        Tracer(scene, backend="optix")


# ----------------------------------------------------------------------------- scalar ports


@njit(cache=False)
def _nb_lights(kind, par, img, pmf, cdf, p, u, d, t, do_sample):
    m = p.shape[0]
    smp = np.zeros((m, 8))
    isc = np.zeros((m, 5))
    pdf = np.zeros(m)
    for i in range(m):
        if do_sample:
            smp[i] = K.light_sample(
                kind, par, img, pmf, cdf, p[i, 0], p[i, 1], p[i, 2], u[i, 0], u[i, 1]
            )
        h, tt, r, g, b = K.light_intersect(
            kind, par, img, p[i, 0], p[i, 1], p[i, 2], d[i, 0], d[i, 1], d[i, 2]
        )
        isc[i] = (1.0 if h else 0.0, tt, r, g, b)
        pdf[i] = K.light_pdf(
            kind, par, pmf, p[i, 0], p[i, 1], p[i, 2], d[i, 0], d[i, 1], d[i, 2], t[i]
        )
    return smp, isc, pdf  # fmt: skip


def _all_lights():
    img = np.random.default_rng(5).random((8, 16, 3)).astype(np.float32) + 0.1
    img[1:3, 4:6] = 20.0
    rot = np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0]])
    return [
        L.SphereLight("/s", np.array([1.0, 2, 3]), center=np.array([0.3, 0.1, 2.0]), radius=0.4),
        L.PointLight("/p", np.array([2.0, 1, 1]), center=np.array([0.3, -0.4, 1.0])),
        L.RectLight("/r", np.ones(3), center=np.array([0, 0, 1.5]), ex=np.array([0.6, 0, 0.1]),
                    ey=np.array([0, 0.3, 0]), normal=np.array([0, 0, -1.0])),
        L.RectLight("/rshear", np.ones(3), center=np.array([0, 0, 1.5]),
                    ex=np.array([0.6, 0, 0.1]), ey=np.array([0.2, 0.3, 0]),
                    normal=np.array([0, 0, -1.0])),
        L.RectLight("/rnear", np.ones(3), center=np.array([0, 0, 0.35]),
                    ex=np.array([2.0, 0, 0]), ey=np.array([0, 1.5, 0]),
                    normal=np.array([0, 0, -1.0])),
        L.DiskLight("/d", np.ones(3), center=np.array([0.2, 0, 1.0]), ex=np.array([0.5, 0, 0]),
                    ey=np.array([0, 0.4, 0]), normal=np.array([0, 0, -1.0])),
        L.CylinderLight("/c", np.ones(3), center=np.array([0, 0, 1.0]),
                        axis=np.array([1.0, 0, 0]), half_length=0.7, radius=0.2),
        L.DistantLight("/sun", np.ones(3), direction=np.array([0, 0.6, 0.8]), half_angle=0.2),
        L.DistantLight("/dsun", np.ones(3), direction=np.array([0.6, 0, 0.8]), half_angle=0.0),
        L.DomeLight("/dome", np.array([0.5, 1, 2])),
        L.DomeLight("/tdome", np.array([0.5, 1, 2]), image=img, rotation=rot),
    ]  # fmt: skip


@pytest.mark.parametrize("light", _all_lights(), ids=lambda lt: lt.path)
def test_numba_lights_equal_numpy(light):
    rng = np.random.default_rng(1)
    m = 3000
    p = rng.uniform(-1, 1, (m, 3)) * [1, 1, 0.3]
    u = rng.random((m, 2))
    tab = K.pack_lights([light])
    if light.sampled:
        d_s, dist, val, pdf = light.sample(p, u)
    else:  # a uniform dome is never sampled (hemisphere sampling covers it)
        d_s = rng.normal(size=(m, 3))
    # intersect/pdf queried along the sampled directions (hits) and random ones (misses)
    d = np.where(rng.random((m, 1)) < 0.5, d_s, rng.normal(size=(m, 3)))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hit, t, rad = light.intersect(p, d)
    smp, isc, npdf = _nb_lights(
        tab.kind[0], tab.par[0], tab.img, tab.pmf, tab.cdf, p, u, d, np.where(hit, t, np.inf),
        light.sampled,
    )  # fmt: skip
    if light.sampled:
        np.testing.assert_allclose(smp[:, 0:3], d_s, rtol=REL, atol=REL)
        np.testing.assert_allclose(smp[:, 3], dist, rtol=REL)
        np.testing.assert_allclose(smp[:, 4:7], val, rtol=REL, atol=REL)
        np.testing.assert_allclose(smp[:, 7], pdf, rtol=REL)
    np.testing.assert_array_equal(isc[:, 0] > 0, hit)
    np.testing.assert_allclose(isc[:, 1][hit], t[hit], rtol=REL)
    np.testing.assert_allclose(isc[:, 2:5], rad, rtol=REL, atol=REL)
    ph = light.pdf(p[hit], d[hit], t[hit])
    np.testing.assert_allclose(npdf[hit], ph, rtol=REL)


@njit(cache=False)
def _nb_tex(tb, k, uv):
    out = np.zeros((uv.shape[0], 4))
    for i in range(uv.shape[0]):
        v, n = nb_texture(tb, k, uv[i, 0], uv[i, 1])
        out[i] = v
    return out


@pytest.mark.parametrize("channels", [(0, 1, 2), (3,), (1,), (0, 1, 2, 3)])
@pytest.mark.parametrize("c", [1, 2, 3, 4])
@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror"])
def test_numba_texture_equals_texture_sample(channels, c, wrap):
    rng = np.random.default_rng(c)
    tex = Texture(
        "t.exr",
        rng.random((5, 7, c)).astype(np.float32),
        np.array([1.0, 0.5, 2.0, 1.0]),
        np.array([0.0, 0.1, 0.0, -0.2]),
        channels,
        (wrap, wrap),
    )
    uv = rng.uniform(-1.5, 2.5, (500, 2))
    tb = NativeTables(*(None,) * 7, *pack_textures([tex]))
    got = _nb_tex(tb, 0, uv)[:, : len(channels)]
    np.testing.assert_allclose(got, tex.sample(uv), rtol=1e-6, atol=1e-6)


# ----------------------------------------------------------------------------- bakes


def _agree(a, b):
    """Means of two independent per-texel estimate sets agree within SIGMAS combined SEs."""
    assert_same_mean(a, b, rel=1e-6, atol=1e-9)  # slack: float32 accumulation


def _bake_both(scene, tex, **kw):
    out = {}
    for backend in ("native", "embreex"):
        tr = Tracer(scene, backend=backend)
        out[backend], _ = bake_texels(scene, tr, tex, **kw)
        tr.close()
    return out["native"], out["embreex"]


@pytest.mark.parametrize("point", [(0.0, -1.0, 0.0), (1.0, 1.0, 0.6)])
def test_backends_bake_the_same_light(point):
    """Every light kind, NEE + MIS, 2 bounces and Russian roulette (bounces=5)."""
    scene = load_scene(_cluttered_stage())
    tex = _texels(np.tile(point, (256, 1)))
    a, b = _bake_both(scene, tex, samples=64, bounces=5, estimator="mc", seed=3)
    for c in range(3):
        _agree(sh.iz(a)[:, c], sh.iz(b)[:, c])
        for k in (1, 2, 3, 8):  # directional coefficients too
            _agree(a[:, c, k], b[:, c, k])


def test_backends_bake_the_same_textures_and_cutouts():
    """Textured albedo and emission, an alpha cut-out and stochastic opacity."""
    st = _stage()
    ground = _material(st, "/mat/ground")
    _quad(st, "/ground", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], ground,
          st_uv=[(0, 0), (4, 0), (4, 4), (0, 4)])  # fmt: skip
    leaf = _material(st, "/mat/leaf")
    _quad(st, "/leaf", [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)], leaf,
          st_uv=[(0, 0), (1, 0), (1, 1), (0, 1)])  # fmt: skip
    veil = _material(st, "/mat/veil", emission=(0.5, 0.2, 0.1))
    _quad(st, "/veil", [(-3, 2, 2), (-3, -2, 2), (-2, -2, 2), (-2, 2, 2)], veil,
          st_uv=[(0, 0), (1, 0), (1, 1), (0, 1)])  # fmt: skip
    sun = UsdLux.DistantLight.Define(st, "/sun")
    sun.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(20.0)
    UsdLux.DomeLight.Define(st, "/sky").CreateIntensityAttr(0.3)
    scene = load_scene(st)
    names = [m.name for m in scene.materials]
    rng = np.random.default_rng(0)
    checker = np.kron((np.indices((4, 4)).sum(0) % 2), np.ones((4, 4)))[..., None]
    one = np.ones(4)
    g = scene.materials[next(i for i, n in enumerate(names) if n.endswith("ground"))]
    g.albedo_tex = Texture("g.exr", rng.random((6, 6, 3)).astype(np.float32), one, 0 * one,
                           (0, 1, 2))  # fmt: skip
    lf = scene.materials[next(i for i, n in enumerate(names) if n.endswith("leaf"))]
    lf.opacity_tex = Texture("a.exr", checker.astype(np.float32), one, 0 * one, (0,))
    lf.opacity_threshold = 0.5
    vl = scene.materials[next(i for i, n in enumerate(names) if n.endswith("veil"))]
    vl.opacity = 0.4  # stochastic transmission
    vl.emission_tex = Texture("e.exr", rng.random((3, 3, 1)).astype(np.float32), one, 0 * one,
                              (0, 1, 2))  # fmt: skip
    pts = np.c_[rng.uniform(-2, 1, (256, 2)), np.zeros(256)]
    tex = _texels(pts)
    a, b = _bake_both(scene, tex, samples=32, bounces=2, estimator="mc", seed=1)
    for c in range(3):
        _agree(sh.iz(a)[:, c], sh.iz(b)[:, c])


def test_native_bake_deterministic_and_thread_independent():
    scene = load_scene(_cluttered_stage())
    tex = _texels(np.tile((0.0, -1.0, 0.0), (40, 1)))
    outs = []
    for threads in (1, 2, 2):
        tr = Tracer(scene, threads=threads, backend="native")
        outs.append(bake_texels(scene, tr, tex, samples=16, bounces=2, seed=9)[0])
        tr.close()
    np.testing.assert_array_equal(outs[0], outs[1])
    np.testing.assert_array_equal(outs[1], outs[2])


@pytest.mark.parametrize("regression", [False, True])
def test_native_result_equals_numpy_result(regression):
    """The per-texel 9x9 solve on the threads equals ``Accum.result`` (float32 output)."""
    from usdahd.bake.kernels.integrate import native_result
    from usdahd.bake.reference import Accum

    rng = np.random.default_rng(4)
    n = 50
    acc = Accum(n)
    y = rng.normal(size=(n, 40, 9))
    acc.gram[:] = np.matmul(y.transpose(0, 2, 1), y)
    acc.hemi[:] = rng.normal(size=(n, 3, 9))
    acc.nee[:] = rng.normal(size=(n, 3, 9))
    acc.delta[:] = rng.normal(size=(n, 3, 9))
    acc.count[:] = rng.integers(1, 40, n)
    acc.back[:] = rng.integers(0, 5, n)
    ref, bf_ref = acc.result("regression" if regression else "mc")
    out = np.empty((n, 3, 9), np.float32)
    bf = np.empty(n, np.float32)
    native_result(np.arange(n), acc.gram, acc.hemi, acc.nee, acc.delta, acc.count, acc.back,
                   regression, out, bf)  # fmt: skip
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-5)  # float32 rounding
    np.testing.assert_array_equal(bf, bf_ref)


def test_kernel_cache_tracks_every_inlined_source():
    """numba only re-validates a cached function against its own file; the fused kernel
    inlines code from several modules, so its cache stamp must cover all of them."""
    from usdahd.bake.kernels import cache, integrate

    if not cache.CACHE_TRACKS_ALL_SOURCES:
        pytest.skip("numba caching internals changed")
    loc = integrate.native_pass._cache._impl.locator
    assert isinstance(loc, cache._KernelStampMixin)
    names = {s[0] for s in loc.get_source_stamp()}
    assert {"trace.py", "lights.py", "integrate.py", "embree_native.py", "reference.py"} <= names
    assert {"layout.py", "sampling.py", "sh.py"} <= names
