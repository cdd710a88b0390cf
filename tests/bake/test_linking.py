"""UsdLux light linking and shadow linking in the integrator (issue 13), against analytic values.

A DistantLight of illuminance E at normal incidence gives a texel facing it I_z = E cos / pi
(exact: delta light, one shadow ray); a uniform DomeLight of radiance 1 gives I_z = 1 on an
unoccluded upward texel. Both backends run every case (stages with linking take the numpy
shading path on the native tracer as well). Delta-light cases are exact to FLOAT_TOL.
"""

import numpy as np
import pytest
from pxr import UsdLux

from tests.scenes import define_quad, distant_light, new_stage, preview_material, square
from usdahd.bake.integrate import bake_texels
from usdahd.bake.trace import Tracer
from usdahd.bake.types import Texels
from usdahd.numerics import sh
from usdahd.usd.reader import load_scene

FLOAT_TOL = 2e-5


def _stage():
    """A Z-up stage and its black material (no bounce light: the sun alone lights a texel)."""
    st = new_stage()
    return st, preview_material(st, "/mat/black", (0, 0, 0), emission=None)


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
    define_quad(st, "/Ground", square(0.0, 5.0), mat)
    define_quad(st, "/Wall", square(-1.0, 0.5), mat)  # another mesh, below the ground
    sun = distant_light(st, "/Sun", intensity=2.0)
    link = UsdLux.LightAPI(sun.GetPrim()).GetLightLinkCollectionAPI()
    link.GetExcludesRel().AddTarget("/Ground")
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 0.0, atol=FLOAT_TOL)
    # the same light without the exclusion lights it: E / pi at normal incidence
    st2, mat2 = _stage()
    define_quad(st2, "/Ground", square(0.0, 5.0), mat2)
    define_quad(st2, "/Wall", square(-1.0, 0.5), mat2)
    distant_light(st2, "/Sun", intensity=2.0)
    np.testing.assert_allclose(_bake(st2, backend, "/Ground"), 2.0 / np.pi, rtol=FLOAT_TOL)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_light_link_include_list_and_other_lights_unaffected(backend):
    st, mat = _stage()
    define_quad(st, "/Ground", square(0.0, 5.0), mat)
    define_quad(st, "/Wall", square(-1.0, 0.5), mat)
    sun = distant_light(st, "/Sun", intensity=2.0)
    link = UsdLux.LightAPI(sun.GetPrim()).GetLightLinkCollectionAPI()
    link.GetIncludeRootAttr().Set(False)
    link.GetIncludesRel().AddTarget("/Wall")  # lights the wall only
    distant_light(st, "/Fill", intensity=0.5)  # default collection: lights everything
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 0.5 / np.pi, rtol=FLOAT_TOL)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_shadow_link_lets_an_excluded_blocker_cast_no_shadow(backend):
    st, mat = _stage()
    define_quad(st, "/Ground", square(0.0, 5.0), mat)
    define_quad(st, "/Blocker", square(1.0, 1.0), mat)  # right above the texels
    sun = distant_light(st, "/Sun", intensity=2.0)
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
    define_quad(st, "/Ground", square(0.0, 5.0), mat)
    define_quad(st, "/Blocker", square(1.0, 1.0), mat)
    dome = UsdLux.DomeLight.Define(st, "/Sky")
    shadow = UsdLux.LightAPI(dome.GetPrim()).GetShadowLinkCollectionAPI()
    shadow.GetExcludesRel().AddTarget("/Blocker")
    np.testing.assert_allclose(_bake(st, backend, "/Ground"), 1.0, atol=1e-4)
    shadow.GetExcludesRel().ClearTargets(True)  # the blocker casts again: the sky is partly hidden
    assert _bake(st, backend, "/Ground").max() < 0.9
