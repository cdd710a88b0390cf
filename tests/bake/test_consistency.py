"""Classic path-tracer consistency tests on a stage with interreflection (issue 17).

Three unbiased estimators of the same incident radiance — light sampling only (``nee``), BSDF
(hemisphere/cosine) sampling only (``bsdf``) and their MIS combination (``mis``, the default) —
must agree, and so must the regression SH estimator and plain Monte Carlo projection. A wrong
MIS weight, a pdf that disagrees with its sampler, a light counted twice or missed by one
strategy, or an estimator bias all show up as a disagreement.

Tolerance: two estimators bake the same N_TEX texels with independent random streams; they
agree when the mean per-texel difference is below SIGMAS = 5 standard errors of that mean (from
the sample variance of the differences, so spatial variation cancels; ``stats.assert_mean``),
plus 1e-6 relative float slack. A false failure is a < 1e-6 event per comparison. Power:
halving the light pdf in the BSDF-side MIS weight (a 10 % bias of the floor's Iz here) fails the
floor case at 5.6 sigma; the lights are large and close so that MIS weights are far from 0 and 1.
"""

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdLux

from tests.scenes import define_quad, preview_material
from tests.stats import assert_mean
from usdahd.bake.integrate import bake_texels
from usdahd.bake.trace import Tracer
from usdahd.bake.types import Texels
from usdahd.errors import UsageError
from usdahd.numerics import sh
from usdahd.usd.reader import load_scene

N_TEX = 96


def _room():
    """A closed 4 x 4 x 3 m room (inward faces, albedo 0.7/0.5) lit by a down-facing RectLight
    under the ceiling, a SphereLight near the floor, a DiskLight on a wall and an emissive
    panel: every area-light kind, interreflection, and an indirect-only ceiling."""
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    wall = preview_material(st, "/mat/wall", (0.7, 0.7, 0.7))
    floor = preview_material(st, "/mat/floor", (0.5, 0.4, 0.3))
    a, h = 2.0, 3.0
    define_quad(st, "/floor", [(-a, -a, 0), (a, -a, 0), (a, a, 0), (-a, a, 0)], floor)
    define_quad(st, "/ceiling", [(-a, -a, h), (-a, a, h), (a, a, h), (a, -a, h)], wall)
    define_quad(st, "/wx0", [(-a, -a, 0), (-a, a, 0), (-a, a, h), (-a, -a, h)], wall)
    define_quad(st, "/wx1", [(a, -a, 0), (a, -a, h), (a, a, h), (a, a, 0)], wall)
    define_quad(st, "/wy0", [(-a, -a, 0), (-a, -a, h), (a, -a, h), (a, -a, 0)], wall)
    define_quad(st, "/wy1", [(-a, a, 0), (a, a, 0), (a, a, h), (-a, a, h)], wall)
    panel = preview_material(st, "/mat/panel", (0.0, 0.0, 0.0), emission=(3.0, 2.0, 1.0))
    y = a - 1e-3  # just in front of the +y wall, facing -y
    define_quad(st, "/panel", [(-0.8, y, 0.8), (0.8, y, 0.8), (0.8, y, 1.8), (-0.8, y, 1.8)], panel)
    r = UsdLux.RectLight.Define(st, "/rect")  # emits along its -Z: down
    r.CreateIntensityAttr(1.5)
    r.CreateWidthAttr(2.0)
    r.CreateHeightAttr(1.2)
    UsdGeom.Xformable(r).AddTranslateOp().Set(Gf.Vec3d(0.3, -0.2, h - 0.6))
    s = UsdLux.SphereLight.Define(st, "/lamp")
    s.CreateRadiusAttr(0.35)
    s.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(s).AddTranslateOp().Set(Gf.Vec3d(-1.0, 0.8, 0.6))
    d = UsdLux.DiskLight.Define(st, "/disk")
    d.CreateRadiusAttr(0.6)
    d.CreateIntensityAttr(1.5)
    x = UsdGeom.Xformable(d)
    x.AddTranslateOp().Set(Gf.Vec3d(a - 0.02, 0.5, 2.0))
    x.AddRotateYOp().Set(90.0)  # its -Z -> -X: into the room
    return st


def _texels(points, normal):
    p = np.asarray(points, np.float32)
    n = len(p)
    nrm = np.asarray(normal, np.float64)
    from usdahd.numerics.sampling import orthonormal_basis

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


def _agree(a, b, what):
    """Paired comparison at the same texels (independent streams): the mean per-texel
    difference is zero within SIGMAS standard errors of that mean (spatial variation cancels)."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    assert_mean(d, 0.0, atol=1e-6 * abs(np.mean(b)) + 1e-12, what=what)  # atol: float32 sums


@pytest.fixture(scope="module")
def room():
    return load_scene(_room())


def _targets():
    rng = np.random.default_rng(11)
    floor = np.c_[rng.uniform(-1.8, 1.8, (N_TEX, 2)), np.zeros(N_TEX)]
    ceiling = np.c_[rng.uniform(-1.8, 1.8, (N_TEX, 2)), np.full(N_TEX, 3.0)]
    return {"floor": _texels(floor, (0, 0, 1)), "ceiling": _texels(ceiling, (0, 0, -1))}


def _bake(scene, backend, tex, **kw):
    tr = Tracer(scene, backend=backend)
    try:
        out, _ = bake_texels(scene, tr, tex, samples=32, estimator="mc", **kw)
    finally:
        tr.close()
    return out


@pytest.mark.parametrize("backend", ["native", "embreex"])
@pytest.mark.parametrize("where", ["floor", "ceiling"])
def test_nee_bsdf_and_mis_agree(room, backend, where):
    tex = _targets()[where]
    est = {
        s: _bake(room, backend, tex, strategy=s, seed=i)
        for i, s in enumerate(("mis", "bsdf", "nee"))
    }
    for other in ("bsdf", "nee"):
        for c in range(3):
            _agree(sh.iz(est[other])[:, c], sh.iz(est["mis"])[:, c], (where, other, "Iz", c))
            for k in (1, 3, 6):  # directional coefficients too
                _agree(est[other][:, c, k], est["mis"][:, c, k], (where, other, k, c))


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_regression_estimator_agrees_with_plain_projection(room, backend):
    tex = _targets()["ceiling"]
    mc = _bake(room, backend, tex, seed=21)
    tr = Tracer(room, backend=backend)
    reg, _ = bake_texels(room, tr, tex, samples=32, estimator="regression", seed=22)
    tr.close()
    for c in range(3):
        _agree(sh.iz(reg)[:, c], sh.iz(mc)[:, c], ("Iz", c))
        for k in range(9):
            _agree(reg[:, c, k], mc[:, c, k], (k, c))


def test_unknown_strategy_is_a_usage_error(room):
    tex = _targets()["floor"]
    with pytest.raises(UsageError, match="light strategy"):
        _bake(room, "native", tex, strategy="nope")
