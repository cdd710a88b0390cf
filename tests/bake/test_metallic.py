"""UsdPreviewSurface inputs:metallic connected to a UsdUVTexture (issue 13): the diffuse albedo
is diffuseColor x (1 - metallic), produced as the material's albedo texture
(usdahd.usd.materials.albedo_times_metal), in the scene read and in both integrator backends.

The bake case: a receiver facing +Z under a reflector facing down, lit only by a sun shining
upwards, so the receiver's I_z is the one-bounce light of the reflector alone. A fully
metallic reflector bounces nothing (I_z = 0 exactly); one whose left half is metallic (the
texture's m(u) + m(1 - u) = 1, clamp wrap) bounces half of a non-metallic one, averaged over
receiver texels placed symmetrically about the split (mirror symmetry of the stage).
"""

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from tests.scenes import new_stage
from usdahd.bake.integrate import bake_texels
from usdahd.bake.trace import Tracer
from usdahd.bake.types import Texels
from usdahd.numerics import sh
from usdahd.usd.reader import load_scene

F = Sdf.ValueTypeNames


def _png(path, pixels, fmt="uint8"):
    pixels = np.ascontiguousarray(pixels)
    h, w = pixels.shape[:2]
    c = 1 if pixels.ndim == 2 else pixels.shape[2]
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.attribute("oiio:UnassociatedAlpha", 1)  # store the pixels as given (straight alpha)
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(pixels.reshape(h, w, c))
    out.close()
    return path


def _half_metal(tmp_path, name="metal.png", w=4, h=4):
    """A 1-channel 8-bit texture: left half (u < 0.5) 0, right half 1 (linear: Hydra's auto
    rule decodes 1-channel 8-bit images without the sRGB curve)."""
    px = np.zeros((h, w), np.uint8)
    px[:, w // 2 :] = 255
    return _png(tmp_path / name, px)


def _quad(st, path, z=0.0, half=0.5, down=False, uv_name="st"):
    """A square quad at height z facing +Z (down: facing -Z), st = ((x, y) + half) / 2 half."""
    h = half
    xy = [(-h, -h), (h, -h), (h, h), (-h, h)]
    if down:
        xy = xy[::-1]
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr([Gf.Vec3f(x, y, z) for x, y in xy])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(uv_name, F.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set([Gf.Vec2f((x + h) / (2 * h), (y + h) / (2 * h)) for x, y in xy])
    return m


def _texture(st, path, file, out="r", varname="st", wrap="clamp", **inputs):
    tex = UsdShade.Shader.Define(st, path)
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", F.Asset).Set(str(file))
    tex.CreateInput("wrapS", F.Token).Set(wrap)
    tex.CreateInput("wrapT", F.Token).Set(wrap)
    for name, (tname, value) in inputs.items():
        tex.CreateInput(name, tname).Set(value)
    rd = UsdShade.Shader.Define(st, f"{path}Reader")
    rd.CreateIdAttr("UsdPrimvarReader_float2")
    rd.CreateInput("varname", F.String).Set(varname)
    rd.CreateOutput("result", F.Float2)
    tex.CreateInput("st", F.Float2).ConnectToSource(rd.ConnectableAPI(), "result")
    tex.CreateOutput(out, F.Float3 if out == "rgb" else F.Float)
    return tex


def _material(st, path, color=(0.5, 0.5, 0.5), metal=None, metal_out="r", diffuse=None):
    """A UsdPreviewSurface; metal / diffuse : UsdUVTexture shaders for metallic / diffuseColor."""
    mat = UsdShade.Material.Define(st, path)
    sh_ = UsdShade.Shader.Define(st, f"{path}/Surface")
    sh_.CreateIdAttr("UsdPreviewSurface")
    dc = sh_.CreateInput("diffuseColor", F.Color3f)
    if diffuse is None:
        dc.Set(Gf.Vec3f(*color))
    else:
        dc.ConnectToSource(diffuse.ConnectableAPI(), "rgb")
    if metal is not None:
        sh_.CreateInput("metallic", F.Float).ConnectToSource(metal.ConnectableAPI(), metal_out)
    mat.CreateSurfaceOutput().ConnectToSource(sh_.ConnectableAPI(), "surface")
    return mat


def _bind(prim, mat):
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def _albedo_at(sc, mesh_path, uv):
    mesh = next(m for m in sc.meshes if m.path == mesh_path)
    mat = sc.materials[mesh.material[0]]
    if mat.albedo_tex is None:
        return np.tile(mat.albedo, (len(uv), 1))
    return mat.albedo_tex.sample(np.asarray(uv, np.float32))


# ------------------------------------------------------------------------------ scene read


def test_constant_diffuse_times_a_metallic_texture(tmp_path):
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path))
    _bind(q.GetPrim(), _material(st, "/World/M", (0.8, 0.4, 0.2), metal=metal))
    sc = load_scene(st)
    assert not any("metallic" in w for w in sc.warnings), sc.warnings
    got = _albedo_at(sc, "/World/Plane", [[0.1, 0.5], [0.9, 0.5], [0.5, 0.5]])
    np.testing.assert_allclose(got[0], (0.8, 0.4, 0.2), rtol=1e-6)
    np.testing.assert_allclose(got[1], 0.0, atol=1e-7)
    # bilinear filtering commutes with c x (1 - m): halfway between the halves, half the albedo
    np.testing.assert_allclose(got[2], (0.4, 0.2, 0.1), rtol=1e-6)
    mat = sc.materials[sc.meshes[0].material[0]]
    assert mat.texcoord == "st" and "st" in sc.texcoords[0]


def test_diffuse_texture_times_metallic_texture_on_a_common_grid(tmp_path):
    """Exact at the common grid's texel centres: a 2 x 2 diffuse texture (linear 16-bit) and a
    4 x 4 metallic texture give a 4 x 4 product; the diffuse one is resampled bilinearly."""
    diffuse = np.array([[[0.2, 0.2, 0.2], [1.0, 1.0, 1.0]]] * 2, np.float32)
    dpng = _png(tmp_path / "d.png", (diffuse * 65535).round().astype(np.uint16), "uint16")
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path))
    dtex = _texture(st, "/World/M/Diffuse", dpng, out="rgb")
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal, diffuse=dtex))
    sc = load_scene(st)
    assert not any("metallic" in w for w in sc.warnings), sc.warnings
    tex = sc.materials[sc.meshes[0].material[0]].albedo_tex
    assert tex.data.shape == (4, 4, 3)
    # column centres u = 1/8, 3/8, 5/8, 7/8: diffuse (clamp) 0.2, 0.4, 0.8, 1.0 x (1, 1, 0, 0)
    np.testing.assert_allclose(tex.data[0, :, 0], [0.2, 0.4, 0.0, 0.0], atol=1e-4)
    np.testing.assert_allclose(tex.data[:, 1, 1], 0.4, atol=1e-4)
    # same resolution: the product of the texels themselves
    st2 = new_stage(meters_per_unit=1.0)
    q2 = _quad(st2, "/World/Plane")
    d4 = np.linspace(0.1, 0.9, 16, dtype=np.float32).reshape(4, 4)
    d4png = _png(tmp_path / "d4.png", (np.repeat(d4[..., None], 3, 2) * 65535).round()
                 .astype(np.uint16), "uint16")  # fmt: skip
    metal2 = _texture(st2, "/World/M/Metal", _half_metal(tmp_path))
    dtex2 = _texture(st2, "/World/M/Diffuse", d4png, out="rgb")
    _bind(q2.GetPrim(), _material(st2, "/World/M", metal=metal2, diffuse=dtex2))
    tex2 = load_scene(st2).materials[0].albedo_tex
    want = d4 * np.array([1, 1, 0, 0], np.float32)[None, :]
    np.testing.assert_allclose(tex2.data[..., 2], want, atol=1e-4)


def test_metallic_texture_fallback_and_specular_workflow(tmp_path):
    st = new_stage(meters_per_unit=1.0)
    a = _quad(st, "/World/A")
    b = _quad(st, "/World/B", z=1)
    missing = _texture(st, "/World/MA/Metal", tmp_path / "nope.png")
    missing.CreateInput("fallback", F.Float4).Set(Gf.Vec4f(0.75, 0, 0, 1))
    _bind(a.GetPrim(), _material(st, "/World/MA", metal=missing))
    metal = _texture(st, "/World/MB/Metal", _half_metal(tmp_path))
    mb = _material(st, "/World/MB", metal=metal)
    UsdShade.Shader.Get(st, "/World/MB/Surface").CreateInput("useSpecularWorkflow", F.Int).Set(1)
    _bind(b.GetPrim(), mb)
    sc = load_scene(st)
    np.testing.assert_allclose(_albedo_at(sc, "/World/A", [[0.5, 0.5]]), 0.5 * 0.25, rtol=1e-6)
    assert any("cannot read texture" in w and "nope.png" in w for w in sc.warnings)
    np.testing.assert_allclose(_albedo_at(sc, "/World/B", [[0.9, 0.5]]), 0.5)


# ------------------------------------------------------------------------------ bad inputs


def test_metallic_and_diffuse_textures_on_different_primvars_warn(tmp_path):
    dpng = _png(tmp_path / "d.png", np.full((2, 2, 3), 128, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    UsdGeom.PrimvarsAPI(q).CreatePrimvar("st1", F.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)]
    )
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path), varname="st1")
    dtex = _texture(st, "/World/M/Diffuse", dpng, out="rgb")
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal, diffuse=dtex))
    sc = load_scene(st)
    msg = [w for w in sc.warnings if "cannot combine" in w]
    assert len(msg) == 1 and msg[0].startswith("/World/M: the metallic texture"), sc.warnings
    assert "reads texcoord 'st1'" in msg[0] and "diffuseColor texture reads 'st'" in msg[0]
    assert "Fix: read both textures through the same primvar" in msg[0]
    mat = sc.materials[0]
    assert mat.albedo_tex.data.shape == (2, 2, 3)  # the diffuse texture, unchanged
    np.testing.assert_allclose(mat.albedo_tex.scale, 1.0)


def test_metallic_connected_to_rgb_reads_the_first_channel(tmp_path):
    rgb = np.zeros((4, 4, 3), np.uint8)
    rgb[:, 2:, 0] = 255  # r: right half metal; g, b: 0
    png = _png(tmp_path / "rgb.png", rgb)
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", png, out="rgb")
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal, metal_out="rgb"))
    sc = load_scene(st)
    assert any(
        "/World/M: inputs:metallic (a float) is connected to /World/M/Metal.outputs:rgb, 3 "
        "channels; the bake reads its first channel (r). Fix: connect outputs:r" in w
        for w in sc.warnings
    ), sc.warnings
    got = _albedo_at(sc, "/World/Plane", [[0.1, 0.5], [0.9, 0.5]])
    np.testing.assert_allclose(got, [[0.5] * 3, [0.0] * 3], atol=1e-6)


def test_metallic_channel_missing_from_the_file_warns(tmp_path):
    png = _png(tmp_path / "rgb.png", np.zeros((2, 2, 3), np.uint8))
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", png, out="a")
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal, metal_out="a"))
    sc = load_scene(st)
    assert any(
        "/World/M: inputs:metallic reads channel 'a' of" in w
        and "rgb.png, which has 3 channels: the missing channel reads 1" in w
        and "Fix: connect an output the file has" in w
        for w in sc.warnings
    ), sc.warnings
    np.testing.assert_allclose(_albedo_at(sc, "/World/Plane", [[0.5, 0.5]]), 0.0)


def test_metallic_texture_out_of_range_is_clamped_with_a_warning(tmp_path):
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    scale = (F.Float4, Gf.Vec4f(2, 2, 2, 1))  # right half 2, left half 0 - 0.25 = -0.25
    bias = (F.Float4, Gf.Vec4f(-0.25, -0.25, -0.25, 0))
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path), scale=scale, bias=bias)
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal))
    sc = load_scene(st)
    assert any(
        "/World/M: 16 texels of the metallic texture" in w
        and "are outside [0, 1] after scale and bias (-0.25 .. 1.75); clamped" in w
        for w in sc.warnings
    ), sc.warnings
    got = _albedo_at(sc, "/World/Plane", [[0.1, 0.5], [0.9, 0.5]])
    np.testing.assert_allclose(got, [[0.5] * 3, [0.0] * 3], atol=1e-6)


def test_different_wrap_modes_warn(tmp_path):
    dpng = _png(tmp_path / "d.png", np.full((2, 2, 3), 128, np.uint8))
    st = new_stage(meters_per_unit=1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path), wrap="repeat")
    dtex = _texture(st, "/World/M/Diffuse", dpng, out="rgb", wrap="clamp")
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal, diffuse=dtex))
    sc = load_scene(st)
    assert any(
        "/World/M: the metallic texture" in w
        and "wraps ('repeat', 'repeat') but the diffuseColor texture" in w
        and "Fix: author the same wrapS/wrapT on both" in w
        for w in sc.warnings
    ), sc.warnings
    assert sc.materials[0].albedo_tex.wrap == ("clamp", "clamp")


# ------------------------------------------------------------------------------ bake


def _reflector_stage(tmp_path, metal):
    """Receiver /Ground (black) at z = 0 facing +Z; reflector /Ceiling (diffuseColor 0.8,
    metallic ``metal``: None, "half" or "full") at z = 1 facing -Z; a sun shining upwards."""
    st = new_stage(meters_per_unit=1.0)
    black = _material(st, "/Mat/Black", (0, 0, 0))
    _bind(_quad(st, "/Ground").GetPrim(), black)
    ceil = _quad(st, "/Ceiling", z=1.0, half=3.0, down=True)
    tex = None
    if metal is not None:
        px = np.full((4, 4), 255, np.uint8)
        if metal == "half":
            px[:, 2:] = 0  # x < 0 metal, x > 0 diffuse (mirror symmetric sum)
        tex = _texture(st, "/Mat/Ceil/Metal", _png(tmp_path / f"{metal}.png", px))
    _bind(ceil.GetPrim(), _material(st, "/Mat/Ceil", (0.8, 0.8, 0.8), metal=tex))
    sun = UsdLux.DistantLight.Define(st, "/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateAngleAttr(0.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(180.0)  # light travels +Z
    return st


def _texels(n=8):
    p = np.zeros((n, 3), np.float32)
    p[:, 0] = np.linspace(-0.35, 0.35, n)
    return Texels(
        (n, 1),
        np.zeros((n, 2), np.int32),
        p,
        np.tile([0, 0, 1.0], (n, 1)).astype(np.float32),
        np.tile(np.eye(3), (n, 1, 1)).astype(np.float32),
        np.zeros(n, np.int32),
        np.ones(n, bool),
    )


def _mean_iz(st, backend):
    scene = load_scene(st)
    index = {m.path: i for i, m in enumerate(scene.meshes)}
    tr = Tracer(scene, backend=backend)
    try:
        out, _ = bake_texels(
            scene, tr, _texels(), samples=512, bounces=1, mesh=index["/Ground"], seed=3
        )
    finally:
        tr.close()
    return float(sh.iz(out)[:, 0].mean())


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_a_metallic_half_bounces_no_light(tmp_path, backend):
    diffuse = _mean_iz(_reflector_stage(tmp_path, None), backend)
    assert diffuse > 0.05  # the ceiling's bounce (direct light: none, the sun is below)
    assert _mean_iz(_reflector_stage(tmp_path, "full"), backend) == 0.0
    half = _mean_iz(_reflector_stage(tmp_path, "half"), backend)
    np.testing.assert_allclose(half, 0.5 * diffuse, rtol=0.06)


def test_changing_the_metallic_texture_makes_the_bake_stale(tmp_path, capsys):
    import json

    from usdahd import cli

    src = tmp_path / "scene.usda"
    st = Usd.Stage.CreateNew(str(src))
    UsdGeom.SetStageUpAxis(st, "Z")
    UsdGeom.SetStageMetersPerUnit(st, 1.0)
    q = _quad(st, "/World/Plane")
    metal = _texture(st, "/World/M/Metal", _half_metal(tmp_path))
    _bind(q.GetPrim(), _material(st, "/World/M", metal=metal))
    UsdLux.DistantLight.Define(st, "/World/Sun").CreateIntensityAttr(1.0)
    st.GetRootLayer().Save()
    fast = ["--resolution", "8", "--samples", "16", "--bounces", "0", "--quiet"]
    assert cli.main(["bake", str(src), *fast]) == 0
    layer = str(tmp_path / "scene.lightmaps.usda")
    assert cli.main(["validate", layer]) == 0
    capsys.readouterr()
    _png(tmp_path / "metal.png", np.zeros((4, 4), np.uint8))  # no longer metallic anywhere
    # the in-process scene cache is keyed on the stage's layers, not on texture files (a new
    # `usdahd validate` process reads the texture afresh)
    from usdahd.validate import staleness

    staleness._SCENES.clear()
    assert cli.main(["validate", layer, "--json"]) == 1
    findings = json.loads(capsys.readouterr().out)["findings"]
    assert any(f["code"] == "Stale" and "materials" in f["message"] for f in findings), findings
