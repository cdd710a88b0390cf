"""Bake what the stage says (issue 13): time, material binding purpose, UsdTransform2d,
metallic, Hydra's colour-space rule, usdz packages through Ar, the silent cases of the scene
reader, validate on an unbaked stage, light-link membership. Each case builds its own stage."""

from __future__ import annotations

import json
import math

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdUtils

from tests.scenes import new_stage
from usdahd import cli
from usdahd.numerics import sh as shmod
from usdahd.scene import lights as L
from usdahd.usd.materials import read_image
from usdahd.usd.reader import load_scene
from usdahd.usd.time import resolve_time

FAST = ["--resolution", "8", "--samples", "32", "--bounces", "0", "--quiet"]


# ----------------------------------------------------------------------------- helpers


def _plane(st, path="/World/Plane", size=1.0, z=0.0, st_uv=True):
    """A size x size quad at height z facing +Z, with vertex st UVs in [0, 1]."""
    h = size / 2
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr(
        [Gf.Vec3f(-h, -h, z), Gf.Vec3f(h, -h, z), Gf.Vec3f(h, h, z), Gf.Vec3f(-h, h, z)]
    )
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    m.CreateNormalsAttr([Gf.Vec3f(0, 0, 1)] * 4)
    m.SetNormalsInterpolation("vertex")
    if st_uv:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        pv.Set(
            [Gf.Vec2f(0.05, 0.05), Gf.Vec2f(0.95, 0.05), Gf.Vec2f(0.95, 0.95), Gf.Vec2f(0.05, 0.95)]
        )
    return m


def _write_png(path, pixels, fmt="uint8"):
    pixels = np.ascontiguousarray(pixels)
    h, w = pixels.shape[:2]
    c = 1 if pixels.ndim == 2 else pixels.shape[2]
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.attribute("oiio:UnassociatedAlpha", 1)  # store the pixels as given (straight alpha)
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels.reshape(h, w, c))
    out.close()


def _material(st, path, color=(0.5, 0.5, 0.5), **inputs):
    mat = UsdShade.Material.Define(st, path)
    sh = UsdShade.Shader.Define(st, f"{path}/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    for name, (tname, value) in inputs.items():
        sh.CreateInput(name, tname).Set(value)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat, sh


def _textured_material(st, path, file, out="rgb", cs=None, transform=None, varname="st"):
    mat, sh = _material(st, path)
    tex = UsdShade.Shader.Define(st, f"{path}/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(file))
    if cs:
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(cs)
    tex.CreateOutput(out, Sdf.ValueTypeNames.Float3 if out == "rgb" else Sdf.ValueTypeNames.Float)
    rd = UsdShade.Shader.Define(st, f"{path}/Reader")
    rd.CreateIdAttr("UsdPrimvarReader_float2")
    rd.CreateInput("varname", Sdf.ValueTypeNames.String).Set(varname)
    rd.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    src = rd
    if transform is not None:
        xf = UsdShade.Shader.Define(st, f"{path}/Transform")
        xf.CreateIdAttr("UsdTransform2d")
        xf.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(
            rd.ConnectableAPI(), "result"
        )
        scale, rot, trans = transform
        xf.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*scale))
        xf.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(rot)
        xf.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*trans))
        xf.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        src = xf
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(src.ConnectableAPI(), "result")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.ConnectableAPI(), out
    )
    return mat


def _bind(prim, mat, purpose=None):
    api = UsdShade.MaterialBindingAPI.Apply(prim)
    if purpose is None:
        api.Bind(mat)
    else:
        api.Bind(mat, materialPurpose=purpose)


def _sun(st, path="/World/Sun", intensity=None, normalize=True):
    sun = UsdLux.DistantLight.Define(st, path)
    if intensity is not None:
        sun.CreateIntensityAttr(intensity)
    sun.CreateNormalizeAttr(normalize)
    return sun


def _baked_iz(layer, prim="/World/Plane"):
    """Mean I_z (RGB) of a baked prim from its SH sidecar, and the settings record."""
    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(layer))
    res = schema.read_results(stage.GetPrimAtPath(prim))
    side = schema.read_record_pixels(res, "sh", schema.SH_SIDECAR_CHANNELS)
    cover = side[..., -1] > 0
    iz = shmod.iz(side[cover][:, :27].reshape(-1, 3, 9).astype(np.float64))
    return iz, res


def _run(argv, capsys):
    code = cli.main(argv)
    out = capsys.readouterr()
    return code, out


# -------------------------------------------------------------------------------------- time


def test_time_sampled_only_distant_light_bakes_at_start_time_code(tmp_path, capsys):
    src = tmp_path / "sun.usda"
    st = new_stage(meters_per_unit=1.0, path=src)
    st.SetStartTimeCode(1)
    st.SetEndTimeCode(10)
    _plane(st)
    sun = _sun(st)
    sun.GetIntensityAttr().Set(8.0, 1.0)  # only a time sample: the fallback would be 50000
    sun.GetIntensityAttr().Set(2.0, 10.0)
    st.GetRootLayer().Save()
    sc = load_scene(str(src))
    assert sc.time == 1.0 and sc.time_auto
    assert any("baked at time 1 (the stage's startTimeCode)" in w for w in sc.warnings)
    code, out = _run(["bake", str(src), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert report["time"] == 1.0
    iz, res = _baked_iz(tmp_path / "sun.lightmaps.usda")
    # normalized DistantLight: intensity = illuminance E, I_z = E / pi, no occluders
    np.testing.assert_allclose(iz, 8.0 / np.pi, rtol=2e-3)
    assert res.settings["time"] == 1.0 and res.settings["time_auto"] is True
    # --time 10 reads the other sample; the time is part of the hash: the prim re-bakes
    code, out = _run(["bake", str(src), "--json", "--time", "10", *FAST[:-1]], capsys)
    report = json.loads(out.out)
    assert report["prims"][0]["status"] == "baked" and "settings" in report["prims"][0]["reason"]
    iz, res = _baked_iz(tmp_path / "sun.lightmaps.usda")
    np.testing.assert_allclose(iz, 2.0 / np.pi, rtol=2e-3)
    assert res.settings["time"] == 10.0 and res.settings["time_auto"] is False
    assert cli.main(["validate", str(tmp_path / "sun.lightmaps.usda"), "--strict"]) == 0


def test_validate_reports_stale_when_the_values_at_the_bake_time_change(tmp_path, capsys):
    src = tmp_path / "sun.usda"
    st = new_stage(meters_per_unit=1.0, path=src)
    st.SetStartTimeCode(1)
    _plane(st)
    _sun(st).GetIntensityAttr().Set(8.0, 1.0)
    st.GetRootLayer().Save()
    assert _run(["bake", str(src), *FAST], capsys)[0] == 0
    layer = tmp_path / "sun.lightmaps.usda"
    capsys.readouterr()
    assert _run(["validate", str(layer)], capsys)[0] == 0
    # the value at the bake time changes: stale
    st.GetPrimAtPath("/World/Sun").GetAttribute("inputs:intensity").Set(4.0, 1.0)
    st.GetRootLayer().Save()
    code, out = _run(["validate", str(layer), "--json"], capsys)
    findings = json.loads(out.out)["findings"]
    assert code == 1
    assert any(f["code"] == "Stale" and "lights" in f["message"] for f in findings)
    # a change elsewhere on the timeline does not make the bake stale
    st.GetPrimAtPath("/World/Sun").GetAttribute("inputs:intensity").Set(8.0, 1.0)
    st.GetPrimAtPath("/World/Sun").GetAttribute("inputs:intensity").Set(99.0, 50.0)
    st.GetRootLayer().Save()
    assert _run(["validate", str(layer)], capsys)[0] == 0
    # moving startTimeCode moves the time a re-bake would read: stale, naming the time
    st.SetStartTimeCode(50)
    st.GetRootLayer().Save()
    code, out = _run(["validate", str(layer), "--json"], capsys)
    msgs = [f["message"] for f in json.loads(out.out)["findings"] if f["code"] == "Stale"]
    assert code == 1 and any("bake time (1.0 -> 50.0" in m for m in msgs)


def test_samples_only_xform_and_points_are_read_at_the_bake_time():
    st = new_stage(meters_per_unit=1.0)
    st.SetStartTimeCode(2)
    m = _plane(st)
    op = m.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 3), 2.0)  # samples only: not identity
    op.Set(Gf.Vec3d(0, 0, 9), 5.0)
    sc = load_scene(st)
    np.testing.assert_allclose(sc.meshes[0].points[:, 2], 3.0)
    sc = load_scene(st, time=5)
    np.testing.assert_allclose(sc.meshes[0].points[:, 2], 9.0)
    assert sc.time == 5.0 and not sc.time_auto


def test_default_plus_samples_warns_and_uses_the_sample():
    st = new_stage(meters_per_unit=1.0)
    st.SetStartTimeCode(1)
    _plane(st)
    sun = _sun(st, intensity=3.0)  # a default ...
    sun.GetIntensityAttr().Set(6.0, 1.0)  # ... and samples
    sc = load_scene(st)
    (light,) = sc.lights
    np.testing.assert_allclose(
        np.max(light.radiance) * np.pi * math.sin(light.half_angle) ** 2, 6.0
    )
    assert any(
        "default value and its time samples disagree; the time sample" in w for w in sc.warnings
    )
    sc = load_scene(st, time="default")
    (light,) = sc.lights
    np.testing.assert_allclose(
        np.max(light.radiance) * np.pi * math.sin(light.half_angle) ** 2, 3.0
    )
    assert any("disagree; the default is used" in w for w in sc.warnings)
    # agreeing default and samples: no warning
    sun.GetIntensityAttr().Set(3.0, 1.0)
    assert not any("disagree" in w for w in load_scene(st).warnings)


def test_static_stage_reads_the_default_time_without_warnings():
    st = new_stage(meters_per_unit=1.0)
    _plane(st)
    _sun(st, intensity=1.0)
    t, auto = resolve_time(st, None)
    assert t.IsDefault() and auto
    sc = load_scene(st)
    assert sc.time is None and sc.time_setting == "default"
    assert not any("time" in w for w in sc.warnings)


def test_samples_without_start_time_code_use_the_first_sample():
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    m.AddTranslateOp().Set(Gf.Vec3d(0, 0, 4), 7.0)
    warnings = []
    t, _ = resolve_time(st, None, warnings.append)
    assert t.GetValue() == 7.0
    assert any("no startTimeCode: baked at the first sample, time 7" in w for w in warnings)


@pytest.mark.parametrize("value", ["soon", "nan", "inf"])
def test_bad_time_is_a_usage_error(tmp_path, capsys, value):
    src = tmp_path / "p.usda"
    st = new_stage(meters_per_unit=1.0, path=src)
    _plane(st)
    _sun(st, intensity=1.0)
    st.GetRootLayer().Save()
    code, out = _run(["bake", str(src), "--time", value, *FAST], capsys)
    assert code == 2 and "--time" in out.err


def test_time_sampled_visibility_is_read_at_the_bake_time():
    st = new_stage(meters_per_unit=1.0)
    st.SetStartTimeCode(1)
    _plane(st)
    hidden = _plane(st, "/World/Blinker", z=1.0)
    hidden.GetVisibilityAttr().Set(UsdGeom.Tokens.invisible, 1.0)
    hidden.GetVisibilityAttr().Set(UsdGeom.Tokens.inherited, 2.0)
    sc = load_scene(st)
    assert [m.path for m in sc.meshes] == ["/World/Plane"]
    assert any("/World/Blinker: visibility is animated" in w for w in sc.warnings)
    assert [m.path for m in load_scene(st, time=2).meshes] == ["/World/Plane", "/World/Blinker"]


# ------------------------------------------------------------------------------- materials


def test_full_purpose_binding_wins_over_all_purpose():
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    red, _ = _material(st, "/World/Red", (0.8, 0.1, 0.1))
    green, _ = _material(st, "/World/Green", (0.1, 0.8, 0.1))
    blue, _ = _material(st, "/World/Blue", (0.1, 0.1, 0.8))
    api = UsdShade.MaterialBindingAPI.Apply(m.GetPrim())
    api.Bind(red)
    api.Bind(green, materialPurpose=UsdShade.Tokens.full)
    api.Bind(blue, materialPurpose=UsdShade.Tokens.preview)
    sc = load_scene(st)
    mat = sc.materials[sc.meshes[0].material[0]]
    assert mat.name == "/World/Green"
    np.testing.assert_allclose(mat.albedo, (0.1, 0.8, 0.1), rtol=1e-6)


def test_metallic_scales_the_diffuse_albedo():
    st = new_stage(meters_per_unit=1.0)
    _plane(st, "/World/A")
    _plane(st, "/World/B", z=1)
    _plane(st, "/World/C", z=2)
    _plane(st, "/World/D", z=3)
    f = Sdf.ValueTypeNames.Float
    i = Sdf.ValueTypeNames.Int
    _bind(st.GetPrimAtPath("/World/A"), _material(st, "/World/M1", metallic=(f, 1.0))[0])
    _bind(st.GetPrimAtPath("/World/B"), _material(st, "/World/M2", metallic=(f, 0.25))[0])
    spec = _material(st, "/World/M3", metallic=(f, 1.0), useSpecularWorkflow=(i, 1))[0]
    _bind(st.GetPrimAtPath("/World/C"), spec)
    mat4, sh4 = _material(st, "/World/M4")
    tex = UsdShade.Shader.Define(st, "/World/M4/MetalTex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.6, 0, 0, 1))
    sh4.CreateInput("metallic", f).ConnectToSource(tex.ConnectableAPI(), "r")
    _bind(st.GetPrimAtPath("/World/D"), mat4)
    sc = load_scene(st)
    alb = {m.path: sc.materials[m.material[0]].albedo for m in sc.meshes}
    np.testing.assert_allclose(alb["/World/A"], 0.0)
    np.testing.assert_allclose(alb["/World/B"], 0.5 * 0.75)
    np.testing.assert_allclose(alb["/World/C"], 0.5)  # specular workflow: metallic unused
    # a UsdUVTexture without a file gives its fallback
    # (metallic textures: tests/bake/test_metallic.py)
    np.testing.assert_allclose(alb["/World/D"], 0.5 * 0.4, rtol=1e-6)
    assert not any("not honoured" in w for w in sc.warnings)


def test_metallic_scales_an_albedo_texture(tmp_path):
    png = tmp_path / "grey.png"
    _write_png(png, np.full((4, 4, 3), 255, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat = _textured_material(st, "/World/Tex", png)
    UsdShade.Shader(st.GetPrimAtPath("/World/Tex/Surface")).CreateInput(
        "metallic", Sdf.ValueTypeNames.Float
    ).Set(0.6)
    _bind(m.GetPrim(), mat)
    sc = load_scene(st)
    mat = sc.materials[sc.meshes[0].material[0]]
    got = mat.albedo_tex.sample(np.array([[0.5, 0.5]], np.float32))
    np.testing.assert_allclose(got, [[0.4, 0.4, 0.4]], rtol=1e-4)  # OCIO: 1 -> 1.00002


def test_unhonoured_inputs_get_one_warning():
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat, sh = _material(
        st,
        "/World/Bumpy",
        clearcoat=(Sdf.ValueTypeNames.Float, 1.0),
        occlusion=(Sdf.ValueTypeNames.Float, 0.5),
    )
    nrm = UsdShade.Shader.Define(st, "/World/Bumpy/NormalMap")
    nrm.CreateIdAttr("UsdUVTexture")
    sh.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(
        nrm.ConnectableAPI(), "rgb"
    )
    _bind(m.GetPrim(), mat)
    m2 = _plane(st, "/World/Other", z=1)
    mat2, sh2 = _material(st, "/World/Bumpy2")
    sh2.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(
        nrm.ConnectableAPI(), "rgb"
    )
    _bind(m2.GetPrim(), mat2)
    w = [x for x in load_scene(st).warnings if "not honoured" in x]
    assert len(w) == 3  # one per input, naming every material
    assert any(
        "normal (connected) is not honoured by the bake in 2 materials (/World/Bumpy, "
        "/World/Bumpy2)" in x
        for x in w
    )
    assert any("clearcoat = 1 is not honoured" in x for x in w)
    assert any("occlusion = 0.5 is not honoured" in x for x in w)


def test_transform2d_applies_to_the_texture_coordinates(tmp_path):
    png = tmp_path / "c.png"
    _write_png(png, np.full((4, 4, 3), 128, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat = _textured_material(st, "/World/Tiled", png, transform=((2.0, 3.0), 90.0, (0.25, -0.5)))
    _bind(m.GetPrim(), mat)
    sc = load_scene(st)
    md = sc.meshes[0]
    name = sc.materials[md.material[0]].texcoord
    assert name.startswith("st@")
    uv = md.uv.astype(np.float64)
    # UsdPreviewSurface spec: out = rotate(scale * in) + translation (rotation in degrees, CCW)
    s = uv * [2.0, 3.0]
    want = np.stack([-s[..., 1], s[..., 0]], axis=-1) + [0.25, -0.5]
    np.testing.assert_allclose(sc.texcoords[0][name], want, atol=1e-5)
    # an identity transform keeps the primvar's own name
    st2 = new_stage(meters_per_unit=1.0)
    m2 = _plane(st2)
    _bind(m2.GetPrim(), _textured_material(st2, "/World/T", png, transform=((1, 1), 0.0, (0, 0))))
    sc2 = load_scene(st2)
    assert sc2.materials[sc2.meshes[0].material[0]].texcoord == "st"


# ----------------------------------------------------------------------------- colour spaces


def _texel(path, cs="auto", file_cs=""):
    return read_image(str(path), cs, None, file_colorspace=file_cs)[0, 0]


def _srgb_decode(v):
    """IEC 61966-2-1 sRGB EOTF (independent of OpenImageIO)."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def test_auto_colour_space_follows_hydra(tmp_path):
    code = 128
    v = code / 255.0
    mask = tmp_path / "mask.png"
    _write_png(mask, np.full((2, 2), code, np.uint8))
    rgb = tmp_path / "rgb.png"
    _write_png(rgb, np.full((2, 2, 3), code, np.uint8))
    rgba = tmp_path / "rgba.png"
    _write_png(rgba, np.full((2, 2, 4), code, np.uint8))
    deep = tmp_path / "deep.png"
    _write_png(deep, np.full((2, 2, 3), code * 257, np.uint16), fmt="uint16")
    # 1-channel 8-bit: linear, as USD's own image loader reads it (a cut-out mask)
    np.testing.assert_allclose(_texel(mask), [v], atol=1e-6)
    # 3/4-channel 8-bit: sRGB-decoded colour, alpha left linear
    np.testing.assert_allclose(_texel(rgb), [_srgb_decode(v)] * 3, atol=1e-4)
    np.testing.assert_allclose(_texel(rgba)[:3], [_srgb_decode(v)] * 3, atol=1e-4)
    np.testing.assert_allclose(_texel(rgba)[3], v, atol=1e-6)
    # 16-bit: linear
    np.testing.assert_allclose(_texel(deep), [v] * 3, atol=1e-5)
    # explicit tokens win; the file's colorSpace metadata decides under auto
    np.testing.assert_allclose(_texel(mask, "sRGB"), [_srgb_decode(v)], atol=1e-4)
    np.testing.assert_allclose(_texel(rgb, "raw"), [v] * 3, atol=1e-6)
    np.testing.assert_allclose(_texel(rgb, "auto", "lin_rec709_scene"), [v] * 3, atol=1e-6)
    np.testing.assert_allclose(
        _texel(mask, "auto", "srgb_rec709_scene"), [_srgb_decode(v)], atol=1e-4
    )


def test_colour_space_metadata_on_the_file_input_is_used(tmp_path):
    png = tmp_path / "lin.png"
    _write_png(png, np.full((2, 2, 3), 128, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat = _textured_material(st, "/World/Lin", png)
    UsdShade.Shader(st.GetPrimAtPath("/World/Lin/Tex")).GetInput("file").GetAttr().SetColorSpace(
        "lin_rec709_scene"
    )
    _bind(m.GetPrim(), mat)
    sc = load_scene(st)
    tex = sc.materials[sc.meshes[0].material[0]].albedo_tex
    np.testing.assert_allclose(tex.data[0, 0], [128 / 255] * 3, atol=1e-6)


def test_unknown_colour_space_warns(tmp_path):
    png = tmp_path / "x.png"
    _write_png(png, np.full((2, 2, 3), 128, np.uint8))
    warnings = []
    data = read_image(str(png), "auto", warnings.append, file_colorspace="no_such_space")
    assert data is not None
    assert any("cannot convert colour space 'no_such_space'" in w for w in warnings)


# ------------------------------------------------------------------------- usdz through Ar


def _usdz_source(tmp_path):
    """A plane with a texture and a DomeLight with a latlong texture, packaged as a usdz."""
    work = tmp_path / "pkg"
    (work / "textures").mkdir(parents=True)
    _write_png(work / "textures" / "albedo.png", np.full((4, 4, 3), 200, np.uint8))
    sky = np.full((8, 16, 3), 0.5, np.float32)
    out = oiio.ImageOutput.create(str(work / "textures" / "sky.exr"))
    out.open(str(work / "textures" / "sky.exr"), oiio.ImageSpec(16, 8, 3, "float"))
    out.write_image(sky)
    out.close()
    st = new_stage(meters_per_unit=1.0, path=work / "scene.usda")
    st.SetDefaultPrim(st.DefinePrim("/World", "Xform"))
    m = _plane(st)
    _bind(m.GetPrim(), _textured_material(st, "/World/Look", "./textures/albedo.png"))
    dome = UsdLux.DomeLight.Define(st, "/World/Sky")
    dome.CreateTextureFileAttr("./textures/sky.exr")
    dome.CreateIntensityAttr(1.0)
    st.GetRootLayer().Save()
    usdz = tmp_path / "scene.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(work / "scene.usda")), str(usdz))
    return usdz


def test_textures_inside_a_usdz_package_are_read(tmp_path):
    usdz = _usdz_source(tmp_path)
    sc = load_scene(str(usdz))
    assert not any("cannot read" in w for w in sc.warnings), sc.warnings
    mat = sc.materials[sc.meshes[0].material[0]]
    assert "[textures/albedo.png]" in mat.albedo_tex.path
    np.testing.assert_allclose(mat.albedo_tex.data[0, 0], [_srgb_decode(200 / 255)] * 3, atol=1e-4)
    (dome,) = [x for x in sc.lights if isinstance(x, L.DomeLight)]
    np.testing.assert_allclose(dome.image, 0.5)


def test_bake_and_validate_a_usdz_package(tmp_path, capsys):
    usdz = _usdz_source(tmp_path)
    code, out = _run(["bake", str(usdz), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    layer = tmp_path / "scene.lightmaps.usda"
    iz, _ = _baked_iz(layer)
    # a uniform latlong dome of radiance 0.5 over an open plane: I_z = 0.5
    np.testing.assert_allclose(iz, 0.5, atol=0.03)
    code, out = _run(["validate", str(layer), "--strict"], capsys)
    assert code == 0, out.out
    # the whole bake packaged: every texture lives inside the usdz
    packed = tmp_path / "baked.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer)), str(packed))
    code, out = _run(["validate", str(packed), "--strict", "--json"], capsys)
    report = json.loads(out.out)
    assert code == 0, report["findings"]
    assert report["prims"] == ["/World/Plane"]


def test_missing_asset_in_a_package_is_reported(tmp_path, capsys):
    from usdahd.usd import assets

    usdz = _usdz_source(tmp_path)
    assert assets.exists(f"{usdz}[textures/albedo.png]")
    assert not assets.exists(f"{usdz}[textures/nope.png]")
    warnings = []
    assert read_image(f"{usdz}[textures/nope.png]", "auto", warnings.append) is None
    assert any("cannot read texture" in w for w in warnings)


# -------------------------------------------------------------------- also silent (scene)


def test_render_purpose_child_of_a_guide_parent_is_baked():
    st = new_stage(meters_per_unit=1.0)
    g = UsdGeom.Xform.Define(st, "/World/Guides")
    g.CreatePurposeAttr(UsdGeom.Tokens.guide)
    _plane(st, "/World/Guides/Rendered").CreatePurposeAttr(UsdGeom.Tokens.render)
    _plane(st, "/World/Guides/Inherits", z=1)
    sc = load_scene(st)
    assert [m.path for m in sc.meshes] == ["/World/Guides/Rendered"]


def test_shadow_color_and_unauthored_intensity_warn():
    st = new_stage(meters_per_unit=1.0)
    _plane(st)
    sun = UsdLux.DistantLight.Define(st, "/World/Sun")  # no intensity authored
    UsdLux.ShadowAPI.Apply(sun.GetPrim())
    sun.GetPrim().CreateAttribute("inputs:shadow:color", Sdf.ValueTypeNames.Color3f).Set(
        Gf.Vec3f(0.2, 0.2, 0.5)
    )
    sc = load_scene(st)
    assert any(
        "/World/Sun: inputs:shadow:color (0.2, 0.2, 0.5) is not supported" in w for w in sc.warnings
    )
    assert any("1 lights do not author inputs:intensity (/World/Sun)" in w for w in sc.warnings)


def test_unauthored_subdivision_scheme_warns_for_meshes_with_normals():
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    m.GetSubdivisionSchemeAttr().Clear()
    sc = load_scene(st)
    w = [x for x in sc.warnings if "leave subdivisionScheme unauthored" in x]
    assert len(w) == 1 and "/World/Plane" in w[0] and "catmullClark" in w[0]
    assert not sc.computed_normals  # its authored normals still win


def test_too_dim_distant_light_warns():
    st = new_stage(meters_per_unit=1.0)
    _plane(st)
    _sun(st, "/World/Sun", intensity=1000.0)
    _sun(st, "/World/Moon", intensity=1.0, normalize=False)  # radiance 1: E = 6.7e-5
    sc = load_scene(st)
    w = [x for x in sc.warnings if "contributes nothing" in x]
    assert len(w) == 1 and w[0].startswith("/World/Moon") and "normalize" in w[0]
    _sun(st, "/World/Moon", intensity=500.0)
    assert not any("contributes nothing" in x for x in load_scene(st).warnings)


def test_light_and_shadow_link_membership():
    st = new_stage(meters_per_unit=1.0)
    _plane(st, "/World/Ground")
    _plane(st, "/World/Wall", z=1)
    sun = _sun(st, intensity=1.0)
    light = UsdLux.LightAPI(sun.GetPrim())
    link = light.GetLightLinkCollectionAPI()
    link.GetIncludeRootAttr().Set(False)
    link.GetIncludesRel().AddTarget("/World/Wall")
    shadow = light.GetShadowLinkCollectionAPI()
    shadow.GetExcludesRel().AddTarget("/World/Wall")
    _sun(st, "/World/Fill", intensity=1.0)  # default collections: everything
    sc = load_scene(st)
    index = {m.path: i for i, m in enumerate(sc.meshes)}
    lights = {x.path: x for x in sc.lights}
    assert lights["/World/Sun"].lit_meshes.tolist() == [index["/World/Wall"]]
    assert lights["/World/Sun"].shadow_meshes.tolist() == [index["/World/Ground"]]
    assert lights["/World/Fill"].lit_meshes is None and lights["/World/Fill"].shadow_meshes is None


# ------------------------------------------------------------------ validate on no lightmaps


def test_validate_a_stage_without_lightmaps_fails(tmp_path, capsys):
    src = tmp_path / "src.usda"
    st = new_stage(meters_per_unit=1.0, path=src)
    _plane(st)
    _sun(st, intensity=1.0)
    st.GetRootLayer().Save()
    code, out = _run(["validate", str(src)], capsys)  # not --strict: still a failure
    assert code == 1
    assert "no prim of" in out.out and "AhdLightmapAPI" in out.out
    code, out = _run(["validate", str(src), "--json"], capsys)
    report = json.loads(out.out)
    assert report["exit_code"] == 1
    assert [f["code"] for f in report["findings"]] == ["NoAhdLightmapAPI"]


# ----------------------------------------------------------------------- bad material inputs


def test_bad_metallic_values(tmp_path):
    from usdahd.errors import StageError

    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat, _ = _material(st, "/World/Odd", metallic=(Sdf.ValueTypeNames.Float, 1.5))
    _bind(m.GetPrim(), mat)
    sc = load_scene(st)
    assert any("/World/Odd: metallic 1.5 outside [0, 1]; clamped" in w for w in sc.warnings)
    np.testing.assert_allclose(sc.materials[sc.meshes[0].material[0]].albedo, 0.0)
    st2 = new_stage(meters_per_unit=1.0)
    m2 = _plane(st2)
    nan, _ = _material(st2, "/World/Nan", metallic=(Sdf.ValueTypeNames.Float, float("nan")))
    _bind(m2.GetPrim(), nan)
    with pytest.raises(StageError, match="/World/Nan: UsdPreviewSurface inputs:metallic is nan"):
        load_scene(st2)


def test_bad_transform2d(tmp_path):
    from usdahd.errors import StageError

    png = tmp_path / "c.png"
    _write_png(png, np.full((2, 2, 3), 128, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    m = _plane(st)
    mat = _textured_material(st, "/World/T", png, transform=((float("nan"), 1), 0.0, (0, 0)))
    _bind(m.GetPrim(), mat)
    with pytest.raises(StageError, match="/World/T/Transform: UsdTransform2d inputs are NaN"):
        load_scene(st)
    st2 = new_stage(meters_per_unit=1.0)
    m2 = _plane(st2)
    mat2 = _textured_material(st2, "/World/T", png, transform=((2, 2), 0.0, (0, 0)))
    UsdShade.Shader(st2.GetPrimAtPath("/World/T/Transform")).GetInput("in").ClearSources()
    _bind(m2.GetPrim(), mat2)
    sc = load_scene(st2)
    assert any("(UsdTransform2d) has no connected 'in'" in w for w in sc.warnings)


def test_unknown_source_colour_space_token_warns(tmp_path):
    png = tmp_path / "x.png"
    _write_png(png, np.full((2, 2, 3), 128, np.uint8))
    warnings = []
    data = read_image(str(png), "bogus", warnings.append)
    assert any("unknown sourceColorSpace 'bogus'; treated as auto" in w for w in warnings)
    np.testing.assert_allclose(data[0, 0], [_srgb_decode(128 / 255)] * 3, atol=1e-4)


def test_moving_a_baked_project_keeps_it_fresh(tmp_path, capsys):
    """The material hash covers texels, not resolved paths: a moved project validates clean."""
    import shutil

    work = tmp_path / "a"
    work.mkdir()
    _write_png(work / "albedo.png", np.full((4, 4, 3), 180, np.uint8))
    st = new_stage(meters_per_unit=1.0, path=work / "s.usda")
    m = _plane(st)
    _bind(m.GetPrim(), _textured_material(st, "/World/Look", "./albedo.png"))
    _sun(st, intensity=3.0)
    st.GetRootLayer().Save()
    assert _run(["bake", str(work / "s.usda"), *FAST], capsys)[0] == 0
    moved = tmp_path / "b" / "deeper"
    shutil.copytree(work, moved)
    code, out = _run(["validate", str(moved / "s.lightmaps.usda"), "--strict"], capsys)
    assert code == 0, out.out
