"""UsdLux light linking and shadow linking in the integrator (issue 13), against analytic values.

A DistantLight of illuminance E at normal incidence gives a texel facing it I_z = E cos / pi
(exact: delta light, one shadow ray); a uniform DomeLight of radiance 1 gives I_z = 1 on an
unoccluded upward texel. Both backends run every case (stages with linking take the numpy
shading path on the native tracer as well). Delta-light cases are exact to FLOAT_TOL.
"""

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from usdahd.bake.integrate import bake_texels
from usdahd.bake.trace import Tracer
from usdahd.bake.types import Texels
from usdahd.numerics import sh
from usdahd.usd.reader import load_scene

FLOAT_TOL = 2e-5


def _stage():
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    mat = UsdShade.Material.Define(st, "/mat/black")
    s = UsdShade.Shader.Define(st, "/mat/black/pbr")
    s.CreateIdAttr("UsdPreviewSurface")
    s.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    mat.CreateSurfaceOutput().ConnectToSource(s.ConnectableAPI(), "surface")
    return st, mat


def _quad(st, path, z, half, mat):
    m = UsdGeom.Mesh.Define(st, path)
    h = half
    m.CreatePointsAttr([Gf.Vec3f(-h, -h, z), Gf.Vec3f(h, -h, z), Gf.Vec3f(h, h, z),
                        Gf.Vec3f(-h, h, z)])  # fmt: skip
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(mat)


def _sun(st, path="/Sun", intensity=2.0):
    sun = UsdLux.DistantLight.Define(st, path)
    sun.CreateIntensityAttr(intensity)
    sun.CreateAngleAttr(0.0)
    return sun


def _texels(n=8):
    p = np.zeros((n, 3), np.float32)
    p[:, 0] = np.linspace(-0.3, 0.3, n)
    return Texels(
        (n, 1),
        np.zeros((n, 2), np.int32),
        p,
        np.tile([0, 0, 1.0], (n, 1)).astype(np.float32),
        np.tile(np.eye(3), (n, 1, 1)).astype(np.float32),
        np.zeros(n, np.int32),
        np.ones(n, bool),
    )


def _bake(st, backend, mesh_path, **kw):
    scene = load_scene(st)
    index = {m.path: i for i, m in enumerate(scene.meshes)}
    tr = Tracer(scene, backend=backend)
    try:
        out, _ = bake_texels(scene, tr, _texels(), samples=64, bounces=0, mesh=index[mesh_path],
                             **kw)  # fmt: skip
    finally:
        tr.close()
    return sh.iz(out)[:, 0]


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_light_link_excludes_the_ground(backend):
    st, mat = _stage()
    _quad(st, "/Ground", 0.0, 5.0, mat)
    _quad(st, "/Wall", -1.0, 0.5, mat)  # another mesh (below the ground, not in the way)
    sun = _sun(st)
    link = UsdLux.LightAPI(sun.GetPrim()).GetLightLinkCollectionAPI()
    link.GetExcludesRel().AddTarget("/Ground")
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 0.0, atol=FLOAT_TOL)
    # the same light without the exclusion lights it: E / pi at normal incidence
    st2, mat2 = _stage()
    _quad(st2, "/Ground", 0.0, 5.0, mat2)
    _quad(st2, "/Wall", -1.0, 0.5, mat2)
    _sun(st2)
    np.testing.assert_allclose(_bake(st2, backend, "/Ground"), 2.0 / np.pi, rtol=FLOAT_TOL)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_light_link_include_list_and_other_lights_unaffected(backend):
    st, mat = _stage()
    _quad(st, "/Ground", 0.0, 5.0, mat)
    _quad(st, "/Wall", -1.0, 0.5, mat)
    sun = _sun(st)
    link = UsdLux.LightAPI(sun.GetPrim()).GetLightLinkCollectionAPI()
    link.GetIncludeRootAttr().Set(False)
    link.GetIncludesRel().AddTarget("/Wall")  # lights the wall only
    _sun(st, "/Fill", intensity=0.5)  # default collection: lights everything
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 0.5 / np.pi, rtol=FLOAT_TOL)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_shadow_link_lets_an_excluded_blocker_cast_no_shadow(backend):
    st, mat = _stage()
    _quad(st, "/Ground", 0.0, 5.0, mat)
    _quad(st, "/Blocker", 1.0, 1.0, mat)  # right above the texels
    sun = _sun(st)
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 0.0, atol=FLOAT_TOL)
    shadow = UsdLux.LightAPI(sun.GetPrim()).GetShadowLinkCollectionAPI()
    shadow.GetExcludesRel().AddTarget("/Blocker")
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 2.0 / np.pi, rtol=FLOAT_TOL)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_shadow_link_on_an_area_light(backend):
    """A uniform dome whose shadows the blocker does not cast: the texel sees the whole sky
    (I_z = 1). Uniform domes are reached by hemisphere rays only, so those must pass through
    the excluded blocker too; every texel is then exact (the sky is in the SH span)."""
    st, mat = _stage()
    _quad(st, "/Ground", 0.0, 5.0, mat)
    _quad(st, "/Blocker", 1.0, 1.0, mat)
    dome = UsdLux.DomeLight.Define(st, "/Sky")
    shadow = UsdLux.LightAPI(dome.GetPrim()).GetShadowLinkCollectionAPI()
    shadow.GetExcludesRel().AddTarget("/Blocker")
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 1.0, atol=1e-4)
    shadow.GetExcludesRel().ClearTargets(True)  # the blocker casts again: the sky is partly hidden
    assert _bake(st, backend, "/Ground").max() < 0.9
