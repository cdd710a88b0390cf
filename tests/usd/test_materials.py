"""usdahd.usd.materials: the material table MaterialReader builds for a stage (bindings,
binding purposes, GeomSubsets, displayColor, UsdPreviewSurface constants and metallic), read
through the stage reader, and its helpers (tex_path, texture_channels, to_rgb)."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade

from tests.scenes import bind, define_mesh, define_quad, new_stage, preview_material, square
from usdahd.usd.materials import DEFAULT_ALBEDO, tex_path, texture_channels, to_rgb
from usdahd.usd.reader import load_scene

F32 = 1e-7  # authored float32 colours


def _albedos(scene, path):
    """Per triangle of mesh ``path``: the albedo of its material."""
    (md,) = [m for m in scene.meshes if m.path == path]
    return np.array([scene.materials[int(k)].albedo for k in md.material])


def test_bound_surface_display_color_and_the_default():
    st = new_stage()
    red = preview_material(st, "/mat/red", (0.8, 0.1, 0.1), emission=(0.0, 0.0, 2.0))
    define_quad(st, "/Bound", square(0.0), red)
    dc = define_quad(st, "/DisplayColor", square(1.0))
    dc.CreateDisplayColorAttr([Gf.Vec3f(0.2, 0.4, 0.6)])
    define_quad(st, "/Nothing", square(2.0))
    sc = load_scene(st)
    np.testing.assert_allclose(_albedos(sc, "/Bound"), [[0.8, 0.1, 0.1]] * 2, atol=F32)
    (md,) = [m for m in sc.meshes if m.path == "/Bound"]
    np.testing.assert_allclose(sc.materials[int(md.material[0])].emission, [0, 0, 2.0])
    np.testing.assert_allclose(_albedos(sc, "/DisplayColor"), [[0.2, 0.4, 0.6]] * 2, atol=F32)
    np.testing.assert_allclose(_albedos(sc, "/Nothing"), [DEFAULT_ALBEDO] * 2, atol=F32)


def test_geom_subsets_give_per_face_materials():
    st = new_stage()
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)]
    mesh = define_mesh(st, "/Two", pts, [(0, 1, 2, 3), (1, 4, 5, 2)])
    grey = preview_material(st, "/mat/grey", (0.5, 0.5, 0.5))
    bind(mesh, grey)  # the faces no subset names keep the prim's binding
    green = preview_material(st, "/mat/green", (0.1, 0.7, 0.1))
    sub = UsdGeom.Subset.CreateGeomSubset(
        UsdGeom.Imageable(mesh), "right", UsdGeom.Tokens.face, [1], "materialBind"
    )
    bind(sub, green)
    sc = load_scene(st)
    (md,) = sc.meshes
    alb = _albedos(sc, "/Two")
    np.testing.assert_allclose(alb[md.face == 0], [[0.5] * 3] * 2, atol=F32)
    np.testing.assert_allclose(alb[md.face == 1], [[0.1, 0.7, 0.1]] * 2, atol=F32)


def test_full_purpose_binding_wins_over_all_purpose():
    st = new_stage()
    preview = preview_material(st, "/mat/preview", (0.9, 0.9, 0.9))
    full = preview_material(st, "/mat/full", (0.3, 0.2, 0.1))
    quad = define_quad(st, "/Q", square(0.0))
    api = UsdShade.MaterialBindingAPI.Apply(quad.GetPrim())
    api.Bind(preview)
    api.Bind(full, materialPurpose=UsdShade.Tokens.full)
    np.testing.assert_allclose(_albedos(load_scene(st), "/Q"), [[0.3, 0.2, 0.1]] * 2, atol=F32)


def test_constant_metallic_scales_the_diffuse_albedo():
    """UsdPreviewSurface's diffuse lobe is weighted by 1 - metallic (the metal reflects
    specularly): albedo = diffuseColor x (1 - metallic)."""
    st = new_stage()
    mat = preview_material(st, "/mat/m", (0.6, 0.4, 0.2))
    shader = UsdShade.Shader.Get(st, "/mat/m/pbr")
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.25)
    define_quad(st, "/Q", square(0.0), mat)
    want = np.array([0.6, 0.4, 0.2]) * 0.75
    np.testing.assert_allclose(_albedos(load_scene(st), "/Q"), [want] * 2, rtol=1e-6)


def test_tex_path_texture_channels_and_to_rgb(tmp_path):
    st = new_stage()
    tex = UsdShade.Shader.Define(st, "/mat/tex")
    tex.CreateIdAttr("UsdUVTexture")
    assert tex_path(tex) == ""  # no file authored
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./missing.png"))
    assert tex_path(tex) == "./missing.png"  # unresolved: the authored path, for messages
    assert texture_channels("rgb") == (0, 1, 2)
    assert [texture_channels(c) for c in "rgba"] == [(0,), (1,), (2,), (3,)]
    assert texture_channels("bogus") == (0, 1, 2)
    grey = np.arange(6, dtype=np.float32).reshape(1, 3, 2)
    rgb = to_rgb(grey)
    assert rgb.shape == (1, 3, 3) and (rgb == grey[..., :1]).all()
    rgba = np.arange(12, dtype=np.float32).reshape(1, 3, 4)
    assert (to_rgb(rgba) == rgba[..., :3]).all()


@pytest.mark.parametrize("albedo", [(1.5, 0.5, 0.5), (-0.2, 0.5, 0.5)])
def test_albedo_outside_zero_one_is_kept_physical(albedo):
    """A diffuseColor outside [0, 1] would create or absorb energy without limit; the reader
    clamps each channel to [0, 1] and says so, naming the material."""
    st = new_stage()
    define_quad(st, "/Q", square(0.0), preview_material(st, "/mat/x", albedo))
    sc = load_scene(st)
    np.testing.assert_allclose(_albedos(sc, "/Q"), [np.clip(albedo, 0, 1)] * 2, atol=F32)
    (w,) = [w for w in sc.warnings if "diffuseColor" in w]
    assert "/mat/x" in w and "non-physical" in w and "clamped" in w
