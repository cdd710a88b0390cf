"""Material textures are kept at MAX_MATERIAL_TEXTURE texels a side (issue 37: a chess set's
2048^2 textures made its bake 87 s -> 190 s and 1.09 -> 2.47 GB). The bounce light the bake
computes from them must not change beyond the Monte Carlo noise."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

from usdahd.usd import materials, textures
from usdahd.usd.reader import load_scene


def test_box_downsample_means_and_shapes():
    rng = np.random.default_rng(1)
    big = rng.random((2048, 1024, 3), dtype=np.float32)
    small = textures.box_downsample(big, 512)
    assert small.shape == (512, 256, 3)
    np.testing.assert_allclose(small[3, 7], big[12:16, 28:32].reshape(-1, 3).mean(0), rtol=1e-6)
    assert small.mean() == pytest.approx(big.mean(), rel=1e-6)
    odd = rng.random((1025, 600, 2), dtype=np.float32)
    o = textures.box_downsample(odd, 512)  # factor 3, last row/column padded by repetition
    assert o.shape == (342, 200, 2)
    last = np.repeat(odd[1023:1025, 0:3], [1, 2], axis=0)  # rows 1023, 1024, 1024 (padding)
    np.testing.assert_allclose(o[-1, 0], last.reshape(-1, 2).mean(0), rtol=1e-6)
    keep = rng.random((512, 300, 4), dtype=np.float32)
    assert textures.box_downsample(keep, 512) is keep


def _write_png(path, data):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(np.ascontiguousarray(data))
    assert buf.write(str(path), oiio.UINT8), buf.geterror()


def _stage(tmp_path, size=2048):
    """A textured floor lit straight down by a sun; a wall standing on it sees the floor's
    bounce only (the sun grazes it at 90 degrees)."""
    rng = np.random.default_rng(7)
    cells = rng.random((32, 32, 3)).repeat(size // 32, 0).repeat(size // 32, 1)
    noise = rng.random((size, size, 3))  # texel-level detail the downsample averages away
    _write_png(tmp_path / "floor.png", (0.6 * cells + 0.4 * noise).astype(np.float32))
    st = Usd.Stage.CreateNew(str(tmp_path / "room.usda"))
    UsdGeom.SetStageUpAxis(st, "Z")
    UsdGeom.SetStageMetersPerUnit(st, 1.0)

    def quad(path, pts):
        m = UsdGeom.Mesh.Define(st, path)
        m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
        m.CreateFaceVertexCountsAttr([4])
        m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        m.CreateSubdivisionSchemeAttr("none")
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        pv.Set([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)])
        return m

    floor = quad("/World/Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)])
    quad("/World/Wall", [(-1, 0, 0.01), (1, 0, 0.01), (1, 0, 2), (-1, 0, 2)])
    mat = UsdShade.Material.Define(st, "/World/Looks/Floor")
    sh = UsdShade.Shader.Define(st, "/World/Looks/Floor/PBR")
    sh.CreateIdAttr("UsdPreviewSurface")
    tex = UsdShade.Shader.Define(st, "/World/Looks/Floor/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./floor.png")
    rd = UsdShade.Shader.Define(st, "/World/Looks/Floor/St")
    rd.CreateIdAttr("UsdPrimvarReader_float2")
    rd.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(rd.ConnectableAPI(), "result")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.ConnectableAPI(), "rgb"
    )
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(floor.GetPrim()).Bind(mat)
    sun = UsdLux.DistantLight.Define(st, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateNormalizeAttr(True)
    st.GetRootLayer().Save()
    return tmp_path / "room.usda"


def _bounce(path, seed):
    from usdahd.bake.integrate import bake_texels
    from usdahd.bake.texels import rasterize
    from usdahd.bake.trace import Tracer
    from usdahd.numerics import sh

    sc = load_scene(path)
    k = [m.path for m in sc.meshes].index("/World/Wall")
    tex = rasterize(sc.meshes[k], (16, 16))
    tr = Tracer(sc)
    out, _ = bake_texels(sc, tr, tex, samples=128, bounces=1, seed=seed, mesh=k)
    return sc, sh.iz(out).astype(np.float64)


def test_downsampled_floor_bounces_within_mc_noise(tmp_path, monkeypatch):
    path = _stage(tmp_path)
    small_sc, small = _bounce(path, 5)
    assert any(
        m.albedo_tex is not None and m.albedo_tex.data.shape[:2] == (512, 512)
        for m in small_sc.materials
    )
    monkeypatch.setattr(materials, "MAX_MATERIAL_TEXTURE", 4096)
    full_sc, full = _bounce(path, 5)
    assert any(
        m.albedo_tex is not None and m.albedo_tex.data.shape[:2] == (2048, 2048)
        for m in full_sc.materials
    )
    _, full2 = _bounce(path, 6)
    assert full.mean() > 0.05  # the wall is lit by the bounce
    noise = np.sqrt(np.mean((full - full2) ** 2))  # two independent estimates at full size
    effect = np.sqrt(np.mean((small - full) ** 2))  # same samples, downsampled texture
    print(f"bounce Iz: MC noise (rms of 2 seeds) {noise:.4g}, downsampling {effect:.4g}")
    # measured 0.0035 vs 0.0118: per texel the texture's own texel noise (40 % of this albedo
    # is white noise per texel, the worst case) moves the estimate by 0.42 sigma, less than
    # another seed does (sigma = noise / sqrt 2)
    assert effect < 0.5 * noise
    # the mean bounce: within 3 standard errors of one estimate (noise / sqrt 2 per texel)
    se = noise / np.sqrt(2) / np.sqrt(full.size)
    assert abs(small.mean() - full.mean()) < 3 * se


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
@pytest.mark.parametrize("dst", ["lin_rec709_scene", "lin_ap1_scene"])
def test_8bit_colour_table_equals_openimageio(channels, dst):
    """The 256-code table gives OpenImageIO's own conversion texel for texel (alpha and the
    alpha of grey+alpha untouched); a conversion that mixes channels (to ACEScg's gamut) is
    not tabulated and falls back to OpenImageIO per pixel."""
    from usdahd import images

    rng = np.random.default_rng(channels)
    d = (rng.integers(0, 256, (64, 48, channels)) / 255.0).astype(np.float32)
    want = images.convert_color(d, "srgb_rec709_scene", dst)
    got = images.convert_color_8bit(d, "srgb_rec709_scene", dst)
    np.testing.assert_array_equal(got, want)
    assert (images._lut8("srgb_rec709_scene", dst) is None) == (dst == "lin_ap1_scene")
