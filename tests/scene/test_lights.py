"""Light sampling consistency and the UsdLux unit rules as extracted from stages.

MC checks use tolerance stats.SIGMAS = 5 SE (the estimator's sample standard error); analytic
unit rules are exact to FLOAT_TOL.
"""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from tests.stats import assert_mean
from usdahd.errors import StageError
from usdahd.numerics import sh
from usdahd.scene import lights as L
from usdahd.usd.reader import load_scene

FLOAT_TOL = 1e-9
N = 100_000


def _mc_ok(vals, exact):
    assert_mean(vals, exact, rel=1e-9)  # rel: float64 rounding when the estimator is constant


def _lights():
    return [
        L.SphereLight("/s", np.ones(3), center=np.array([0.3, 0.1, 2.0]), radius=0.4),
        L.RectLight(
            "/r",
            np.ones(3),
            center=np.array([0, 0, 1.5]),
            ex=np.array([0.6, 0, 0]),
            ey=np.array([0, 0.3, 0]),
            normal=np.array([0, 0, -1.0]),
        ),
        L.RectLight(  # sheared: area sampling
            "/rshear",
            np.ones(3),
            center=np.array([0, 0, 1.5]),
            ex=np.array([0.6, 0, 0]),
            ey=np.array([0.2, 0.3, 0]),
            normal=np.array([0, 0, -1.0]),
        ),
        L.RectLight(  # close and large: solid angle near the upper bound
            "/rnear",
            np.ones(3),
            center=np.array([0.1, 0, 0.3]),
            ex=np.array([1.5, 0, 0]),
            ey=np.array([0, 1.2, 0]),
            normal=np.array([0, 0, -1.0]),
        ),
        L.RectLight(  # far: area sampling below the lower bound
            "/rfar",
            np.ones(3),
            center=np.array([0.5, 0, 30.0]),
            ex=np.array([0.2, 0, 0]),
            ey=np.array([0, 0.2, 0]),
            normal=np.array([0, 0, -1.0]),
        ),
        L.DiskLight(
            "/d",
            np.ones(3),
            center=np.array([0.2, 0, 1.0]),
            ex=np.array([0.5, 0, 0]),
            ey=np.array([0, 0.5, 0]),
            normal=np.array([0, 0, -1.0]),
        ),
        L.CylinderLight(
            "/c",
            np.ones(3),
            center=np.array([0, 0, 1.0]),
            axis=np.array([1.0, 0, 0]),
            half_length=0.7,
            radius=0.2,
        ),
        L.DistantLight("/sun", np.ones(3), direction=np.array([0, 0.6, 0.8]), half_angle=0.2),
    ]


@pytest.mark.parametrize("light", _lights(), ids=lambda lt: lt.path)
def test_sample_intersect_pdf_agree(light):
    rng = np.random.default_rng(0)
    p = np.zeros((2000, 3))
    d, dist, val, pdf = light.sample(p, rng.random((2000, 2)))
    ok = pdf > 0
    assert ok.mean() > 0.4
    hit, t, rad = light.intersect(p[ok], d[ok])
    assert hit.mean() > 0.999
    np.testing.assert_allclose(light.pdf(p[ok][hit], d[ok][hit], t[hit]), pdf[ok][hit], rtol=1e-6)
    if np.isfinite(dist[ok]).all():
        np.testing.assert_allclose(t[hit], dist[ok][hit], rtol=1e-6)


@pytest.mark.parametrize("light", _lights(), ids=lambda lt: lt.path)
def test_light_sampling_unbiased_against_quadrature(light):
    """E[value/pdf * cos] equals the quadrature of radiance*cos over directions that hit."""
    rng = np.random.default_rng(1)
    p = np.zeros((N, 3))
    d, _, val, pdf = light.sample(p, rng.random((N, 2)))
    est = np.where(pdf > 0, val[:, 0] * np.clip(d[:, 2], 0, None) / np.where(pdf > 0, pdf, 1), 0)
    if isinstance(light, L.RectLight):  # midpoint rule over the rectangle's area (any size)
        g = (np.arange(1000) + 0.5) / 500 - 1.0
        a, b = np.meshgrid(g, g)
        pts = light.center + a.reshape(-1, 1) * light.ex + b.reshape(-1, 1) * light.ey
        dist = np.linalg.norm(pts, axis=1)
        cos_r = np.clip(pts[:, 2] / dist, 0, None)
        cos_l = np.clip(-(pts @ light.normal) / dist, 0, None)
        exact = float(light.radiance[0] * (cos_r * cos_l / dist**2).mean() * light.area)
    else:
        q, w = sh.sphere_quadrature(600)  # light solid angles are small: fine rule, ~7e5 dirs
        hit, _, rad = light.intersect(np.zeros((len(q), 3)), q)
        exact = float((rad[:, 0] * np.clip(q[:, 2], 0, None) * hit) @ w)
    # the quadrature of an indicator has its own error, ~ boundary cells: allow 1 %
    assert_mean(est, exact, rel=0.01)


def test_dome_importance_sampling_pdf():
    img = np.ones((16, 32, 3), np.float32)
    img[2:5, 20:24] = 50.0  # a bright sun patch near the top
    dome = L.DomeLight("/dome", np.ones(3), image=img)
    q, w = sh.sphere_quadrature(256)
    pq = dome.pdf(np.zeros((len(q), 3)), q, None)
    np.testing.assert_allclose(pq @ w, 1.0, rtol=2e-3)  # piecewise-constant: cell edges
    d, _, val, pdf = dome.sample(np.zeros((N, 3)), np.random.default_rng(2).random((N, 2)))
    np.testing.assert_allclose(dome.pdf(np.zeros((N, 3)), d, None), pdf, rtol=1e-3)
    exact = float(dome.eval(q)[:, 0] @ w)
    _mc_ok(val[:, 0] / pdf, exact)


def test_dome_latlong_orientation():
    """OpenEXR latlong: column 0 = longitude +pi; longitude 0 = +Z, pi/2 = +X, top row = +Y."""
    img = np.zeros((8, 16, 3), np.float32)
    img[0, :] = 1.0  # top row
    img[4:6, 8] = 2.0  # column just right of the centre: longitude ~0 -> +Z
    img[4:6, 4] = 3.0  # longitude ~ +pi/2 -> +X
    dome = L.DomeLight("/dome", np.ones(3), image=img)
    ev = lambda v: dome.eval(np.array([v], float) / np.linalg.norm(v))[0, 0]
    assert ev([0, 1, 0]) == 1.0
    assert ev([-0.1, -0.1, 1]) == 2.0
    assert ev([1, -0.1, 0.0]) == 3.0


# ----------------------------------------------------------------------------- UsdLux units


def _stage_with(kind, **attrs):
    st = Usd.Stage.CreateInMemory()
    m = UsdGeom.Mesh.Define(st, "/g")
    m.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0)])
    m.CreateFaceVertexCountsAttr([3])
    m.CreateFaceVertexIndicesAttr([0, 1, 2])
    lt = getattr(UsdLux, kind).Define(st, "/light")
    for k, v in attrs.items():
        if k == "scale":
            UsdGeom.Xformable(lt).AddScaleOp().Set(Gf.Vec3f(*v))
        else:
            a = lt.GetPrim().GetAttribute(f"inputs:{k}")
            (a if a else lt.GetPrim().GetAttribute(k)).Set(v)
    return st


def _one_light(st):
    sc = load_scene(st)
    assert len(sc.lights) == 1
    return sc.lights[0], sc


def test_intensity_exposure_color_diffuse():
    lt, _ = _one_light(
        _stage_with(
            "SphereLight", intensity=3.0, exposure=2.0, color=Gf.Vec3f(1, 0.5, 0.25), diffuse=0.5
        )
    )
    np.testing.assert_allclose(lt.radiance, 3.0 * 4.0 * np.array([1, 0.5, 0.25]) * 0.5)


def test_color_temperature_multiplies():
    lt, _ = _one_light(
        _stage_with("DiskLight", enableColorTemperature=True, colorTemperature=3000.0)
    )
    np.testing.assert_allclose(lt.radiance, UsdLux.BlackbodyTemperatureAsRgb(3000.0), rtol=1e-6)


@pytest.mark.parametrize(
    "kind,area",
    [
        ("SphereLight", 4 * np.pi * (0.5 * 2) ** 2),
        ("RectLight", (1 * 2) * (1 * 2)),
        ("DiskLight", np.pi * (0.5 * 2) ** 2),
        ("CylinderLight", 2 * np.pi * (0.5 * 2) * (1 * 2)),
    ],
)
def test_normalize_divides_by_world_area(kind, area):
    lt, _ = _one_light(_stage_with(kind, normalize=True, intensity=10.0, scale=(2, 2, 2)))
    np.testing.assert_allclose(lt.radiance, 10.0 / area, rtol=1e-6)
    lt2, _ = _one_light(_stage_with(kind, normalize=False, intensity=10.0, scale=(2, 2, 2)))
    np.testing.assert_allclose(lt2.radiance, 10.0, rtol=1e-6)


def test_distant_normalize_and_fallbacks():
    lt, sc = _one_light(_stage_with("DistantLight"))  # nothing authored: schema fallbacks
    st0 = Usd.Stage.CreateInMemory()
    fb = UsdLux.DistantLight.Define(st0, "/x")
    inten = fb.GetIntensityAttr().Get()
    angle = fb.GetAngleAttr().Get()
    np.testing.assert_allclose(lt.radiance, inten)
    np.testing.assert_allclose(lt.half_angle, np.radians(angle) / 2)
    lt2, _ = _one_light(_stage_with("DistantLight", normalize=True, intensity=5.0))
    np.testing.assert_allclose(lt2.radiance * np.pi * np.sin(lt2.half_angle) ** 2, 5.0)
    lt3, sc3 = _one_light(_stage_with("DistantLight", angle=0.0, intensity=5.0))
    assert lt3.delta and any("angle 0" in w for w in sc3.warnings)


def test_sphere_treat_as_point():
    lt, _ = _one_light(_stage_with("SphereLight", treatAsPoint=True, radius=0.5, intensity=2.0))
    assert isinstance(lt, L.PointLight)
    np.testing.assert_allclose(lt.radiance, 2.0 * np.pi * 0.25)


@pytest.mark.parametrize("val", [-1.0, float("nan")])
def test_bad_intensity_names_the_light(val):
    with pytest.raises(StageError, match="/light"):
        load_scene(_stage_with("RectLight", intensity=val))


def test_unsupported_features_warn_once_each():
    st = _stage_with("SphereLight")
    prim = st.GetPrimAtPath("/light")
    sh_api = UsdLux.ShapingAPI.Apply(prim)
    sh_api.CreateShapingConeAngleAttr(30.0)
    sh_api.CreateShapingIesFileAttr(Sdf.AssetPath("x.ies"))
    UsdLux.LightAPI(prim).GetFiltersRel().AddTarget("/filter")
    dome = UsdLux.DomeLight.Define(st, "/dome")
    dome.GetPortalsRel().AddTarget("/portal")
    sc = load_scene(st)
    text = "\n".join(sc.warnings)
    for word in ("shaping", "IES", "filters", "portals"):
        assert word in text, (word, sc.warnings)
    assert len(sc.warnings) == len(set(sc.warnings))


# ----------------------------------------------------------------------------- light selection


def test_selection_favours_the_light_that_dominates_here():
    """``selection_pmf`` (which light a path vertex samples): near a small lamp the lamp, far
    from it the sun; behind a one-sided rect only the rect's floor share; every light keeps
    at least floor / n; a point light's bound is its exact irradiance at normal incidence."""
    lamp = L.SphereLight("/lamp", np.full(3, 50.0), center=np.array([0, 0, 0.5]), radius=0.05)
    sun = L.DistantLight("/sun", np.full(3, 3.0))  # delta: 3 lux at normal incidence
    rect = L.RectLight("/rect", np.full(3, 10.0), center=np.array([0, 0, 3.0]),
                       normal=np.array([0, 0, -1.0]))  # fmt: skip
    b = [lamp.bound(), sun.bound(), rect.bound()]
    p = np.array([[0, 0, 0.4], [20.0, 0, 0], [0, 0, 4.0]])
    pmf = L.selection_pmf(b, p, 0.1)
    assert pmf[0].argmax() == 0 and pmf[0, 0] > 0.8  # under the lamp
    assert pmf[1].argmax() == 1 and pmf[1, 1] > 0.8  # far away: the sun
    assert pmf[2, 2] == pytest.approx(0.1 / 3)  # behind the rect's emitting side
    assert np.all(pmf >= 0.1 / 3 - 1e-15) and np.allclose(pmf.sum(axis=1), 1.0)
    # the sphere's far field is its irradiance at normal incidence, pi r^2 L / d^2
    far = np.array([[0, 0, 10.5]])
    assert lamp.bound().importance(far)[0] == pytest.approx(np.pi * 0.05**2 * 50 / 100)
    pt = L.PointLight("/pt", np.full(3, 2.0), center=np.zeros(3))
    assert pt.bound().importance(np.array([[0, 0, 2.0]]))[0] == pytest.approx(0.5)
    # close to an emitter the bound stops at the irradiance of a hemisphere of it, pi L
    assert lamp.bound().importance(np.array([[0, 0, 0.5]]))[0] == pytest.approx(np.pi * 50)
    # no light has any importance here: uniform
    dark = L.SphereLight("/dark", np.zeros(3), center=np.zeros(3), radius=1.0)
    assert np.allclose(L.selection_pmf([dark.bound()] * 2, p, 0.1), 0.5)


def test_dome_bound_is_its_mean_irradiance():
    """A textured dome's bound: pi x its radiance x the image's mean luminance over the
    sphere (latlong rows weighted by sin theta), checked against brute-force quadrature."""
    rng = np.random.default_rng(2)
    img = rng.random((16, 32, 3)).astype(np.float32)
    dome = L.DomeLight("/dome", np.array([2.0, 2.0, 2.0]), image=img)
    d = rng.normal(size=(400000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    mean = (dome.eval(d) @ sh.LUMINANCE).mean()
    assert dome.bound().cap == pytest.approx(np.pi * mean, rel=5e-3)
