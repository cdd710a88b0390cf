"""Native (libembree4 from numba) and reference (embreex + numpy) backends agree.

- Hits: the same random rays give the same triangle ids and distances (same library, same
  build flags; distances to float32 precision).
- The scalar numba ports (lights, textures, the 9x9 solve) are checked against their numpy
  twins in tests/bake/test_kernel_parity.py.
- Bakes: the two backends use different random streams, so their per-texel estimates are
  independent; the difference of the means over N texels must be below
  SIGMAS * sqrt(se_a^2 + se_b^2) with se the measured standard errors (``stats.SIGMAS`` = 5:
  false failure < 1e-6; ``stats.assert_same_mean``).
"""

import numpy as np
import pytest
from numba import njit
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from tests.stats import assert_same_mean
from usdahd.bake.integrate import bake_texels
from usdahd.bake.kernels import embree
from usdahd.bake.kernels.trace import nb_transmittance_rays
from usdahd.bake.trace import Tracer
from usdahd.bake.types import Texels
from usdahd.errors import UsageError
from usdahd.numerics import sh
from usdahd.scene.types import Texture
from usdahd.usd.reader import load_scene

REL = 1e-9  # float64 scalar vs vectorized numpy: rounding-order differences only

pytestmark = pytest.mark.skipif(
    not embree.available(), reason="libembree4 not found next to embreex"
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


def test_a_fork_shares_the_bvh_and_threads_and_counts_its_own_rays():
    """Prims traced at once each trace on a fork: the same hits from two threads at once as
    from the original, one ray count per fork, the original's untouched."""
    from concurrent.futures import ThreadPoolExecutor

    scene = load_scene(_cluttered_stage())
    tr = Tracer(scene, backend="native")
    a, b = tr.fork(), tr.fork()
    assert a._pool is tr._pool and a.native_tables() is tr.native_tables()
    rng = np.random.default_rng(1)
    m = 40000
    o = rng.uniform([-4, -4, 0.01], [4, 4, 3], (m, 3))
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    want = tr.intersect(o, d)["tri"]
    with ThreadPoolExecutor(2) as pool:
        got = list(pool.map(lambda t: t.intersect(o, d)["tri"], [a, b]))
    for g in got:
        np.testing.assert_array_equal(g, want)
    assert (a.rays_traced, b.rays_traced, tr.rays_traced) == (m, m, m)
    b.occluded(o[:10], d[:10], np.full(10, np.inf))
    assert (a.rays_traced, b.rays_traced, tr.rays_traced) == (m, m + 10, m)
    tr.close()


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
    pk, rec = embree.new_packet(), embree.new_scratch()
    assert pk.ctypes.data % 64 == 0 and len(pk) == embree.PACKET_FLOATS
    embree.intersect_rays(tr.native_handle, pk, rec, rays, m, hits)
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
    embree.occluded_rays(tr.native_handle, pk, rec, rays, m, occ)
    np.testing.assert_array_equal(occ, tr.occluded(o, d, tfar))


def test_unknown_backend_is_a_usage_error():
    scene = load_scene(_cluttered_stage())
    with pytest.raises(UsageError, match="backend"):
        Tracer(scene, backend="optix")


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


@pytest.mark.parametrize("point", [(0.0, -1.0, 0.0), (1.0, 1.0, 0.6)])
def test_backends_bake_the_same_linked_light(point):
    """UsdLux light and shadow linking (issue 38: the native kernel runs linked stages):
    lights that skip the receiving ground, light only a box, or whose shadows a box does not
    cast, on the ground texels (the receiver) and along 5-bounce paths (receivers: the
    vertices' meshes). Both backends against each other, NEE + MIS."""
    st = _cluttered_stage()
    ground, b1 = Sdf.Path("/ground"), Sdf.Path("/b1")
    for path, coll, how in [
        ("/rect", "lightLink", "exclude_ground"),
        ("/bulb", "lightLink", "only_b1"),
        ("/point", "lightLink", "exclude_ground"),
        ("/sun", "shadowLink", "exclude_b1"),
        ("/rect", "shadowLink", "exclude_b1"),
        ("/sky", "shadowLink", "exclude_b1"),
    ]:
        api = UsdLux.LightAPI(st.GetPrimAtPath(path))
        c = api.GetLightLinkCollectionAPI() if coll == "lightLink" else (
            api.GetShadowLinkCollectionAPI())  # fmt: skip
        if how == "only_b1":
            c.GetIncludeRootAttr().Set(False)
            c.GetIncludesRel().AddTarget(b1)
        else:
            c.GetExcludesRel().AddTarget(ground if how == "exclude_ground" else b1)
    scene = load_scene(st)
    mesh = [m.path for m in scene.meshes].index("/ground")
    assert {lt.path for lt in scene.lights if lt.lit_meshes is not None} == {
        "/rect", "/bulb", "/point"
    }  # fmt: skip
    tex = _texels(np.tile(point, (256, 1)))
    a, b = _bake_both(scene, tex, samples=64, bounces=5, estimator="mc", seed=3, mesh=mesh)
    for c in range(3):
        _agree(sh.iz(a)[:, c], sh.iz(b)[:, c])
        for k in (1, 2, 3, 8):
            _agree(a[:, c, k], b[:, c, k])
    # and the linking matters here: the same stage unlinked bakes another light
    c, _ = _bake_both(load_scene(_cluttered_stage()), tex, samples=64, bounces=5,
                      estimator="mc", seed=3, mesh=mesh)  # fmt: skip
    assert abs(sh.iz(c)[:, 1].mean() - sh.iz(a)[:, 1].mean()) > 0.05 * sh.iz(c)[:, 1].mean()


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


def test_kernel_cache_tracks_every_inlined_source():
    """numba only re-validates a cached function against its own file; the fused kernel
    inlines code from several modules, so its cache stamp must cover all of them."""
    from usdahd.bake.kernels import cache, integrate

    if not cache.CACHE_TRACKS_ALL_SOURCES:
        pytest.skip("numba caching internals changed")
    loc = integrate.native_pass._cache._impl.locator
    assert isinstance(loc, cache._KernelStampMixin)
    names = {s[0] for s in loc.get_source_stamp()}
    assert {"trace.py", "lights.py", "integrate.py", "embree.py", "reference.py"} <= names
    assert {"layout.py", "sampling.py", "sh.py"} <= names


# ----------------------------------------------------------------------------- shadow rays


def _veiled_scene():
    """A ground with, above it, a veil of constant opacity 0.3 (z = 1), a cut-out checker
    (threshold 0.5, z = 2) over x < 0 and an opaque roof over y > 2 (z = 3)."""
    st = _stage()
    _quad(st, "/ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], _material(st, "/m/g"))
    _quad(st, "/veil", [(-4, -4, 1), (4, -4, 1), (4, 4, 1), (-4, 4, 1)], _material(st, "/m/veil"))
    _quad(st, "/cut", [(-4, -4, 2), (0, -4, 2), (0, 4, 2), (-4, 4, 2)], _material(st, "/m/cut"),
          st_uv=[(0, 0), (1, 0), (1, 1), (0, 1)])  # fmt: skip
    _quad(st, "/roof", [(-4, 2, 3), (4, 2, 3), (4, 4, 3), (-4, 4, 3)], _material(st, "/m/roof"))
    sun = UsdLux.DistantLight.Define(st, "/sun")  # overhead, a delta light of 2 lux
    sun.CreateIntensityAttr(2.0)
    sun.CreateAngleAttr(0.0)
    scene = load_scene(st)
    names = [m.name for m in scene.materials]
    mat = {n.rsplit("/", 1)[-1]: scene.materials[i] for i, n in enumerate(names)}
    mat["veil"].opacity = 0.3
    checker = np.kron((np.indices((4, 4)).sum(0) % 2), np.ones((4, 4)))[..., None]
    one = np.ones(4)
    mat["cut"].opacity_tex = Texture("a.exr", checker.astype(np.float32), one, 0 * one, (0,))
    mat["cut"].opacity_threshold = 0.5
    k = next(i for i, m in enumerate(scene.meshes) if m.path == "/cut")
    w = scene.meshes[k].points[scene.meshes[k].triangles]  # (t, 3, 3) corners
    while len(scene.texcoords) <= k:
        scene.texcoords.append({})
    scene.texcoords[k]["st"] = np.stack([(w[..., 0] + 4) / 4, (w[..., 1] + 4) / 8], -1).astype(
        np.float32
    )
    return scene


def _expected_transmittance(o):
    """Straight-up rays from points o (m, 3) at z = 0.5: 0.7 through the veil, times the
    checker's hole (1) or card (0) for x < 0, 0 under the roof."""
    x, y = o[:, 0], o[:, 1]
    s, t = (x + 4) / 4, (y + 4) / 8  # the cut-out's texcoords (image row 0 at t = 1)
    card = (np.floor(s * 16).astype(int) // 4 + np.floor((1 - t) * 16).astype(int) // 4) % 2
    hole = np.where(x < 0, card == 0, True)
    return np.where(y > 2, 0.0, 0.7 * hole)


@njit(cache=False)
def _nb_transmittance(scene, pk, rec, tb, rays):
    out = np.zeros(rays.shape[0])
    nb_transmittance_rays(scene, pk, rec, tb, True, rays, rays.shape[0], out)
    return out


def test_shadow_rays_carry_the_transmittance_of_what_they_cross():
    """Tracer.transmittance: the product of 1 - opacity over fractional-opacity surfaces, 1
    through cut-out holes, 0 behind cards and opaque surfaces; both backends alike; the
    expectation of the stochastic pass-through (Tracer.occluded) it replaces."""
    scene = _veiled_scene()
    rng = np.random.default_rng(0)
    # keep clear of the checker's cell edges (texture filtering is nearest: 1/16 cells)
    x = (rng.integers(0, 32, 2000) + rng.uniform(0.2, 0.8, 2000)) / 4 - 4
    y = (rng.integers(0, 32, 2000) + rng.uniform(0.2, 0.8, 2000)) / 4 - 4
    o = np.c_[x, y, np.full(2000, 0.5)]
    d = np.tile([0.0, 0, 1], (2000, 1))
    want = _expected_transmittance(o)
    assert 0.1 < (want == 0.7).mean() < 0.9 and (want == 0).any()
    for backend in ("native", "embreex"):
        tr = Tracer(scene, backend=backend)
        got = tr.transmittance(o, d, np.full(2000, np.inf))
        np.testing.assert_allclose(got, want, atol=1e-6)
        # a light below the veil: nothing in between
        np.testing.assert_array_equal(tr.transmittance(o, d, np.full(2000, 0.4)), 1.0)
        if backend == "native":
            tb = tr.native_tables()
            rays = np.c_[o, d, np.full(2000, np.inf)]
            pk, rec = embree.new_packet(), embree.new_scratch()
            nb = _nb_transmittance(tr.native_handle, pk, rec, tb, rays)
            np.testing.assert_allclose(nb, got, rtol=REL, atol=1e-12)
        tr.close()
    # the stochastic pass-through it replaces has the same mean (the numpy path draws from
    # ``rng``; 200 draws: 5 sigma of a Bernoulli(0.7) mean)
    tr = Tracer(scene, backend="embreex")
    occ = np.mean([~tr.occluded(o, d, np.full(2000, np.inf), rng=np.random.default_rng(k))
                   for k in range(200)], axis=0)  # fmt: skip
    assert np.abs(occ - want).max() < 5 * np.sqrt(0.7 * 0.3 / 200)
    tr.close()


def test_a_veiled_sun_bakes_its_exact_attenuated_irradiance():
    """Delta sun through a 0.3-opacity veil: I_z is exactly 0.7 x 2 / pi on the open ground
    (a deterministic shadow ray: no coin-flip noise), on both backends."""
    scene = _veiled_scene()
    pts = np.c_[np.random.default_rng(1).uniform(0.5, 3.5, (64, 2)) * [1, 0.4], np.zeros(64)]
    tex = _texels(pts)
    for backend in ("native", "embreex"):
        tr = Tracer(scene, backend=backend)
        res, _ = bake_texels(scene, tr, tex, samples=16, bounces=0, seed=2)
        tr.close()
        np.testing.assert_allclose(sh.iz(res)[:, 1], 0.7 * 2.0 / np.pi, rtol=1e-5)
