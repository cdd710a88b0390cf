"""The Cycles reference harness (benchmarks/reference): exporter radiometry and geometry without
bpy, error statistics, bad inputs, and a smoke test through Blender that skips cleanly when no
bpy interpreter is configured ($USDAHD_BPY_PYTHON).

Expected light values are written out by hand from the UsdLux definitions (not from the
exporter's code): L = intensity * 2^exposure * color; normalize divides by the world-space
area; a normalized DistantLight's intensity is its illuminance, an unnormalized one of
angular radius a gives L pi sin^2 a.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import new_stage
from tests.stats import SIGMAS

pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt  # noqa: E402

import usdahd.usd  # noqa: E402, F401  (registers the schema plugin before any stage is made)

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.reference import calibrate, compare, export, probes, runner  # noqa: E402

REL = 1e-6  # float32 storage of authored values


def _plane(stage, path="/World/Geometry/Plane", st=True, normals=False):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
    m.CreateSubdivisionSchemeAttr("none")
    if st:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        pv.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)]))
    if normals:
        m.CreateNormalsAttr(Vt.Vec3fArray([(0, 0, 1)] * 4))  # deliberately not the winding
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    return m


def _light(stage, cls, path, intensity, exposure=0.0, color=(1, 1, 1), normalize=False):
    lt = cls.Define(stage, path)
    api = UsdLux.LightAPI(lt.GetPrim())
    api.CreateIntensityAttr(intensity)
    api.CreateExposureAttr(exposure)
    api.CreateColorAttr(Gf.Vec3f(*color))
    api.CreateNormalizeAttr(normalize)
    return lt


def _export(stage, **kw):
    stage.GetRootLayer().Save()
    return export.export_stage(stage.GetRootLayer().realPath, resolution=8, **kw)


def _by_path(scene, path):
    return next(x for x in scene.lights if x["path"] == path)


# ------------------------------------------------------------------------ radiometry


def test_sphere_rect_disk_radiance_and_normalize(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    s = _light(st, UsdLux.SphereLight, "/L/S", 3.0, 1.0, (1, 0.5, 0.25))
    s.CreateRadiusAttr(0.2)
    UsdGeom.Xformable(s).AddScaleOp().Set(Gf.Vec3f(2, 2, 2))  # world radius 0.4
    sn = _light(st, UsdLux.SphereLight, "/L/SN", 5.0, normalize=True)
    sn.CreateRadiusAttr(0.5)
    r = _light(st, UsdLux.RectLight, "/L/R", 2.0, -1.0, normalize=True)
    r.CreateWidthAttr(2.0)
    r.CreateHeightAttr(0.5)
    d = _light(st, UsdLux.DiskLight, "/L/D", 4.0, normalize=True)
    d.CreateRadiusAttr(0.25)
    sc = _export(st)
    ls = _by_path(sc, "/L/S")
    assert ls["type"] == "sphere" and ls["radius"] == pytest.approx(0.4, rel=REL)
    assert ls["radiance"] == pytest.approx([6.0, 3.0, 1.5], rel=REL)
    lsn = _by_path(sc, "/L/SN")
    assert lsn["radiance"] == pytest.approx([5.0 / (4 * math.pi * 0.25)] * 3, rel=REL)
    lr = _by_path(sc, "/L/R")
    assert lr["size"] == pytest.approx([2.0, 0.5]) and lr["area"] == pytest.approx(1.0)
    assert lr["radiance"] == pytest.approx([1.0] * 3, rel=REL)
    ld = _by_path(sc, "/L/D")
    assert ld["area"] == pytest.approx(math.pi / 16, rel=REL)
    assert ld["radiance"] == pytest.approx([4.0 / (math.pi / 16)] * 3, rel=REL)


def test_treat_as_point_and_distant_light_illuminance(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    p = _light(st, UsdLux.SphereLight, "/L/P", 10.0)
    p.CreateRadiusAttr(0.1)
    p.CreateTreatAsPointAttr(True)
    dn = _light(st, UsdLux.DistantLight, "/L/DN", 3.0, normalize=True)
    dn.CreateAngleAttr(0.53)
    du = _light(st, UsdLux.DistantLight, "/L/DU", 50000.0, color=(1, 0.5, 1))
    du.CreateAngleAttr(1.0)
    UsdGeom.Xformable(du).AddRotateXOp().Set(-90.0)  # travels along -Y
    sc = _export(st)
    lp = _by_path(sc, "/L/P")
    assert lp["type"] == "point"
    assert lp["intensity"] == pytest.approx([10.0 * math.pi * 0.01] * 3, rel=REL)
    assert _by_path(sc, "/L/DN")["illuminance"] == pytest.approx([3.0] * 3, rel=REL)
    ldu = _by_path(sc, "/L/DU")
    e = 50000.0 * math.pi * math.sin(math.radians(0.5)) ** 2
    assert ldu["illuminance"] == pytest.approx([e, e / 2, e], rel=REL)
    assert ldu["angle"] == pytest.approx(math.radians(1.0))
    assert ldu["direction"] == pytest.approx([0, -1, 0], abs=1e-9)


def test_dome_colour_and_texture_orientation(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    _light(st, UsdLux.DomeLight, "/L/Dome", 0.5, 1.0, (0.2, 0.4, 0.8))
    sc = _export(st)
    assert sc.dome_color == pytest.approx([0.2, 0.4, 0.8], rel=REL)
    # latlong: row 0 is +Y (the pole); an image whose top half is 1 and bottom half 0 gives
    # 1 above the horizon and 0 below.
    img = np.zeros((64, 128, 3))
    img[:32] = 1.0
    up = export.latlong_lookup(img, np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]))
    assert up[:, 0] == pytest.approx([1.0, 0.0])
    # Blender's equirect rows run bottom-up with z up: the first row is the nadir (-Z).
    dirs = export.blender_equirect_dirs(8)
    assert dirs[0, 0, 2] < -0.95 and dirs[-1, 0, 2] > 0.95
    # A Y-up dome resampled for Blender: +Y (world) bright, -Y dark.
    res = export.dome_to_blender(img, np.eye(3), "Y", rows=16).reshape(-1, 3)
    d = export.blender_equirect_dirs(16).reshape(-1, 3)
    assert np.all(res[d[:, 1] > 0.2, 0] > 0.99) and np.all(res[d[:, 1] < -0.2, 0] < 0.01)


def test_an_8bit_dome_texture_is_srgb_decoded(tmp_path):
    """Hydra's rule for a texture without a colour space: an 8-bit RGB image is sRGB. Code 128
    is 128/255 = 0.50196 encoded, ((0.50196 + 0.055) / 1.055)^2.4 = 0.21586 linear; a float
    EXR is read as it is."""
    import OpenImageIO as oiio

    for name, fmt, value, want in (("sky.png", oiio.UINT8, 128 / 255, 0.21586),
                                   ("sky.exr", oiio.FLOAT, 0.5, 0.5)):  # fmt: skip
        path = tmp_path / name
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), oiio.ImageSpec(8, 4, 3, fmt))
        out.write_image(np.full((4, 8, 3), value, np.float32))
        out.close()
        assert export._read_image(str(path)) == pytest.approx(np.full((4, 8, 3), want), abs=2e-5)


def test_emissive_material_and_texture_path(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    m = _plane(st)
    mat = UsdShade.Material.Define(st, "/M")
    sh = UsdShade.Shader.Define(st, "/M/S")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.1, 0.2, 0.3))
    sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(4, 5, 6))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(mat)
    sc = _export(st)
    desc = sc.materials[sc.tri_mat[0]]
    assert desc["albedo"] == pytest.approx([0.1, 0.2, 0.3], rel=REL)
    assert desc["emission"] == pytest.approx([4, 5, 6], rel=REL)
    assert desc["double_sided"] is False


def _cutout_stage(tmp_path, alpha: float, name="cut.usda"):
    """A lit plane under a uniform dome with a quad 0.5 above it whose material's opacity is
    the alpha of its diffuse texture (``alpha`` everywhere), threshold 0.5: alpha 0 is a
    fully cut-out occluder, alpha 1 an opaque one."""
    import OpenImageIO as oiio

    png = tmp_path / f"alpha{alpha:g}.png"
    img = np.zeros((4, 4, 4), np.float32)
    img[..., :3], img[..., 3] = 0.5, alpha
    out = oiio.ImageOutput.create(str(png))
    out.open(str(png), oiio.ImageSpec(4, 4, 4, oiio.UINT8))
    out.write_image(img)
    out.close()
    st = new_stage("Y", path=tmp_path / name)
    _plane(st)
    occ = _plane(st, "/World/Occluder")
    occ.AddTranslateOp().Set(Gf.Vec3d(0, 0.5, 0))
    mat = UsdShade.Material.Define(st, "/Cut")
    sh = UsdShade.Shader.Define(st, "/Cut/S")
    sh.CreateIdAttr("UsdPreviewSurface")
    rd = UsdShade.Shader.Define(st, "/Cut/St")
    rd.CreateIdAttr("UsdPrimvarReader_float2")
    rd.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tx = UsdShade.Shader.Define(st, "/Cut/Tex")
    tx.CreateIdAttr("UsdUVTexture")
    tx.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(png))
    tx.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(rd.ConnectableAPI(), "result")
    tx.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    tx.CreateOutput("a", Sdf.ValueTypeNames.Float)
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tx.ConnectableAPI(), "rgb"
    )
    sh.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(tx.ConnectableAPI(), "a")
    sh.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(occ.GetPrim()).Bind(mat)
    _light(st, UsdLux.DomeLight, "/World/Dome", 1.0)
    st.GetRootLayer().Save()
    return st


def test_textured_metallic_and_emission_are_exported(tmp_path):
    """A metallic fed by a texture's channel scales the diffuse albedo by (1 - metallic) in the
    reference as usdahd reads it; a textured emissiveColor is exported as that texture; a
    constant metallic on a textured diffuseColor scales the texture."""
    st = _cutout_stage(tmp_path, 1.0)
    sh = UsdShade.Shader(st.GetPrimAtPath("/Cut/S"))
    tx = UsdShade.Shader(st.GetPrimAtPath("/Cut/Tex"))
    tx.CreateOutput("b", Sdf.ValueTypeNames.Float)
    sh.CreateInput("metallic", Sdf.ValueTypeNames.Float).ConnectToSource(tx.ConnectableAPI(), "b")
    sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tx.ConnectableAPI(), "rgb"
    )
    st.GetRootLayer().Save()
    sc = export.export_stage(st.GetRootLayer().realPath, resolution=4)
    occ = next(i for i, m in enumerate(sc.meshes) if m["path"] == "/World/Occluder")
    desc = sc.materials[sc.tri_mat[sc.tri_mesh == occ][0]]
    assert Path(desc["metallic_texture"]).name == "alpha1.png"
    assert desc["metallic_channel"] == "b" and desc["metallic_srgb"] is True  # 8-bit PNG: auto
    assert Path(desc["emission_texture"]).name == "alpha1.png"
    assert not [w for w in sc.warnings if "not supported" in w]
    sh.GetInput("metallic").DisconnectSource()
    sh.GetInput("metallic").Set(0.75)
    st.GetRootLayer().Save()
    sc = export.export_stage(st.GetRootLayer().realPath, resolution=4)
    desc = sc.materials[sc.tri_mat[sc.tri_mesh == occ][0]]
    assert desc["albedo_scale"] == pytest.approx(0.25) and "metallic_texture" not in desc


def test_opacity_cutouts_and_constant_opacity_are_exported(tmp_path):
    """opacity fed by the diffuse texture's alpha with a threshold, and a constant opacity,
    reach the reference as usdahd reads them (usdahd/bake/kernels/trace.py nb_transmits)."""
    st = _cutout_stage(tmp_path, 0.0)
    sc = export.export_stage(st.GetRootLayer().realPath, resolution=4)
    occ = next(i for i, m in enumerate(sc.meshes) if m["path"] == "/World/Occluder")
    desc = sc.materials[sc.tri_mat[sc.tri_mesh == occ][0]]
    assert Path(desc["opacity_texture"]).name == "alpha0.png"
    assert desc["opacity_channel"] == "a" and desc["opacity_threshold"] == pytest.approx(0.5)
    assert desc["texture_uv"] == "st"
    sh = UsdShade.Shader(st.GetPrimAtPath("/Cut/S"))
    sh.GetInput("opacity").DisconnectSource()
    sh.GetInput("opacity").Set(0.25)
    sh.GetInput("opacityThreshold").Set(0.0)
    st.GetRootLayer().Save()
    sc = export.export_stage(st.GetRootLayer().realPath, resolution=4)
    desc = sc.materials[sc.tri_mat[sc.tri_mesh == occ][0]]
    assert desc["opacity"] == pytest.approx(0.25) and desc["opacity_texture"] is None
    assert desc["opacity_threshold"] == 0.0


@pytest.mark.parametrize("metallic, spec, want", [(0.75, False, 0.25), (1.0, False, 0.0),
                                                   (0.75, True, 1.0)])  # fmt: skip
def test_metallic_reduces_the_exported_diffuse_albedo(tmp_path, metallic, spec, want):
    """The reference renders the diffuse transport usdahd bakes: diffuseColor x (1 - metallic)
    in the metallic workflow, diffuseColor in the specular one (classroom's metal chairs were
    exported white, so the reference was ~20 % brighter than the bake there)."""
    st = new_stage("Y", path=tmp_path / "s.usda")
    m = _plane(st)
    mat = UsdShade.Material.Define(st, "/M")
    sh = UsdShade.Shader.Define(st, "/M/S")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.4, 0.8, 1.0))
    sh.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(metallic)
    sh.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(int(spec))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(mat)
    desc = _export(st).materials[0]
    assert desc["albedo"] == pytest.approx([0.4 * want, 0.8 * want, 1.0 * want], rel=REL, abs=1e-9)


# -------------------------------------------------------------------------- geometry


def _box(stage, path, scheme="none"):
    """A unit cube without normals (6 quads, welded points, outward CCW)."""
    pts = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    faces = [
        (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3),
    ]  # fmt: skip
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray(pts))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([4] * 6))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([i for f in faces for i in f]))
    if scheme:
        m.CreateSubdivisionSchemeAttr(scheme)
    return m


def test_box_without_normals_is_flat_and_outward(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    _box(st, "/Box")
    sc = _export(st)
    k = [m["path"] for m in sc.meshes].index("/Box")
    sel = sc.tri_mesh == k
    p, n = sc.tri_p[sel], sc.tri_n[sel]
    geo = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    geo /= np.linalg.norm(geo, axis=1, keepdims=True)
    # Every corner normal equals its triangle's flat normal, which points out of the cube.
    assert np.allclose(n, geo[:, None, :], atol=1e-9)
    assert np.all(((p.mean(1) - 0.5) * geo).sum(1) > 0)


def test_left_handed_box_without_normals_faces_its_front(tmp_path):
    """orientation = leftHanded makes the clockwise side the front: computed normals (and
    the exported winding) then point into this cube."""
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    _box(st, "/Box").CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    sc = _export(st)
    k = [m["path"] for m in sc.meshes].index("/Box")
    p, n = sc.tri_p[sc.tri_mesh == k], sc.tri_n[sc.tri_mesh == k]
    geo = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    geo /= np.linalg.norm(geo, axis=1, keepdims=True)
    assert np.allclose(n, geo[:, None, :], atol=1e-9)
    assert np.all(((p.mean(1) - 0.5) * geo).sum(1) < 0)


def test_subdivision_mesh_without_normals_is_smooth(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    # the plane below the box, not under its bottom face (coincident faces are moved apart)
    UsdGeom.Xformable(_plane(st)).AddTranslateOp().Set(Gf.Vec3d(0, -1, 0))
    _box(st, "/Box", scheme=None)  # catmullClark fallback: smooth normals
    sc = _export(st)
    k = [m["path"] for m in sc.meshes].index("/Box")
    n = sc.tri_n[sc.tri_mesh == k].reshape(-1, 3)
    p = sc.tri_p[sc.tri_mesh == k].reshape(-1, 3)
    want = (p - 0.5) / np.linalg.norm(p - 0.5, axis=1, keepdims=True)  # corner diagonals
    assert np.allclose(n, want, atol=1e-9)


def test_authored_normals_win_and_left_handed_flips_winding(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    m = _plane(st, normals=True)
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    sc = _export(st)
    assert np.allclose(sc.tri_n, [0, 0, 1])  # authored, even though not the winding normal
    p = sc.tri_p
    geo = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(geo[:, 1] < 0)  # leftHanded: the front of this quad is -y
    # UVs follow their corners through the flip.
    for t in range(len(p)):
        for c in range(3):
            x, z = p[t, c, 0], p[t, c, 2]
            assert sc.tri_uv[t, c] == pytest.approx([(x + 1) / 2, (1 - z) / 2])


def test_computed_normals_crease_rule_per_face_pair():
    # Two faces folded by 20 deg (smoothed at 30) and a third at 90 deg (kept sharp).
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 2, 0.364], [1, 2, 0.364]])
    counts = np.array([4, 4])
    fv = np.array([0, 1, 2, 3, 3, 2, 5, 4])
    n = export.computed_normals(pts, counts, fv, 30.0)
    shared = n[[2, 3]]  # face 0 corners at the fold
    assert np.allclose(shared, n[[5, 4]])  # same normal from both sides
    assert shared[0, 2] > 0.98 and shared[0, 1] < 0  # between the two face normals
    flat = export.computed_normals(pts, counts, fv, 10.0)
    assert np.allclose(flat[:4], [0, 0, 1])


# ------------------------------------------------------------------------ statistics


def test_interior_mask_and_error_stats():
    mask = np.zeros((5, 5), bool)
    mask[1:5, 0:4] = True
    inner = compare.interior(mask)
    assert inner.sum() == 4 and inner[2:4, 1:3].all()
    t = np.ones((100, 3))
    s = compare.error_stats(t * 1.02, t)
    assert s["bias"] == pytest.approx(0.02) and s["rel_rmse"] == pytest.approx(0.02)
    rng = np.random.default_rng(0)
    noise = 1 + 0.1 * rng.standard_normal((20000, 1))
    s = compare.error_stats(t.repeat(200, 0) * noise, t.repeat(200, 0))
    assert abs(s["bias"]) < SIGMAS * 0.1 / math.sqrt(20000)  # SIGMAS standard errors of the mean
    assert s["rel_rmse"] == pytest.approx(0.1, rel=0.03)


def test_compare_images_uses_interior_lit_texels_only():
    meshes = [{"path": "/A", "baked": True, "resolution": [6, 6]}]
    truth = np.full((6, 6, 3), np.nan)
    truth[1:5, 1:5] = 1.0
    ours = np.full((6, 6, 3), 5.0)  # wrong on the border texels, which must be ignored
    ours[2:4, 2:4] = 1.1
    out = compare.compare_images(meshes, {0: truth}, {0: truth}, {0: (ours, np.ones((6, 6), bool))},
                                 16, 64)  # fmt: skip
    row = out["meshes"][0]
    assert row["compared"] == 4 and row["covered"] == 16
    assert row["usdahd"]["bias"] == pytest.approx(0.1)
    assert row["cycles"]["bias"] == pytest.approx(0.0)


def test_texels_the_bake_filled_are_reported_apart():
    """A texel usdahd filled from its neighbours (bakevar's ``invalid``: covered, inside
    geometry) carries the fill rule's value, not an estimate: left out of the mesh's figures
    and reported apart (``filled``), as the classroom ground's texel under the building is."""
    meshes = [{"path": "/G", "baked": True, "resolution": [9, 9]}]
    truth = np.ones((9, 9, 3))
    ours = np.ones((9, 9, 3))
    ours[4, 4] = 6.0  # the neighbours' mean where the point itself is dim
    fill = np.zeros((9, 9), bool)
    fill[4, 4] = True
    var = np.full((9, 9), 1e-4)
    args = (meshes, {0: truth}, {}, {0: (ours, np.ones((9, 9), bool))}, 16, 64, {0: (var, var)})
    row = compare.compare_images(*args, {0: fill})["meshes"][0]
    assert row["compared"] == 48 and row["usdahd"]["bias"] == pytest.approx(0.0)
    assert row["filled"]["texels"] == 1 and row["filled"]["bias"] == pytest.approx(5.0)
    row = compare.compare_images(*args)["meshes"][0]  # without the fill mask: in the figures
    assert row["compared"] == 49 and row["usdahd"]["bias"] == pytest.approx(5.0 / 49)
    assert "filled" not in row


def test_compare_reports_apart_what_the_sample_benchmark_leaves_out():
    """compare.py's ``filled`` mask is the sample benchmark's left-out rule: bakevar's
    ``invalid`` and ``moved`` texels (sampled off the centre), an old file's missing ``moved``
    flagging nothing."""
    h = w = 4
    xy = np.array([(x, y) for y in range(h) for x in range(w)])
    inv, mv = np.zeros(h * w, bool), np.zeros(h * w, bool)
    inv[1 * w + 1], mv[2 * w + 3] = True, True
    var = {"/m": {"xy": xy, "s2": np.ones(h * w), "halves": np.ones(h * w),
                  "invalid": inv, "moved": mv}}  # fmt: skip
    (_, _), mask = compare.variance_images(var, "/m", (h, w))
    assert mask.sum() == 2 and mask[1, 1] and mask[2, 3]
    var["/m"]["moved"] = np.zeros(0, bool)
    (_, _), mask = compare.variance_images(var, "/m", (h, w))
    assert mask.sum() == 1 and mask[1, 1]
    assert compare.NOT_AT_CENTRE == ("invalid", "moved")


def test_texels_next_to_unlit_ones_are_reported_apart():
    """A dark footprint (a box standing on the floor) in the middle of a lit chart: its lit
    neighbours are 'contact' texels, not part of the main figures."""
    meshes = [{"path": "/F", "baked": True, "resolution": [9, 9]}]
    truth = np.ones((9, 9, 3))
    truth[4, 4] = 0.0  # under the box
    ours = np.ones((9, 9, 3))
    ring = np.zeros((9, 9), bool)
    ring[3:6, 3:6] = True
    ring[4, 4] = False
    ours[ring] = 1.5  # a leak along the contact edge
    out = compare.compare_images(meshes, {0: truth}, {}, {0: (ours, np.ones((9, 9), bool))},
                                 16, 64)  # fmt: skip
    row = out["meshes"][0]
    assert row["usdahd"]["bias"] == pytest.approx(0.0)
    assert row["compared"] == 49 - 9  # interior of the chart minus the 3 x 3 around the box
    assert row["contact"]["texels"] == 8 and row["contact"]["bias"] == pytest.approx(0.5)


# ----------------------------------------------------------------------- bad inputs


def test_export_errors_name_the_problem(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st, st=False)
    st.GetRootLayer().Save()
    with pytest.raises(export.ExportError, match="no mesh has the lightmap UV primvar 'st'"):
        export.export_stage(tmp_path / "s.usda", resolution=8)
    with pytest.raises(export.ExportError, match="no such file"):
        export.export_stage(tmp_path / "missing.usda", resolution=8)
    with pytest.raises(export.ExportError, match="lightmap UV primvar 'uv2' not found"):
        export.export_stage(
            tmp_path / "s.usda",
            baked={"/World/Geometry/Plane": {"uv": "uv2", "resolution": [8, 8]}},
        )


def test_missing_dome_texture_is_an_error(tmp_path):
    st = new_stage("Y", path=tmp_path / "s.usda")
    _plane(st)
    d = _light(st, UsdLux.DomeLight, "/L/Dome", 1.0)
    d.CreateTextureFileAttr(Sdf.AssetPath("./nope.exr"))
    with pytest.raises(export.ExportError, match="dome texture ./nope.exr does not resolve"):
        _export(st)


def test_bpy_interpreter_errors_say_how_to_create_one(tmp_path, monkeypatch):
    monkeypatch.delenv(runner.ENV_VAR, raising=False)
    with pytest.raises(runner.ReferenceUnavailable, match="pip install bpy==5.0.1"):
        runner.find_bpy(None)
    with pytest.raises(runner.ReferenceUnavailable, match="not an executable file"):
        runner.find_bpy(str(tmp_path / "python"))
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'No module named bpy' >&2\nexit 1\n")
    fake.chmod(0o755)
    with pytest.raises(runner.ReferenceUnavailable, match="'import bpy' fails"):
        runner.find_bpy(str(fake))


def test_compare_cli_usage_errors(tmp_path, capsys):
    assert compare.main(["compare", str(tmp_path / "none.usda"), "--bpy-python", "/x"]) == 2
    assert "no such file" in capsys.readouterr().err
    stage = ROOT / "samples" / "open_plane.usda"
    assert (
        compare.main(["compare", str(stage), str(tmp_path / "b.usda"), "--bpy-python", "/x"]) == 2
    )
    assert "b.usda: no such file" in capsys.readouterr().err  # before baking the first one
    assert compare.main(["compare", str(stage), "--truth-spp", "0"]) == 2
    assert "--truth-spp must be >= 1" in capsys.readouterr().err
    assert compare.main(["compare", str(stage), "--oversample", "2"]) == 2
    assert "--oversample must be odd and >= 1, got 2" in capsys.readouterr().err


def test_denoise_gain_ratios_table_and_usage_errors(tmp_path, capsys):
    """benchmarks/reference/denoise_gain.py: the ratio is denoised / plain relRMSE overall and
    per mesh (worst named), the table averages seeds; a missing stage or bpy exits 2 first."""
    from benchmarks.reference import denoise_gain as dg
    from usdahd.commands import bake as bake_cmd

    # each run names its flag, so a change of the bake's default cannot make both alike
    parse = argparse.ArgumentParser()
    bake_cmd.add_parser(parse.add_subparsers())
    assert [parse.parse_args(["bake", "s.usda", *f]).denoise for _, f in dg.RUNS] == [False, True]

    def figs(overall, *meshes):
        return {"overall": {"usdahd": {"rel_rmse": overall}},
                "meshes": [{"path": p, "usdahd": {"rel_rmse": r}} for p, r in meshes]}  # fmt: skip

    row = {"plain": figs(0.02, ("/a", 0.02), ("/b", 0.01)),
           "denoised": figs(0.01, ("/a", 0.005), ("/b", 0.015))}  # fmt: skip
    ratio, worst, where = dg.ratios(row)
    assert ratio == pytest.approx(0.5) and worst == pytest.approx(1.5) and where == "/b"
    rows = [{"stage": "/x/st.usda", "spp": 16, "ratio": r, "worst": w, "worst_mesh": "/m"}
            for r, w in ((0.4, 0.9), (0.6, 1.2))]  # fmt: skip
    text = dg.table(rows, [16, 64])
    assert "| st | 0.50 |  | 1.20 m (16) |" in text
    assert dg.stage_path("cornell_box") == ROOT / "samples" / "cornell_box.usda"
    assert dg.main(["--stages", str(tmp_path / "none.usda")]) == 2
    assert "no such stage" in capsys.readouterr().err
    stage = str(ROOT / "samples" / "open_plane.usda")
    assert dg.main(["--stages", stage, "--bpy-python", str(tmp_path / "nope")]) == 2
    assert "bpy interpreter" in capsys.readouterr().err


def test_denoise_gain_direction_error_from_sidecars(tmp_path):
    """The directional judge: tilted-normal irradiance from a real bake's SH sidecar is the
    cosine-convolved SH at the 4 tilted normals; the error against a reference is 0 against
    itself, 0.5 against twice itself, and the reference's own noise comes out in quadrature."""
    from benchmarks.reference import denoise_gain as dg
    from usdahd import cli, images
    from usdahd.numerics import sh as shm
    from usdahd.usd import schema

    stage = tmp_path / "open_plane.usda"
    stage.write_bytes((ROOT / "samples" / "open_plane.usda").read_bytes())
    layer = tmp_path / "open_plane.lightmaps.usda"
    args = ["bake", str(stage), "-o", str(layer), "--resolution", "8", "--samples", "4"]
    assert cli.main([*args, "--quiet", "--no-denoise"]) == 0
    (mesh, sidecar), *_ = dg.sidecars(layer).items()
    e, cov = dg.tilted_irradiance(sidecar)
    assert e.shape == (8, 8, 3, 4) and cov.any()
    iz = compare.usdahd_iz(sidecar)[0]  # the untilted normal's, which must differ
    raw = np.asarray(images.read(sidecar, channels=schema.SH_SIDECAR_CHANNELS).pixels, float)
    sh9 = raw[..., :27].reshape(8, 8, 3, 9)
    n = np.array([0.0, -1.0, 1.0]) / np.sqrt(2.0)
    np.testing.assert_allclose(e[..., 3], shm.irradiance(sh9, n), rtol=1e-12)
    assert not np.allclose(e[cov][..., 0], iz[cov])
    same = {mesh: (e, 0.0, cov)}
    assert dg.direction_error(layer, same) == pytest.approx(0.0, abs=1e-12)
    assert dg.direction_error(layer, {mesh: (2 * e, 0.0, cov)}) == pytest.approx(0.5)
    # a reference whose noise variance v is known: v per value is taken out of the error
    rng = np.random.default_rng(3)
    ref = e + 0.01 * rng.standard_normal(e.shape)
    got = dg.direction_error(layer, {mesh: (ref, 1e-4, cov)})
    assert got < 0.25 * np.sqrt(np.mean((e - ref)[cov] ** 2) / np.mean(ref[cov] ** 2))
    row = {"plain": {"direction_rel_rmse": 0.04}, "denoised": {"direction_rel_rmse": 0.01}}
    assert dg.direction_ratio(row) == pytest.approx(0.25)
    rows = [{"stage": "/x/st.usda", "spp": 16, "ratio": 0.5, "worst": 0.9, "worst_mesh": "/m",
             **row}]  # fmt: skip
    assert dg.table(rows, [16]).splitlines()[-1] == "| st | 0.50 | 0.90 m (16) | 0.25 |"


def test_new_samples_regenerate_identically(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "make_samples_ref", ROOT / "samples" / "make_samples.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_samples_ref"] = module
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path)]) == 0
    for name in ("stretched_boxes", "indirect_ceiling", "floor_lamp", "emissive_only",
                 "exterior_sun_sky"):  # fmt: skip
        fresh = Sdf.Layer.FindOrOpen(str(tmp_path / f"{name}.usda")).ExportToString()
        kept = Sdf.Layer.FindOrOpen(str(ROOT / "samples" / f"{name}.usda")).ExportToString()
        assert fresh == kept, name


def test_stretched_boxes_have_no_normals_and_stretched_charts():
    stage = Usd.Stage.Open(str(ROOT / "samples" / "stretched_boxes.usda"))
    box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Geometry/TallBox"))
    assert not box.GetNormalsAttr().HasAuthoredValue()
    sc = export.export_stage(ROOT / "samples" / "stretched_boxes.usda", resolution=16)
    k = [m["path"] for m in sc.meshes].index("/World/Geometry/TallBox")
    p, uv = sc.tri_p[sc.tri_mesh == k], sc.tri_uv[sc.tri_mesh == k]
    world = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    uva = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    density = uva / world
    assert density.max() / density.min() > 2.0  # non-uniform texel density across charts


def test_point_probes_sit_at_texel_centres_and_own_their_pixel():
    """probes.mesh_probes on a tilted, stretched quad: each probe's centroid is the texel
    centre's surface point lifted along the face normal by LIFT texel widths, capped by
    usdahd's ray offset there, its corners SIZE / 2 texel widths (capped by SIZE_LIFTS / 2
    offsets) from it in the plane normal to the shading normal, wound
    counter-clockwise about it; in UV it contains Blender's sample point of its own pixel
    ((x + 0.501) / w, v up) and no other pixel's."""
    w, h = 8, 4
    rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.8, -0.6], [0.0, 0.6, 0.8]])
    quad = np.array([[0, 0, 0], [4, 0, 0], [4, 0, -1], [0, 0, -1]], float) @ rot.T + [1, 2, 3]
    uvq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    tri = [[0, 1, 2], [0, 2, 3]]
    nrm = np.array([0.0, 1.0, 0.0]) @ rot.T
    pr = probes.mesh_probes(quad[tri], np.broadcast_to(nrm, (2, 3, 3)), uvq[tri], (w, h))
    assert len(pr["ids"]) == w * h  # every centre is inside one of the two triangles
    x, y = pr["ids"] % w, pr["ids"] // w
    u, v = (x + 0.5) / w, 1 - (y + 0.5) / h
    on_surface = (np.array([1, 2, 3]) + np.outer(4 * u, [1, 0, 0] @ rot.T)
                  + np.outer(v, [0, 0, -1] @ rot.T))  # fmt: skip
    width = np.sqrt(4.0 * 1.0 / (w * h))  # metres per texel of this mapping (0.5 x 0.25)
    assert np.allclose(pr["width"], width)
    centroid = pr["p"].mean(axis=1)
    # both capped by usdahd's ray offset on the quad: 64 float32 ulps of its largest coordinate
    cap = 64 * np.finfo(np.float32).eps * np.abs(quad).max()
    assert cap < probes.LIFT * width and probes.SIZE_LIFTS * cap < probes.SIZE * width
    assert np.allclose(centroid, on_surface + cap * nrm, atol=1e-12)
    r = np.linalg.norm(pr["p"] - centroid[:, None], axis=2)
    assert np.allclose(r, probes.SIZE_LIFTS * cap / 2)
    assert np.allclose(((pr["p"] - centroid[:, None]) @ nrm), 0, atol=1e-12)
    face_n = np.cross(pr["p"][:, 1] - pr["p"][:, 0], pr["p"][:, 2] - pr["p"][:, 0])
    assert (face_n @ nrm > 0).all()
    px = pr["uv"] * [w, h]  # v up, in pixels
    for i in range(len(px)):
        tri2 = px[i]
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                q = np.array([x[i] + 0.501 + dx, (h - 1 - y[i]) + 0.502 + dy])
                a, b = tri2[[1, 2, 0]] - tri2, q - tri2
                e = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
                assert (min(e) > 0) == (dx == 0 and dy == 0)


def test_point_probes_skip_texels_whose_centre_is_outside_every_triangle():
    """Conservative edge texels (centre outside the triangle) get no probe."""
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 0, -1]]], float)
    uv = np.array([[[0.05, 0.05], [0.85, 0.05], [0.05, 0.85]]])
    pr = probes.mesh_probes(tri, np.broadcast_to([0.0, 1.0, 0.0], (1, 3, 3)), uv, (4, 4))
    x, y = pr["ids"] % 4, pr["ids"] // 4
    u, v = (x + 0.5) / 4, 1 - (y + 0.5) / 4
    assert len(pr["ids"]) == 6 and (u + v < 0.9).all()  # centres with u + v < 0.9: 3 + 2 + 1


def test_point_probes_under_tilted_normals_lie_in_the_face_plane_above_the_mesh():
    """Where the shading normal tilts more than 1 degree from the face (smoothed corner normals
    at a crease) a probe lies in the face's plane, lifted along the face normal, so no part of
    it dips under the mesh (perpendicular to a normal tilted 15 degrees, its edge sank by
    radius sin 15 deg ~ 1.3 lifts, and the mesh shadowed that part in Cycles: -9.5 % at the
    crease); its shading normal stays the interpolated one. Untilted probes are unchanged."""
    tri = np.array([[[0, 0, 1], [2, 0, 1], [2, 0, -1]], [[0, 0, 1], [2, 0, -1], [0, 0, -1]]],
                   float)  # fmt: skip
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    lean = np.array([np.sin(np.radians(15)), np.cos(np.radians(15)), 0.0])
    up = np.array([0.0, 1.0, 0.0])
    nrm = np.array([[lean, up, up], [lean, up, lean]])  # the x = 0 edge leans 15 degrees
    pr = probes.mesh_probes(tri, nrm, uv, (8, 8))
    assert len(pr["ids"]) == 64
    tilt = np.degrees(np.arccos(np.clip(pr["n"] @ up, -1, 1)))
    assert tilt.max() > 7  # perpendicular to n, these would have dipped under the face
    lift = pr["p"].mean(axis=1)[:, 1]
    assert (lift > 0).all()
    face_n = np.cross(pr["p"][:, 1] - pr["p"][:, 0], pr["p"][:, 2] - pr["p"][:, 0])
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    tilted = tilt > 1.0
    assert tilted.any() and (~tilted).any()
    # tilted: every corner at the probe's lift (the face plane), wound about the face normal
    assert np.allclose(pr["p"][tilted][:, :, 1], lift[tilted][:, None], rtol=1e-9, atol=0)
    assert np.allclose(face_n[tilted], up)
    # untilted: perpendicular to the shading normal as before
    assert np.allclose(np.einsum("nj,nj->n", face_n[~tilted], pr["n"][~tilted]), 1.0)


def test_point_truths_are_keyed_by_their_probes_content():
    """A point truth's cache key hashes the probes Cycles bakes (not probes.py's text): equal
    probes give equal keys, different probes or no probes different ones."""
    from benchmarks.reference import runner

    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 0, -1]]], float)
    uv = np.array([[[0.05, 0.05], [0.85, 0.05], [0.05, 0.85]]])
    n_up = np.broadcast_to([0.0, 1.0, 0.0], (1, 3, 3))
    a = probes.mesh_probes(tri, n_up, uv, (4, 4))
    b = probes.mesh_probes(tri.copy(), n_up.copy(), uv.copy(), (4, 4))
    c = probes.mesh_probes(tri, n_up, uv, (8, 8))
    arr = lambda pr: {"p_0": pr["p"], "n_0": pr["n"], "uv_0": pr["uv"]}  # noqa: E731
    da, db, dc = (probes.probes_digest(arr(pr)) for pr in (a, b, c))
    assert da == db != dc
    keys = {runner.cache_key("d", 64, 1, 1, x) for x in (da, dc, None)}
    assert len(keys) == 3


# ------------------------------------------------------------------ through Blender


@pytest.fixture(scope="module")
def bpy_python():
    try:
        return runner.find_bpy()
    except runner.ReferenceUnavailable as exc:
        pytest.skip(str(exc))


def test_smoke_cycles_bakes_uniform_dome_exactly(tmp_path, bpy_python):
    """open_plane: I_z = 1 in every texel (a uniform dome, nothing else visible; Cycles has
    no noise here because every path escapes to the same radiance)."""
    sc = export.export_stage(ROOT / "samples" / "open_plane.usda", resolution=8)
    sf = export.save_scene(sc, tmp_path / "scene.npz")
    info, images = runner.run_cycles(sf, 4, bpy=bpy_python, quiet=True)
    iz = images[0]
    assert iz.shape == (8, 8, 3) and np.isfinite(iz).all()
    assert np.allclose(iz, 1.0, atol=1e-5)
    assert info["spp"] == 4


def test_smoke_oversampled_bake_keeps_texel_centres(tmp_path, bpy_python):
    """--oversample 3 bakes 12 x 12 and returns the 4 x 4 centre sub-texels (same layout)."""
    sc = export.export_stage(ROOT / "samples" / "open_plane.usda", resolution=4)
    sf = export.save_scene(sc, tmp_path / "scene.npz")
    info, images = runner.run_cycles(sf, 2, bpy=bpy_python, quiet=True, oversample=3)
    assert images[0].shape == (4, 4, 3) and info["oversample"] == 3
    assert np.allclose(images[0], 1.0, atol=1e-5)


def test_smoke_cycles_sees_through_cutouts(tmp_path, bpy_python):
    """A fully cut-out occluder (alpha 0 < threshold 0.5) leaves the uniform dome's I_z = 1 on
    the plane below (Cycles' transparent bounces consume no randomness: exact); the same
    occluder opaque (alpha 1) darkens it."""
    for alpha, name in ((0.0, "clear.usda"), (1.0, "opaque.usda")):
        st = _cutout_stage(tmp_path, alpha, name)
        sc = export.export_stage(st.GetRootLayer().realPath, resolution=4)
        plane = next(i for i, m in enumerate(sc.meshes) if m["path"] == "/World/Geometry/Plane")
        sf = export.save_scene(sc, tmp_path / f"{name}.npz")
        _, images = runner.run_cycles(sf, 16, bpy=bpy_python, quiet=True)
        iz = images[plane]
        if alpha == 0.0:
            assert np.allclose(iz, 1.0, atol=1e-4)
        else:
            assert iz.mean() < 0.8


def test_smoke_calibration_sphere_case(bpy_python):
    """One analytic case through the whole harness (USD -> export -> Cycles), 64 spp: the mean
    ratio to the closed form within SIGMAS of its standard errors plus the 0.1 % calibration
    allowance (texel jitter)."""
    rows = calibrate.run(64, bpy_python, names=["sphere normalize"], quiet=True)
    assert len(rows) == 1
    r = rows[0]
    assert r["texels"] == calibrate.RES**2
    assert abs(r["ratio_m1"]) < SIGMAS * r["stderr"] + 1e-3


def test_smoke_point_probes_bake_texel_centres(tmp_path, bpy_python):
    """--point: the uniform dome gives I_z = 1 at every probe (the probes, invisible to bounce
    and shadow rays, neither shadow the plane nor each other), and the sphere light's closed
    form holds at the texel centres within SIGMAS standard errors plus 0.05 % (probes sit
    LIFT = 1/1000 texel above the plane)."""
    sc = export.export_stage(ROOT / "samples" / "open_plane.usda", resolution=8)
    sf = export.save_scene(sc, tmp_path / "scene.npz")
    info, images = runner.run_cycles(sf, 4, bpy=bpy_python, quiet=True, point=True)
    assert info["footprint"] == "point" and images[0].shape == (8, 8, 3)
    assert np.allclose(images[0], 1.0, atol=1e-5)
    (r,) = calibrate.run(64, bpy_python, names=["sphere normalize"], quiet=True, point=True)
    assert r["footprint"] == "point" and r["texels"] == calibrate.RES**2
    assert abs(r["ratio_m1"]) < SIGMAS * r["stderr"] + 5e-4


CREASE_STAGE = """#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Y"
)
def Xform "World"
{
    def Mesh "Flat" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(0, 0, 1), (2, 0, 1), (2, 0, -1), (0, 0, -1)]
        normal3f[] normals = [(0.2588, 0.9659, 0), (0, 1, 0), (0, 1, 0), (0.2588, 0.9659, 0)] (
            interpolation = "faceVarying")
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "faceVarying")
        rel material:binding = </World/Black>
    }
    def Material "Black"
    {
        token outputs:surface.connect = </World/Black/S.outputs:surface>
        def Shader "S"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0, 0, 0)
            token outputs:surface
        }
    }
    def DistantLight "Sun"
    {
        float inputs:angle = 0
        float inputs:intensity = 3
        bool inputs:normalize = 1
        float3 xformOp:rotateXYZ = (-50, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }
}
"""


def test_smoke_point_probes_under_tilted_normals_bake_the_shading_cosine(tmp_path, bpy_python):
    """A black quad whose x = 0 edge normals lean 15 degrees (smoothed toward a crease), lit by
    a sun only: every probe bakes E cos(n, l) / pi about its own interpolated shading normal
    (within 0.1 %). Probes perpendicular to the tilted normal dipped under the quad near that
    edge and read up to 9.5 % low (the quad shadowed them)."""
    stage = tmp_path / "crease.usda"
    stage.write_text(CREASE_STAGE)
    sc = export.export_stage(stage, resolution=16)
    sf = export.save_scene(sc, tmp_path / "scene.npz")
    info, images = runner.run_cycles(sf, 16, bpy=bpy_python, quiet=True, point=True)
    pr = probes.scene_probes(sf)
    (sun,) = json_lights(sf)
    to_light = -np.asarray(sun["direction"], float)
    w = 16
    ids = probes.mesh_probes(*_mesh_arrays(sf, 0), (w, w))["ids"]
    want = 3.0 * np.clip(pr["n_0"] @ to_light, 0, None) / np.pi
    got = images[0].reshape(-1, 3)[ids, 1]
    tilt = np.degrees(np.arccos(np.clip(pr["n_0"][:, 1], -1, 1)))
    assert tilt.max() > 10
    np.testing.assert_allclose(got, want, rtol=1e-3)


def json_lights(scene_file):
    import json

    return json.loads(str(np.load(scene_file)["meta"]))["lights"]


def _mesh_arrays(scene_file, k):
    d = np.load(scene_file)
    sel = d["tri_mesh"] == k
    return d["tri_p"][sel], d["tri_n"][sel], d["tri_uv"][sel]


@pytest.mark.slow
def test_compare_open_plane_end_to_end(bpy_python, tmp_path, monkeypatch):
    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    res = compare.run_compare(
        ROOT / "samples" / "open_plane.usda", resolution=8, usdahd_args="--samples 256",
        truth_spp=8, bpy=bpy_python, quiet=True,
    )  # fmt: skip
    (row,) = res["meshes"]
    assert row["compared"] > 0
    # usdahd's 256 samples integrate the uniform dome to ~1e-8 (measured 6.7e-9 at 32^2).
    assert abs(row["usdahd"]["bias"]) < 1e-4 and abs(row["cycles"]["bias"]) < 1e-5
    assert "| **overall** |" in compare.table(res)
    assert list((tmp_path / "cache").glob("*.npz"))  # the truth was cached
    # the bake's own standard error came through bakevar.py: an upper bound (s^2 / S of the
    # per-sample values; the regression estimator integrates the uniform dome exactly, so it
    # is loose here: 0.33 % measured where the bias is ~1e-8)
    assert 0 < row["bake_se"] < 0.01 and "bake_se" in res["overall"]


def test_bakevar_keeps_the_integrators_variances_per_prim(tmp_path, capsys):
    """bakevar.py is ``usdahd bake`` (same exit code, same layer) that also writes each
    prim's texel coordinates and per-texel I_z variances; in process and as a subprocess."""
    import json
    import subprocess

    from benchmarks.reference import bakevar

    stage = ROOT / "samples" / "cornell_box.usda"
    args = [str(stage), "--resolution", "8", "--samples", "16", "--no-denoise", "--json"]
    out = tmp_path / "v.npz"
    assert bakevar.main([str(out), *args, "-o", str(tmp_path / "a" / "c.lightmaps.usda")]) == 0
    report = json.loads(capsys.readouterr().out)
    got = bakevar.read(out)
    assert set(got) == {p["path"] for p in report["prims"] if p.get("status") == "baked"}
    for v in got.values():
        n = len(v["xy"])
        assert n and v["s2"].shape == v["halves"].shape == (n,)
        assert (v["s2"] >= 0).all() and (v["halves"] >= 0).all() and v["s2"].max() > 0
        assert 0 <= v["xy"].min() and v["xy"].max() < 8
        assert v["invalid"].shape == (n,) and v["invalid"].dtype == bool
    out2 = tmp_path / "w.npz"
    r = subprocess.run(
        [sys.executable, "-m", "benchmarks.reference.bakevar", str(out2), *args, "-o",
         str(tmp_path / "b" / "c.lightmaps.usda")], capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    again = bakevar.read(out2)
    for k, v in got.items():  # seeded: the same variances
        np.testing.assert_array_equal(again[k]["s2"], v["s2"])
    assert bakevar.main([str(out)]) == 2
    assert "usage" in capsys.readouterr().err
    # usdahd's own errors and exit code pass through (no such stage)
    assert bakevar.main([str(tmp_path / "x.npz"), str(tmp_path / "none.usda"), "-o",
                         str(tmp_path / "x.usda")]) == 2  # fmt: skip


def test_time_to_quality_interpolates_in_log_log_and_says_not_reached():
    from benchmarks import reference_bench as rb

    def row(ren, spp, secs, err, stage="s"):
        return {"stage": stage, "renderer": ren, "spp": spp, "seconds": secs, "rel_rmse": err}

    # usdahd: error halves per 4x time (a power law): Cycles' 1024-spp error 0.02 sits exactly
    # between its runs at 0.04 (1 s) and 0.01 (16 s) in log-log, i.e. at 4 s.
    rows = [row("cycles", 1024, 40.0, 0.02), row("usdahd", 256, 1.0, 0.04)]
    rows += [row("usdahd", 1024, 16.0, 0.01)]
    rows += [row("cycles", 1024, 10.0, 0.01, "b"), row("usdahd", 16, 1.0, 0.05, "b")]
    rows += [row("usdahd", 1024, 9.0, 0.03, "b")]  # bias-limited: never reaches 0.01
    got = {t["stage"]: t for t in rb.time_to_quality(rows)}
    assert got["s"]["usdahd_seconds"] == pytest.approx(4.0)
    assert got["s"]["ratio"] == pytest.approx(0.1)
    assert got["b"]["usdahd_seconds"] is None and got["b"]["ratio"] is None
    md = rb.markdown(rows, type("A", (), {"resolution": 8, "samples": [16], "truth_spp": 64}), None)
    assert "| b | defaults | 1.00 % | 10.0 | not reached | - |" in md
    # a lever (a variant's flags) gets its own row
    rows += [dict(row("usdahd", 1024, 2.0, 0.008, "b"), renderer="usdahd --denoise")]
    got = [t for t in rb.time_to_quality(rows) if t["stage"] == "b"]
    assert [t["renderer"] for t in got] == ["usdahd", "usdahd --denoise"]
    assert got[1]["usdahd_seconds"] == 2.0 and got[1]["ratio"] == pytest.approx(0.2)


def test_time_to_quality_judges_errors_net_of_the_truths_noise():
    from benchmarks import reference_bench as rb

    # independent noise adds in quadrature: 5 % measured against a truth with 3 % noise is 4 %
    assert rb.net_of_truth_noise(0.05, 0.03) == pytest.approx(0.04)
    assert rb.net_of_truth_noise(0.02, 0.03) == 0.0  # the truth's noise dominates
    assert rb.net_of_truth_noise(0.05, None) == 0.05

    def row(ren, spp, secs, err, net):
        return {"stage": "s", "renderer": ren, "spp": spp, "seconds": secs, "rel_rmse": err,
                "rel_rmse_net": net}  # fmt: skip

    # raw errors never reach Cycles' 0.02 (usdahd's against a noisier centre truth), net ones do
    rows = [row("cycles", 1024, 40.0, 0.021, 0.02), row("usdahd", 256, 1.0, 0.05, 0.04)]
    rows += [row("usdahd", 1024, 16.0, 0.025, 0.01)]
    (got,) = rb.time_to_quality(rows)
    assert got["target"] == 0.02 and got["usdahd_seconds"] == pytest.approx(4.0)


def test_time_to_quality_gives_the_ratio_of_every_repeat():
    """Repeated timings: the ratio uses the median times; ``ratios`` has one per repeat, from
    that repeat's times of both renderers (so a load change during one repeat shows)."""
    from benchmarks import reference_bench as rb

    def row(ren, spp, runs, err):
        return {"stage": "s", "renderer": ren, "spp": spp, "seconds": sorted(runs)[1],
                "seconds_runs": runs, "rel_rmse": err}  # fmt: skip

    rows = [
        row("cycles", 1024, [40.0, 20.0, 80.0], 0.02),
        row("usdahd", 256, [1.0, 1.0, 1.0], 0.04),
    ]
    rows += [row("usdahd", 1024, [16.0, 16.0, 8.0], 0.01)]
    (got,) = rb.time_to_quality(rows)
    # medians: usdahd 1 s and 16 s bracket the error -> 4 s; Cycles 40 s
    assert got["ratio"] == pytest.approx(0.1)
    # repeat 0: 4 / 40; repeat 1: 4 / 20; repeat 2: sqrt(1 * 8) / 80
    assert got["ratios"] == pytest.approx([0.1, 0.2, 8**0.5 / 80])
    md = rb.markdown(rows, type("A", (), {"resolution": 8, "samples": [16], "truth_spp": 64}), None)
    assert "median of 3 repeats" in md and "0.10, 0.20, 0.04 |" in md


def test_cycles_samples_of_their_own_are_in_the_command_and_must_hold_the_target(capsys):
    from benchmarks import reference_bench as rb

    def row(ren, spp, secs, err):
        return {"stage": "s", "renderer": ren, "spp": spp, "seconds": secs, "rel_rmse": err}

    rows = [row("cycles", 256, 10.0, 0.04), row("cycles", 1024, 40.0, 0.02)]
    rows += [row("usdahd", 16, 1.0, 0.04), row("usdahd", 256, 16.0, 0.01)]
    args = type("A", (), {"resolution": 128, "samples": [16, 256], "truth_spp": 64})
    md = rb.markdown(rows, args, None)
    assert "--samples 16 256 --truth-spp 64 --cycles-samples 256 1024" in md
    assert rb.main(["--cycles-samples", "256", "--stages", "floor_lamp"]) == 2
    assert "--cycles-samples must include 1024" in capsys.readouterr().err


def test_run_section_without_bpy_says_how_to_set_it_up(monkeypatch, tmp_path):
    from benchmarks import reference_bench as rb

    monkeypatch.delenv("USDAHD_BPY_PYTHON", raising=False)
    monkeypatch.setattr(
        runner,
        "find_bpy",
        lambda _=None: (_ for _ in ()).throw(
            runner.ReferenceUnavailable("no bpy interpreter configured; create one with: ...")
        ),
    )
    got = rb.run_section("quick", tmp_path)
    assert "skipped" in got
    assert "Not run: no bpy interpreter configured" in rb.section(got)


def test_warm_baker_bakes_what_the_cli_bakes(tmp_path):
    """benchmarks/reference/warm.py runs ``usdahd bake`` in one long-lived process: the same
    textures as the ``usdahd bake`` command (same code, same seed), a report per call, and a
    usage error comes back as exit code 2 instead of killing the process."""
    from benchmarks.reference.warm import WarmBaker

    stage = ROOT / "samples" / "open_plane.usda"
    args = ["--samples", "8", "--resolution", "8"]
    (tmp_path / "cli").mkdir()
    cli = compare.bake_usdahd(stage, tmp_path / "cli", 8, None, ["--samples", "8"], quiet=True)
    with WarmBaker() as wb:
        (tmp_path / "w").mkdir()
        a = wb.bake(stage, tmp_path / "w" / "open_plane.lightmaps.usda", None, args)
        assert wb.run(["bake", "--no-such-flag"])["code"] == 2
        (tmp_path / "w2").mkdir()
        b = wb.bake(stage, tmp_path / "w2" / "open_plane.lightmaps.usda", None, args)
    for r in (a, b):
        assert r["report"]["exit_code"] == 0 and r["report"]["seconds"] > 0
    ours = compare.usdahd_results(b["layer"])
    theirs = compare.usdahd_results(cli["layer"])
    assert ours.keys() == theirs.keys()
    for p in ours:
        np.testing.assert_array_equal(
            compare.usdahd_iz(ours[p]["record"])[0], compare.usdahd_iz(theirs[p]["record"])[0]
        )


def _spy_cycles(monkeypatch) -> list:
    """Record (spp, seed, point) of every Cycles render from now on (they still run)."""
    calls = []
    real = runner.run_cycles

    def spy(scene_file, spp, **kw):
        calls.append((spp, kw.get("seed"), kw.get("point", False)))
        return real(scene_file, spp, **kw)

    monkeypatch.setattr(runner, "run_cycles", spy)
    return calls


def test_smoke_truths_only_caches_what_bench_stage_reads(tmp_path, bpy_python, monkeypatch):
    """``reference_bench.py --truths-only`` computes the truths untimed (beforehand, e.g. at a
    low priority); a later bench_stage of the same stage and resolution renders no truth, only
    its own equal-spp Cycles run."""
    from benchmarks import reference_bench as rb

    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    args = ["--truths-only", "--stages", "floor_lamp", "--resolution", "8", "--truth-spp", "8"]
    assert rb.main([*args, "--bpy-python", bpy_python]) == 0
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 3  # box, and two point halves
    calls = _spy_cycles(monkeypatch)
    stage = ROOT / "samples" / "floor_lamp.usda"
    rows = rb.bench_stage(stage, 8, [4], 8, bpy_python, cycles_samples=[4])
    assert calls == [(4, compare.EQUAL_SEED, False)]
    assert {r["renderer"] for r in rows} == {"usdahd", "cycles"}


def test_smoke_stored_truths_serve_a_new_machine(tmp_path, bpy_python, monkeypatch):
    """``--truths-only --store`` keeps the truths in the repository's store; with an empty user
    cache (a new machine) bench_stage reads them from there and renders no truth."""
    from benchmarks import reference_bench as rb

    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    monkeypatch.setattr(runner, "STORE_DIR", tmp_path / "store")
    args = ["--truths-only", "--store", "--stages", "floor_lamp", "--resolution", "8",
            "--truth-spp", "8", "--bpy-python", bpy_python]  # fmt: skip
    assert rb.main(args) == 0
    assert len(list((tmp_path / "store").glob("*.npz"))) == 3
    for f in (tmp_path / "cache").glob("*.npz"):
        f.unlink()
    calls = _spy_cycles(monkeypatch)
    rb.bench_stage(ROOT / "samples" / "floor_lamp.usda", 8, [4], 8, bpy_python,
                   cycles_samples=[4])  # fmt: skip
    assert calls == [(4, compare.EQUAL_SEED, False)]


class _Scene:
    def __init__(self, digest):
        self._digest = digest

    def digest(self):
        return self._digest


def test_the_store_is_read_after_the_user_cache_without_bpy(tmp_path, monkeypatch):
    """A result in the repository's store (compressed, same arrays) is found with no bpy
    interpreter and an empty user cache; the user cache's own file wins when both exist; a
    key in neither needs bpy (the message says how to set it up)."""
    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    monkeypatch.setattr(runner, "STORE_DIR", tmp_path / "store")
    (tmp_path / "cache").mkdir()
    scene = _Scene("d" * 16)
    key = runner.cache_key(scene.digest(), 64, 1)
    iz = (np.arange(12, dtype=np.float32) * 0.37 + 1e-7).reshape(2, 2, 3)
    meta = {"meshes": [{"index": 0}], "spp": 64}
    runner.save_npz(tmp_path / "cache" / f"{key}.npz",
                    {"iz_0": iz, "meta": np.array(json.dumps(meta))})  # fmt: skip
    assert runner.store([tmp_path / "cache" / f"{key}.npz"]) == [tmp_path / "store" / f"{key}.npz"]
    assert runner.store([tmp_path / "cache" / f"{key}.npz"]) == []  # already there
    (tmp_path / "cache" / f"{key}.npz").unlink()
    info, images, hit = runner.cached_cycles(scene, None, 64, seed=1, bpy=None)
    assert hit and info["cached"] == str(tmp_path / "store" / f"{key}.npz")
    assert images[0].dtype == np.float32
    np.testing.assert_allclose(images[0], iz, rtol=2.0**-11, atol=0)
    runner.save_npz(tmp_path / "cache" / f"{key}.npz",
                    {"iz_0": iz + 1, "meta": np.array(json.dumps(meta))})  # fmt: skip
    _, images, _ = runner.cached_cycles(scene, None, 64, seed=1, bpy=None)
    np.testing.assert_array_equal(images[0], iz + 1)
    with pytest.raises(runner.ReferenceUnavailable, match="pip install bpy"):
        runner.cached_cycles(scene, None, 128, seed=1, bpy=None)


def test_the_store_keeps_every_value_to_float16_precision():
    """The store's float16 + power-of-two scale: relative rounding <= 2^-11 for every value
    within 2^28 of the image's largest (dark corners next to a lamp), zeros stay zero."""
    rng = np.random.default_rng(0)
    img = (10.0 ** rng.uniform(-8, 4, size=(64, 64, 3))).astype(np.float32)
    img[0, 0] = 0.0
    half, scale = runner._half(img)
    back = half.astype(np.float32) * np.float32(scale)
    assert np.log2(scale) == int(np.log2(scale))
    assert back[0, 0].tolist() == [0.0, 0.0, 0.0]
    keep = img >= img.max() * 2.0**-28
    rel = np.abs(back[keep] - img[keep]) / img[keep]
    assert rel.max() <= 2.0**-11 and np.sqrt(np.mean(rel**2)) < 2.5e-4


def test_store_needs_truths_only(capsys):
    from benchmarks import reference_bench as rb

    assert rb.main(["--store", "--stages", "floor_lamp"]) == 2
    assert "--store keeps the truths that --truths-only computes" in capsys.readouterr().err


def test_summary_meshes_checks_the_readme_bounds(tmp_path, capsys):
    """`summary --meshes`: one row per mesh against README.md's bounds (|bias| <= 1 % + 2
    standard errors, none here, so 1 %; ratio <= 1.5x); a mesh outside is marked and named in
    the last line."""
    import json

    def mesh(path, bias, ratio):
        return {
            "path": path,
            "compared": 100,
            "usdahd": {"bias": bias, "rel_rmse": 0.02},
            "cycles": {"bias": 0.0, "rel_rmse": 0.02 / ratio},
            "rmse_ratio": ratio,
        }

    res = {
        "stage": "/x/room.usda",
        "meshes": [mesh("/A", 0.004, 0.7), mesh("/B", -0.012, 0.9), mesh("/C", 0.0, 1.6)],
    }
    f = tmp_path / "r.json"
    f.write_text(json.dumps([res]))
    assert compare.main(["summary", "--meshes", str(f)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| room.usda")]
    assert [r.rstrip(" |").rsplit("| ", 1)[1] for r in rows] == ["yes", "**no**", "**no**"]
    assert "1 of 3 meshes within |bias| <= 1 % + 2 x sqrt(SE_truth^2 + SE_bake^2) and " \
           "ratio <= 1.5x" in out  # fmt: skip
    assert "outside: room.usda /B, room.usda /C" in out


def test_summary_meshes_bound_combines_the_truths_and_the_bakes_standard_errors(tmp_path, capsys):
    """`summary --meshes --noise`: the bias bound is 1 % + 2 sqrt(SE_truth^2 + SE_bake^2) with
    SE_truth = truth_noise / sqrt(texels) and SE_bake the row's ``bake_se``; a mesh within only
    by them reads `yes (noise)`; one beyond, or outside the ratio bound, `**no**`."""
    import json

    def mesh(path, bias, ratio, texels, truth_noise, bake_se=None):
        m = {
            "path": path,
            "compared": texels,
            "usdahd": {"bias": bias, "rel_rmse": 0.02},
            "cycles": {"bias": -0.005, "rel_rmse": 0.02 / ratio},
            "rmse_ratio": ratio,
            "truth_noise": truth_noise,
        }
        if bake_se is not None:
            m["bake_se"] = bake_se
        return m

    # /A: 25 texels at 10 % -> SE_truth 2 %, bound 1 % + 4 % = 5 %: -3 % is noise.
    # /B: 400 texels at 10 % -> SE_truth 0.5 %, bound 2 %: +3 % is beyond. /C: ratio 1.6x.
    # /E: /B's truth and the bake's own SE 1.5 %: bound 1 % + 2 sqrt(0.5^2 + 1.5^2) = 4.16 %.
    res = {
        "stage": "/x/room.usda",
        "meshes": [
            mesh("/A", -0.03, 0.7, 25, 0.10),
            mesh("/B", 0.03, 0.7, 400, 0.10),
            mesh("/C", 0.0, 1.6, 25, 0.10),
            mesh("/D", 0.002, 0.7, 25, 0.10),
            mesh("/E", 0.03, 0.7, 400, 0.10, bake_se=0.015),
        ],
    }
    f = tmp_path / "r.json"
    f.write_text(json.dumps([res]))
    assert compare.main(["summary", "--meshes", "--noise", str(f)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| room.usda")]
    assert [r.rstrip(" |").rsplit("| ", 1)[1] for r in rows] == [
        "yes (noise)",
        "**no**",
        "**no**",
        "yes",
        "yes (noise)",
    ]
    assert "| -0.50 % | 2.00 % | — | 5.00 % |" in rows[0]
    assert "| 0.50 % | 1.50 % | 4.16 % |" in rows[4]
    assert "3 of 5 meshes within" in out
    assert "outside: room.usda /B, room.usda /C" in out
    assert "2 of them within only by the standard errors" in out


def _synthetic_compare(seed, *, scale, sigma, truth_sigma=0.05, side=40):
    """compare_images on one mesh: a smooth signal, a truth with ``truth_sigma`` relative noise
    per texel (1024 spp), Cycles at equal spp as noisy as usdahd, usdahd = ``scale`` x signal
    with ``sigma`` relative noise per texel and the integrator's variances of it (s^2 / S
    with many degrees of freedom, the halves' with one), as bakevar.py hands them over."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:side, 0:side] / side
    signal = (1.0 + 0.5 * np.sin(6 * xx) * np.cos(4 * yy))[..., None] * np.ones(3)
    truth = signal * (1 + truth_sigma * rng.standard_normal((side, side, 1)))
    equal = signal * (1 + sigma * rng.standard_normal((side, side, 1)))
    ours = scale * signal * (1 + sigma * rng.standard_normal((side, side, 1)))
    var = (scale * signal[..., 0] * sigma) ** 2
    s2 = var * rng.chisquare(64, (side, side)) / 64
    halves = var * rng.chisquare(1, (side, side))
    meshes = [{"path": "/M", "baked": True, "resolution": [side, side]}]
    out = compare.compare_images(meshes, {0: truth}, {0: equal},
                                 {0: (ours, np.ones((side, side), bool))}, 256, 1024,
                                 {0: (s2, halves)})  # fmt: skip
    return out["meshes"][0]


def test_bake_standard_error_matches_the_scatter_of_the_mesh_mean():
    """``bake_se`` (from the integrator's per-texel variances) is the standard deviation of a
    mesh's bias over seeds: 40 seeds of 1444 texels at 30 % noise per texel (SE 0.79 %)."""
    rows = [_synthetic_compare(s, scale=1.0, sigma=0.3) for s in range(40)]
    assert all(r["compared"] == 38 * 38 for r in rows)
    biases = np.array([r["usdahd"]["bias"] for r in rows])
    se = np.array([r["bake_se"] for r in rows])
    # the truth's noise is in every bias too; remove its share (its SE 0.05 / 38)
    scatter = math.sqrt(max(biases.var(ddof=1) - (0.05 / 38) ** 2, 0.0))
    assert np.median(se) == pytest.approx(0.3 / 38, rel=0.1)
    assert scatter == pytest.approx(np.median(se), rel=0.3)  # 40 seeds: SD known to ~11 %


def test_bias_bound_counts_the_bakes_scatter_and_still_catches_a_3_percent_bias():
    """Unbiased bakes noisy enough that their mesh mean scatters beyond 1 % (SE 1.05 %) are
    within the bound for every seed, where the truth-only bound fails some; a bake scaled by
    1.03 at Sponza-like noise (10 % per texel, SE 0.26 %) is outside it for every seed."""
    noisy = [_synthetic_compare(s, scale=1.0, sigma=0.4) for s in range(20)]
    assert all(compare.within(r) for r in noisy)
    assert sum(abs(r["usdahd"]["bias"]) > 0.01 for r in noisy) >= 2
    truth_only = [dict(r, bake_se=None) for r in noisy]
    assert not all(compare.within(r) for r in truth_only)
    scaled = [_synthetic_compare(s, scale=1.03, sigma=0.1) for s in range(20)]
    assert all(r["usdahd"]["bias"] == pytest.approx(0.03, abs=0.01) for r in scaled)
    assert not any(compare.within(r) for r in scaled)
    assert all(compare.bias_bound(r) < 0.02 for r in scaled)


def test_bake_mean_error_needs_every_compared_texel():
    lit = np.ones((2, 2), bool)
    var = np.full((2, 2), 0.04)
    se = compare.bake_mean_error((var, var / 2), lit, 1.0)
    assert se["se"] == pytest.approx(math.sqrt(0.02 * 4) / 4) and se["se_s2"] == 0.1
    var[0, 0] = np.nan  # a compared texel the bake has no variance for
    assert compare.bake_mean_error((var, var), lit, 1.0) is None
    assert compare.bake_mean_error(None, lit, 1.0) is None
    # pooled over meshes even when one has no compared texel (a dark mesh)
    meshes = [{"path": p, "baked": True, "resolution": [9, 9]} for p in ("/A", "/B")]
    t, dark, v = np.ones((9, 9, 3)), np.zeros((9, 9, 3)), np.full((9, 9), 1e-4)
    cov = np.ones((9, 9), bool)
    out = compare.compare_images(meshes, {0: t, 1: dark}, {}, {0: (t, cov), 1: (dark, cov)},
                                 16, 64, {0: (v, v), 1: (v, v)})  # fmt: skip
    assert out["overall"]["bake_se"] == pytest.approx(math.sqrt(49e-4) / 49)


def test_seed_rows_pool_per_spp_with_the_standard_error_of_the_seeds():
    from benchmarks.reference import seeds

    rows = seeds.seed_rows({256: [-0.01, 0.0, 0.01, 0.02], 64: [0.5]})
    assert [r["spp"] for r in rows] == [64, 256]
    r = rows[1]
    assert r["seeds"] == 4 and r["bias"] == pytest.approx(0.005)
    sd = float(np.std([-0.01, 0.0, 0.01, 0.02], ddof=1))
    assert r["sd"] == pytest.approx(sd) and r["se"] == pytest.approx(sd / 2)
    assert (r["min"], r["max"]) == (-0.01, 0.02)
    assert math.isnan(rows[0]["se"])  # one seed: no standard error
    row = "| 256 | 4 | +0.50 % | 0.65 % | 1.29 % | -1.00 % / +2.00 % | — | — |"
    assert row in seeds.table(rows)
    # the bake's own SE estimates per seed: their RMS, beside the measured SD
    est = {"256": {"integrator": [0.01, 0.01, 0.014, 0.014], "seed_pairs": [0.012, 0.012]}}
    r = seeds.seed_rows({256: [-0.01, 0.0, 0.01, 0.02]}, est)[0]
    assert r["est_integrator"] == pytest.approx(math.sqrt((0.0001 + 0.000196) / 2))
    assert r["est_seed_pairs"] == pytest.approx(0.012)
    assert "| 1.22 % | 1.20 % |" in seeds.table([r])


def test_seeds_cli_usage_errors(tmp_path, capsys):
    import subprocess

    from benchmarks.reference import __main__ as ref_main

    stage = ROOT / "samples" / "open_plane.usda"
    base = ["seeds", str(stage), "--prim", "/World/Geometry/Plane", "--resolution", "8"]
    assert ref_main.main(["seeds", str(tmp_path / "none.usda"), "--prim", "/P",
                          "--resolution", "8"]) == 2  # fmt: skip
    assert "none.usda: no such file" in capsys.readouterr().err
    assert ref_main.main([*base, "--spp", "64,x"]) == 2
    assert "--spp takes comma-separated integers, got '64,x'" in capsys.readouterr().err
    assert ref_main.main([*base, "--seeds", "0"]) == 2
    assert "--seeds values must be >= 1, got '0'" in capsys.readouterr().err
    assert ref_main.main([*base, "--spp", "64,256", "--seeds", "4"]) == 2
    assert "--spp and --seeds need as many values each" in capsys.readouterr().err
    r = subprocess.run(
        [sys.executable, "-m", "benchmarks.reference", "seeds", str(tmp_path / "none.usda"),
         "--prim", "/P", "--resolution", "8"],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert r.returncode == 2 and "none.usda: no such file" in r.stderr


def test_seeds_open_plane_end_to_end(bpy_python, tmp_path, monkeypatch):
    """Every seed and spp of a uniform dome is exact (usdahd ~1e-8 at these samples), the
    texels are compare's (same count), and an unknown prim says so."""
    from benchmarks.reference import seeds

    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    stage = ROOT / "samples" / "open_plane.usda"
    cmp = compare.run_compare(
        stage, resolution=8, truth_spp=8, bpy=bpy_python, quiet=True, point=True
    )
    res = seeds.run_seeds(stage, "/World/Geometry/Plane", resolution=8, spps=[16, 64], seeds=[2, 3],
                          truth_spp=8, bpy=bpy_python, quiet=True)  # fmt: skip
    assert res["compared"] == cmp["meshes"][0]["compared"] > 0 and res["truth_cached"]
    assert [(r["spp"], r["seeds"]) for r in res["rows"]] == [(16, 2), (64, 3)]
    assert all(abs(b) < 1e-4 for v in res["biases"].values() for b in v)
    with pytest.raises(compare.CompareError, match="/World/Nope: not baked"):
        seeds.run_seeds(stage, "/World/Nope", resolution=8, spps=[16], seeds=[1],
                        truth_spp=8, bpy=bpy_python, quiet=True)  # fmt: skip


def test_truth_pair_usage_errors(tmp_path, capsys):
    from benchmarks.reference import truth_pair

    assert truth_pair.main([str(tmp_path / "none.usda"), "--resolution", "8"]) == 2
    assert "no such file" in capsys.readouterr().err
    stage = str(ROOT / "samples" / "open_plane.usda")
    assert truth_pair.main([stage, "--resolution", "8", "--spp", "16", "--seeds", "1"]) == 2
    assert "two values each" in capsys.readouterr().err
    assert truth_pair.main([stage, "--resolution", "8", "--spp", "16,16", "--seeds", "1,1"]) == 2
    assert "must differ" in capsys.readouterr().err


def test_truth_pair_open_plane_end_to_end(bpy_python, tmp_path, monkeypatch, capsys):
    """Two truths of the uniform dome agree exactly (every path escapes to the same radiance)."""
    from benchmarks.reference import truth_pair

    monkeypatch.setenv(runner.CACHE_VAR, str(tmp_path / "cache"))
    args = [str(ROOT / "samples" / "open_plane.usda"), "--resolution", "8", "--spp", "8,16",
            "--seeds", "1,3", "--bpy-python", bpy_python, "--quiet"]  # fmt: skip
    assert truth_pair.main([*args, "--json"]) == 0
    res = __import__("json").loads(capsys.readouterr().out)
    (m,) = res["meshes"].values()
    assert m["texels"] > 0 and abs(m["bias"]) < 1e-5 and res["cached"] == [False, False]
    assert truth_pair.main(args) == 0  # now from the cache, as a table
    assert "| truth 8 spp (seed 1) vs 16 spp (seed 3) |" in capsys.readouterr().out


def test_reference_bench_leaves_out_texels_not_estimated_at_the_centre_for_both_renderers():
    """Texels a bake fills from neighbours (bakevar's ``invalid``: e.g. a ceiling under an
    emissive panel 1 cm below it) or samples off the centre (``moved``: contacts, rim texels
    under a low cover) do not hold usdahd's estimate at the point the point truth probes:
    every run's such texels (their union) leave the comparison for both renderers, and the
    section says how many. emissive_only at 128^2, 256 spp: 1.47 % with them."""
    from benchmarks import reference_bench as rb
    from benchmarks.reference import compare

    h = w = 8
    xy = np.array([(x, y) for y in range(h) for x in range(w)])
    inv_a = np.zeros(h * w, bool)
    inv_a[3 * w + 3] = True  # texel (3, 3) filled in one run
    inv_b = np.zeros(h * w, bool)
    inv_b[4 * w + 4] = True  # texel (4, 4) in another
    moved = np.zeros(h * w, bool)
    moved[5 * w + 2] = True  # texel (2, 5) sampled off its centre
    cov = np.ones((h, w), bool)
    left = {}
    for inv, mv in ((inv_a, np.zeros(0, bool)), (inv_b, moved)):  # an old file: no "moved"
        var = {"/m": {"xy": xy, "s2": np.zeros(h * w), "halves": np.zeros(h * w),
                      "invalid": inv, "moved": mv}}  # fmt: skip
        rb._add_left_out(left, 0, var, "/m", cov)
    assert left[0].sum() == 3 and left[0][3, 3] and left[0][4, 4] and left[0][5, 2]
    rb._add_left_out(left, 1, {}, "/other", cov)  # no variance for a prim: nothing added
    assert 1 not in left and rb._left_out_count(left) == 3
    # compare_images then judges neither renderer on those texels
    truth = np.ones((h, w, 3))
    ours = truth.copy()
    ours[3, 3] = ours[5, 2] = 5.0
    meshes = [{"path": "/m", "baked": True, "resolution": [w, h]}]
    got = compare.compare_images(meshes, {0: truth}, {0: ours}, {0: (ours, cov)}, 16, 64,
                                 filled=left)  # fmt: skip
    assert got["overall"]["usdahd"]["rel_rmse"] == pytest.approx(0.0)
    assert got["overall"]["cycles"]["rel_rmse"] == pytest.approx(0.0)
    args = type("A", (), {"resolution": 8, "samples": [16], "truth_spp": 64})
    rows = [{"stage": "s", "renderer": "cycles", "spp": 1024, "seconds": 4.0, "rel_rmse": 0.02},
            {"stage": "s", "renderer": "usdahd", "spp": 16, "seconds": 1.0, "rel_rmse": 0.01,
             "left_out": 3}]  # fmt: skip
    assert "left out for both renderers (s 3 texels)" in rb.markdown(rows, args, None)


def test_bakevar_marks_the_texels_whose_sample_point_left_the_centre():
    from benchmarks.reference import bakevar

    xy = np.array([[0, 0], [1, 0], [2, 3], [5, 1]])
    got = bakevar._rows_in(xy, [np.array([[2, 3]]), np.array([[5, 1], [9, 9]])])
    assert got.tolist() == [False, False, True, True]
    assert not bakevar._rows_in(xy, []).any()


def test_summary_plot_times_equal_error_from_the_stored_production_rows(tmp_path, capsys):
    """`summary --plot`: the stored quiet Sponza 64² row gives docs/benchmarks.md's time to
    equal error (net of the truth's noise, Cycles' error as 1/sqrt(time) from its bake call:
    (4.79 / 2.29)² x 31.7 s = 138 s against usdahd's 57.2 s, 0.41x), and a PNG is written."""
    from benchmarks.reference import production_plot

    f = Path(compare.__file__).parent / "results/compare_sponza_point1024_r64_quiet_eef9b39.json"
    eq = production_plot.equal_error(json.loads(f.read_text()))
    assert eq["usdahd"][1] == pytest.approx(0.0229, abs=5e-4)
    assert eq["cycles"][1] == pytest.approx(0.0479, abs=5e-4)
    assert eq["cycles_at_usdahd_error"] == pytest.approx(138, abs=2)
    assert eq["ratio"] == pytest.approx(0.41, abs=0.01)
    png = tmp_path / "p.png"
    assert compare.main(["summary", str(f), "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| sponza.usdc | 16609 |" in capsys.readouterr().out


def test_production_plot_labels_a_bake_at_the_automatic_density_auto():
    """A compare run without --resolution (usdahd's automatic texel density: each mesh its
    own resolution) is labelled "<stage> auto", not by its first mesh's resolution; the
    stored classroom run at the defaults gives the ratio docs/benchmarks.md states."""
    from benchmarks.reference import production_plot

    base = Path(compare.__file__).parent / "results"
    auto = json.loads((base / "compare_classroom_point1024_auto_cfed267.json").read_text())
    assert production_plot.stage_label(auto) == "classroom auto"
    fixed = json.loads((base / "compare_classroom_point1024_r64_quiet_b4536ba.json").read_text())
    assert production_plot.stage_label(fixed) == "classroom 64²"
    eq = production_plot.equal_error(auto)
    assert eq["ratio"] == pytest.approx(1.63, abs=0.01)
