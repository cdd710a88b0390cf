"""Every numba kernel function against its numpy twin (issue 12; design.md: "Every numba kernel
has a numpy twin with the same named fields and a parity test").

Tolerances, with their reason:

- ``REL`` = 1e-9 relative: a scalar float64 port of a vectorized numpy expression evaluates the
  same formula in a different order (numpy's einsum/matmul sum order, ``np.clip`` vs min/max),
  so results differ by a few ulp, amplified at most by the conditioning of arcsin/sqrt near
  their domain edges (lights); 1e-9 leaves ~1e6 ulp of room and still catches a wrong slot or
  sign, which shows at O(1).
- Bit for bit: where twin and port perform the same float64 operations in the same order (the
  MIS weights, the ray offset, the SH basis), results are compared bit for bit.
- Textures: 1e-6, both round the texel value to float32.
- The 9x9 solve: 1e-5, the output is float32 and LU with partial pivoting (numba) vs LAPACK's
  ``gesv`` (numpy) round differently.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from numba import njit

from usdahd.bake import reference as R
from usdahd.bake.kernels import integrate as KI
from usdahd.bake.kernels import lights as K
from usdahd.bake.kernels import shading as KS
from usdahd.bake.kernels.layout import (
    LIGHT_PARAMS,
    MODE_BSDF,
    MODE_MIS,
    MODE_NEE,
    NativeTables,
)
from usdahd.bake.kernels.trace import nb_offset, nb_texture
from usdahd.bake.trace import Tracer, pack_textures
from usdahd.numerics import sh
from usdahd.numerics.offsets import FLT_EPS, OFFSET_ULPS, triangle_offset_scale
from usdahd.numerics.sampling import orthonormal_basis, sample_discrete, to_world
from usdahd.scene import lights as L
from usdahd.scene.types import Texture

REL = 1e-9  # float64 scalar vs vectorized numpy: rounding-order differences only

#: integrate.STRATEGIES order -> kernel mode
MODES = {"mis": MODE_MIS, "bsdf": MODE_BSDF, "nee": MODE_NEE}


def _unit(rng, m):
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- lights


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
    tex_data, tex_info, tex_chan, tex_sb = pack_textures([tex])
    fields = dict(tex_data=tex_data, tex_info=tex_info, tex_chan=tex_chan, tex_sb=tex_sb)
    tb = NativeTables(**{f: fields.get(f) for f in NativeTables._fields})
    got = _nb_tex(tb, 0, uv)[:, : len(channels)]
    np.testing.assert_allclose(got, tex.sample(uv), rtol=1e-6, atol=1e-6)


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
    native_result(np.arange(n), acc.arrays, regression, out, bf)
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-5)  # float32 rounding
    np.testing.assert_array_equal(bf, bf_ref)


# ----------------------------------------------------------------------------- small helpers
@njit(cache=False)
def _nb_sh9(d):
    out = np.zeros((d.shape[0], 9))
    Y = np.zeros(9)
    for i in range(d.shape[0]):
        KI._sh9(Y, d[i, 0], d[i, 1], d[i, 2])
        out[i] = Y
    return out


def test_sh9_equals_sh_basis():
    """The kernel's SH basis (texel light samples, delta lights) is :func:`usdahd.sh.basis`:
    the same products of the same constants in the same order: bit-identical."""
    d = _unit(np.random.default_rng(0), 2000)
    np.testing.assert_array_equal(_nb_sh9(d), sh.basis(d))


@njit(cache=False)
def _nb_offsets(scale, p, ng, d):
    out = np.zeros_like(p)
    for i in range(p.shape[0]):
        out[i] = nb_offset(scale[i], p[i, 0], p[i, 1], p[i, 2], ng[i, 0], ng[i, 1], ng[i, 2],
                           d[i, 0], d[i, 1], d[i, 2])  # fmt: skip
    return out


def test_triangle_offset_scale_is_ulps_of_the_largest_coordinate():
    v = np.array([[[1.0, -2.0, 0.5], [0.0, 0.0, 0.0], [0.0, 4.0, 0.0]], [[0, 0, 0]] * 3])
    np.testing.assert_allclose(
        triangle_offset_scale(v), [OFFSET_ULPS * FLT_EPS * 4.0, OFFSET_ULPS * FLT_EPS * 1e-30]
    )
    assert triangle_offset_scale(np.zeros((0, 3, 3))).shape == (0,)


def test_nb_offset_equals_tracer_offset():
    """``nb_offset`` is :meth:`Tracer.offset` for one ray (both sides, and d . ng = 0 which
    both send to the +ng side); same operations in the same order: bit-identical."""
    rng = np.random.default_rng(1)
    m = 1000
    p = rng.uniform(-50, 50, (m, 3))
    ng = _unit(rng, m)
    d = _unit(rng, m)
    ng[:10], d[:10] = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]  # tangent: d . ng exactly 0
    # per-point offsets (a triangle's or a texel's), some below the point's own ulp floor
    scale = rng.uniform(0.0, 2e-4, m)
    tr = SimpleNamespace(offset_eps=3e-5)
    tr.offset_scale = lambda p, sc=None: Tracer.offset_scale(tr, p, sc)
    ref = Tracer.offset(tr, p, ng, d, scale)
    np.testing.assert_array_equal(_nb_offsets(scale, p, ng, d), ref)
    moved = np.linalg.norm(ref - p, axis=1)
    floor = OFFSET_ULPS * FLT_EPS * np.abs(p).max(axis=1)
    np.testing.assert_allclose(moved, np.maximum(scale, floor), rtol=1e-9)
    assert (scale < floor).any() and (scale > floor).any()


@njit(cache=False)
def _nb_frames(n, loc):
    out = np.zeros_like(loc)
    for i in range(n.shape[0]):
        out[i] = K.nb_basis_apply(n[i, 0], n[i, 1], n[i, 2], loc[i, 0], loc[i, 1], loc[i, 2])
    return out


def test_nb_basis_apply_equals_to_world_orthonormal_basis():
    """The kernel's Duff et al. frame is :func:`usdahd.numerics.sampling.orthonormal_basis`."""
    rng = np.random.default_rng(2)
    n = _unit(rng, 2000)
    n[:4] = [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, -1.0, 0]]
    loc = _unit(rng, 2000)
    ref = to_world(loc, orthonormal_basis(n))
    np.testing.assert_allclose(_nb_frames(n, loc), ref, rtol=REL, atol=REL)


@njit(cache=False)
def _nb_cones(axis, omc, u):
    out = np.zeros((axis.shape[0], 3))
    for i in range(axis.shape[0]):
        out[i] = K._cone(axis[i, 0], axis[i, 1], axis[i, 2], omc[i], u[i, 0], u[i, 1])
    return out


def test_cone_equals_scene_cone_dirs():
    """The kernel's cone sampler (sphere and distant lights) is ``scene.lights.cone_dirs``,
    down to tiny cones (1 - cos = 1e-12, the stable form both use)."""
    rng = np.random.default_rng(3)
    m = 2000
    axis = _unit(rng, m)
    omc = 10.0 ** rng.uniform(-12, 0.3, m)
    u = rng.random((m, 2))
    ref = L.cone_dirs(axis, omc, u)
    np.testing.assert_allclose(_nb_cones(axis, omc, u), ref, rtol=REL, atol=REL)


@njit(cache=False)
def _nb_weights(mode, pa, pb):
    wl = np.zeros(pa.shape[0])
    wb = np.zeros(pa.shape[0])
    for i in range(pa.shape[0]):
        wl[i] = KS.w_light(mode, pa[i], pb[i])
        wb[i] = KS.w_bsdf(mode, pb[i], pa[i])
    return wl, wb


@pytest.mark.parametrize("strategy", sorted(MODES))
def test_mis_weights_equal_reference(strategy):
    """``_wl``/``_wb`` (power heuristic, or the strategy's 0/1 weights) are the reference's
    ``_w_light``/``_w_bsdf``, including both pdfs zero (weight 0): bit-identical."""
    rng = np.random.default_rng(4)
    pa = rng.exponential(size=500)
    pb = rng.exponential(size=500)
    pa[:5] = pb[:5] = 0.0
    pa[5:10] = 0.0
    wl, wb = _nb_weights(MODES[strategy], pa, pb)
    np.testing.assert_array_equal(wl, R._w_light(strategy, pa, pb))
    np.testing.assert_array_equal(wb, R._w_bsdf(strategy, pb, pa))


@njit(cache=False)
def _nb_shadows(o, p, d, dist):
    out = np.zeros((o.shape[0], 4))
    for i in range(o.shape[0]):
        out[i] = KS.shadow1(o[i, 0], o[i, 1], o[i, 2], p[i, 0], p[i, 1], p[i, 2],
                             d[i, 0], d[i, 1], d[i, 2], dist[i])  # fmt: skip
    return out


def test_shadow1_equals_reference_shadow():
    """``shading.shadow1`` is the reference's ``_shadow`` (finite lights aimed at the sampled point
    and shortened, infinite ones keep d)."""
    rng = np.random.default_rng(5)
    m = 1000
    p = rng.uniform(-1, 1, (m, 3))
    d = _unit(rng, m)
    o = p + 1e-4 * _unit(rng, m)
    dist = rng.uniform(0.1, 5.0, m)
    dist[::7] = np.inf
    dirs, tfar = R._shadow(o, p, d, dist)
    got = _nb_shadows(o, p, d, dist)
    np.testing.assert_allclose(got[:, :3], dirs, rtol=REL, atol=REL)
    np.testing.assert_allclose(got[:, 3], tfar, rtol=REL)


@njit(cache=False)
def _nb_search(cdf, base, n, u):
    out = np.zeros(u.shape[0], np.int64)
    for i in range(u.shape[0]):
        out[i] = K.search_right(cdf, base, n, u[i])
    return out


def test_search_right_equals_sample_discrete():
    """The kernels' table lookup (dome pixels, emissive triangles) is
    :func:`usdahd.numerics.sampling.sample_discrete` on one block: integers, exact."""
    rng = np.random.default_rng(6)
    pmf = rng.random(37)
    pmf[[3, 4, 20]] = 0.0  # empty bins are never chosen
    cdf = np.cumsum(pmf) / pmf.sum()
    table = np.r_[rng.random(5), cdf, rng.random(4)]  # the block at offset 5
    u = np.r_[rng.random(2000), 0.0, cdf[:5], 1.0 - 1e-16]
    np.testing.assert_array_equal(_nb_search(table, 5, len(cdf), u), sample_discrete(cdf, u))


# ----------------------------------------------------------------------------- kernel helpers


def test_helper_called_from_python_raises_instead_of_crashing():
    """Helpers have no Python entry point (``cache.helper``, compile time): a call from Python
    raises TypeError naming the function and the fix, even once compiled for a numba caller."""
    from usdahd.bake.kernels.cache import HelperDispatcher

    assert isinstance(KS.power, HelperDispatcher)
    with pytest.raises(TypeError, match=r"shading\.power is a numba kernel helper .* @njit"):
        KS.power(1.0, 2.0)

    @njit(cache=False)
    def call(a, b):
        return KS.power(a, b)

    assert call(1.0, 1.0) == 0.5  # from numba code it works
    with pytest.raises(TypeError, match="call it from @njit code"):
        KS.power(1.0, 1.0)  # now compiled for (float64, float64): still no call from Python


def test_helpers_compile_one_specialisation_per_argument_types():
    """Constant indices are passed as int64 values (``trace._I0``..), not literals (compile
    time): a literal 1 would compile ``_bary`` for the type ``Literal[int](1)`` of its own."""
    from usdahd.bake.kernels import trace as T

    tc = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)

    @njit(cache=False)
    def second(a, u, v):
        return T._bary(a, np.int64(1), u, v, T._I1)

    w0 = 1.0 - 0.25 - 0.5
    assert second(tc, 0.25, 0.5) == w0 * tc[1, 0, 1] + 0.25 * tc[1, 1, 1] + 0.5 * tc[1, 2, 1]
    assert T._bary.signatures
    assert [sig for sig in T._bary.signatures if any("Literal" in str(a) for a in sig)] == []


# ----------------------------------------------------------------------------- light selection


@njit(cache=False)
def _nb_importance(par, p):
    out = np.zeros(p.shape[0])
    for i in range(p.shape[0]):
        out[i] = K.light_importance(par, p[i, 0], p[i, 1], p[i, 2])
    return out


def _emissive_light():
    """Two emissive triangles of different power, as ``EmissiveTriangles`` (no tracer)."""
    v = np.array([[[0, 0, 2.0], [1, 0, 2], [0, 1, 2]], [[3, 0, 0.0], [3, 1, 0], [3, 0, 1]]])
    area = np.full(2, 0.5)
    lum = np.array([4.0, 0.5])
    return L.EmissiveTriangles("<emissive triangles>", np.ones(3), tri=np.arange(2), verts=v,
                               area=area, lum=lum)  # fmt: skip


@pytest.mark.parametrize("light", _all_lights() + [_emissive_light()], ids=lambda lt: lt.path)
def test_numba_light_importance_equals_bound(light):
    rng = np.random.default_rng(3)
    p = rng.uniform(-2, 2, (2000, 3))
    b = light.bound()
    par = np.zeros(K.N_PAR)
    par[K.PAR_IMP_FALLOFF], par[K.PAR_IMP_SCALE], par[K.PAR_IMP_R2] = b.falloff, b.scale, b.r2
    par[K.PAR_IMP_CAP] = b.cap
    par[K.PAR_IMP_CENTER : K.PAR_IMP_CENTER + 3] = b.center
    par[K.PAR_IMP_NORMAL : K.PAR_IMP_NORMAL + 3] = b.normal
    if not isinstance(light, L.EmissiveTriangles):  # pack_lights writes the same slots
        imp = np.zeros(K.N_PAR, bool)
        for f in ("imp_falloff", "imp_scale", "imp_r2", "imp_cap", "imp_center", "imp_normal"):
            o = LIGHT_PARAMS.offset[f]
            imp[o : o + LIGHT_PARAMS.width[f]] = True
        np.testing.assert_array_equal(K.pack_lights([light]).par[0][imp], par[imp])
    np.testing.assert_allclose(_nb_importance(par, p), b.importance(p), rtol=REL)
    assert np.all(b.importance(p) >= 0)


@njit(cache=False)
def _nb_selection(par, nee_idx, p, u):
    m, n = p.shape[0], nee_idx.shape[0]
    q = np.zeros(m, np.int64)
    ps = np.zeros(m)
    sel = np.zeros((m, n))
    for i in range(m):
        q[i], ps[i] = KS.nee_pick(par, nee_idx, p[i, 0], p[i, 1], p[i, 2], u[i])
        for j in range(n):
            sel[i, j] = KS.nee_sel(par, nee_idx, nee_idx[j], p[i, 0], p[i, 1], p[i, 2])
    return q, ps, sel


def test_vertex_light_selection_equals_selection_pmf():
    """The kernel's pick and MIS selection pdf at a vertex are ``scene.lights.selection_pmf``:
    the same probabilities, the pick an inverse-CDF draw of them (so NEE and the MIS weight
    of a BSDF ray that hits the light use one distribution)."""
    lights = _all_lights()
    tab = K.pack_lights(lights)
    nee_idx = np.array([3, 0, 7, 8, 6, 1], np.int64)  # any subset, in any order
    rng = np.random.default_rng(4)
    p = rng.uniform(-2, 2, (4000, 3))
    u = rng.random(len(p))
    pmf = L.selection_pmf([lights[k].bound() for k in nee_idx], p, R.LIGHT_SELECTION_FLOOR)
    q, ps, sel = _nb_selection(tab.par, nee_idx, p, u)
    np.testing.assert_allclose(sel, pmf, rtol=REL)
    np.testing.assert_allclose(pmf.sum(axis=1), 1.0, rtol=1e-12)
    assert pmf.min() >= R.LIGHT_SELECTION_FLOOR / len(nee_idx) * (1 - 1e-12)
    col = np.minimum((u[:, None] >= np.cumsum(pmf, axis=1)).sum(axis=1), len(nee_idx) - 1)
    np.testing.assert_array_equal(q, nee_idx[col])
    np.testing.assert_allclose(ps, pmf[np.arange(len(p)), col], rtol=REL)


# ----------------------------------------------------------------------------- declared records


def test_light_rows_are_declared_per_kind_without_overlap():
    """Every light kind's fields (LIGHT_PARAMS, from each class's FIELDS) occupy disjoint
    slots inside the row, a field name has one offset for every kind, and the generated
    constants are those offsets."""
    from usdahd.bake.kernels import layout

    rec = layout.LIGHT_PARAMS
    assert set(rec.variants) == {cls.KIND for cls in L.PACKED_LIGHTS}
    for kind, names in rec.variants.items():
        slots = np.zeros(rec.size, int)
        for f in names:
            slots[rec.offset[f] : rec.offset[f] + rec.width[f]] += 1
        assert slots.max() == 1, kind
    for i, cls in enumerate(L.PACKED_LIGHTS):
        assert getattr(layout, "KIND_" + cls.KIND.upper()) == i
        for f, w in cls.FIELDS:
            assert getattr(layout, "PAR_" + f.upper()) == rec.offset[f] and rec.width[f] == w


def test_a_light_row_refuses_a_foreign_field_and_reports_a_missing_one():
    """A wrong slot is an error, not plausible wrong light: a kind's view refuses another
    kind's field, and packing raises when a declared field stays unwritten."""
    rec = LIGHT_PARAMS
    row = np.zeros(rec.size)
    view = rec.view(row, "sphere")
    view.radius = 0.5
    assert row[K.PAR_RADIUS] == 0.5
    with pytest.raises(AttributeError, match="no field 'ex'"):
        view.ex = np.ones(3)  # a rect light's field
    with pytest.raises(ValueError, match=r"sphere.*not written.*radius"):
        rec.pack(np.zeros(rec.size), "sphere", lambda v: setattr(v, "center", np.ones(3)))


def test_overlapping_declarations_are_refused():
    from usdahd.bake.kernels.layout import Row

    with pytest.raises(ValueError, match="widths"):
        Row.union("r", "R_", [("a", 1)], {"x": [("b", 3)], "y": [("b", 2)]})
    r = Row.union("r", "R_", [("a", 1)], {"x": [("b", 3), ("c", 1)], "y": [("c", 1), ("d", 2)]})
    assert r.offset["c"] not in range(r.offset["b"], r.offset["b"] + 3)
    assert r.offset["d"] not in (r.offset["c"], r.offset["c"] - 1)
