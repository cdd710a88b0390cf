"""Materials as production USD writes them (issue 37): MaterialX surfaces inline and from
``.mtlx`` files, displayColor through a primvar reader and on unbound meshes, unreadable
albedo textures. The stages are tests/data/production/{mtlx,displaycolor,badtexture}_*.

Expected values are computed here from the specs, independently of the reader: the sRGB
transfer function (IEC 61966-2-1), the MaterialX standard_surface / open_pbr_surface input
definitions as the MaterialX standard library declares them (parsed with ElementTree, not
with the MaterialX API the reader uses), and for the bake a closed-form view factor.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from usdahd import cli
from usdahd.usd.checks import check_stage
from usdahd.usd.reader import load_scene

DATA = Path(__file__).resolve().parents[1] / "data" / "production"
ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT.parent / "assets" / "usd-wg-assets" / "full_assets"


def _srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


#: mtlx_albedo.png: every texel (200, 100, 50), 8-bit sRGB
ALBEDO_PNG = _srgb_to_linear(np.array([200, 100, 50]) / 255.0)


def _scene(name):
    sc = load_scene(Usd.Stage.Open(str(DATA / name)))
    return sc, {m.name: m for m in sc.materials}


def _albedo(m):
    """The material's albedo: its constant, or its texture's (uniform) output."""
    if m.albedo_tex is None:
        return np.asarray(m.albedo, np.float64)
    v = m.albedo_tex.outputs().reshape(-1, len(m.albedo_tex.channels)).astype(np.float64)
    assert np.ptp(v, axis=0).max() < 1e-6  # the test textures are uniform
    return v[0]


def _stdlib_default(nodedef, name):
    """An input default read from the MaterialX standard library's XML itself."""
    import MaterialX

    lib = Path(MaterialX.__file__).parent / "libraries" / "bxdf"
    for f in lib.glob("*.mtlx"):
        for nd in ET.parse(f).getroot().iter("nodedef"):
            if nd.get("name") == nodedef:
                for inp in nd.iter("input"):
                    if inp.get("name") == name:
                        return [float(x) for x in inp.get("value").split(",")]
    raise KeyError((nodedef, name))


# --------------------------------------------------------------------- MaterialX inline


def test_mtlx_inline_standard_surface_open_pbr_and_usdpreviewsurface():
    sc, mats = _scene("mtlx_inline.usda")
    std = mats["/World/Looks/StdSurf"]
    # base_color (an sRGB image node through a NodeGraph) x base 0.5 x (1 - metalness 0.2);
    # the universal UsdPreviewSurface (0.18) is not what a MaterialX renderer shows
    np.testing.assert_allclose(_albedo(std), ALBEDO_PNG * 0.5 * 0.8, rtol=2e-3)
    np.testing.assert_allclose(std.emission, 0.5 * np.array([0.2, 0.4, 0.6]), rtol=1e-6)
    assert std.texcoord == "st"
    opbr = mats["/World/Looks/OpenPbr"]
    # base_metalness unauthored: the library default (0), read from the XML here
    assert _stdlib_default("ND_open_pbr_surface_surfaceshader", "base_metalness") == [0.0]
    np.testing.assert_allclose(opbr.albedo, 0.75 * np.array([0.2, 0.4, 0.8]), rtol=1e-6)
    # emission_luminance (nits, UsdLux's radiance unit) x emission_color
    np.testing.assert_allclose(opbr.emission, 2.0 * np.array([1, 0.5, 0.25]), rtol=1e-6)
    px = mats["/World/Looks/PreviewX"]
    # ND_UsdPreviewSurface: diffuseColor (a tiledimage, 8-bit PNG without colour space: Hydra's
    # rule, sRGB) x (1 - metallic 0.5); uvtiling (2, 2) becomes a texcoord transform
    np.testing.assert_allclose(_albedo(px), ALBEDO_PNG * 0.5, rtol=2e-3)
    assert px.texcoord.startswith("st@scale(2,2)")
    assert not any("not UsdPreviewSurface" in w or "fallback" in w for w in sc.warnings)


def test_mtlx_inline_defaults_are_the_materialx_library_defaults(tmp_path):
    """An unauthored standard_surface: base_color 0.8 x base 1 (the library's values)."""
    src = (DATA / "mtlx_inline.usda").read_text()
    src = src.replace("float inputs:base = 0.5\n", "").replace(
        "color3f inputs:base_color.connect = </World/Looks/StdSurf/Graph.outputs:base_color>\n",
        "",
    )
    src = src.replace("float inputs:metalness = 0.2\n", "")
    (tmp_path / "s.usda").write_text(src)
    shutil.copy(DATA / "mtlx_albedo.png", tmp_path)
    sc = load_scene(Usd.Stage.Open(str(tmp_path / "s.usda")))
    std = {m.name: m for m in sc.materials}["/World/Looks/StdSurf"]
    want = np.array(_stdlib_default("ND_standard_surface_surfaceshader", "base_color"))
    want = want * _stdlib_default("ND_standard_surface_surfaceshader", "base")[0]
    np.testing.assert_allclose(std.albedo, want, rtol=1e-6)
    assert std.albedo_tex is None


# ------------------------------------------------------------------- MaterialX from a file


def test_mtlx_file_materials_are_read_with_the_materialx_library():
    sc, mats = _scene("mtlx_file.usda")
    np.testing.assert_allclose(
        mats["/World/Materials/M_Red"].albedo, 0.9 * np.array([0.8, 0.1, 0.1]), rtol=1e-6
    )
    tex = mats["/World/Materials/M_Textured"]
    # open_pbr_surface: base_color (sRGB image in a nodegraph) x (1 - base_metalness 0.25)
    np.testing.assert_allclose(_albedo(tex), ALBEDO_PNG * 0.75, rtol=2e-3)
    np.testing.assert_allclose(tex.emission, 3.0 * np.array([0.5, 0.5, 1.0]), rtol=1e-6)
    # a Material prim that references the document's material itself
    np.testing.assert_allclose(
        mats["/World/DirectLook"].albedo, 0.9 * np.array([0.8, 0.1, 0.1]), rtol=1e-6
    )
    said = [w for w in sc.warnings if "mtlx_look.mtlx" in w and "MaterialX" in w]
    assert len(said) == 1, sc.warnings
    assert "MaterialX file could not be composed by USD" in said[0]
    assert "usdMtlx" in said[0] and "reads the materials" in said[0]
    assert not any("fix the binding" in w for w in sc.warnings)
    found = check_stage(Usd.Stage.Open(str(DATA / "mtlx_file.usda")))
    assert not any("material:binding" in w for w in found.warnings), found.warnings


def test_mtlx_file_that_cannot_be_read_says_so_not_fix_the_binding():
    sc, mats = _scene("mtlx_broken.usda")
    np.testing.assert_allclose(mats["/World/Gone/M_Gone"].albedo, 0.18)
    np.testing.assert_allclose(mats["/World/Looks/M_Nope"].albedo, 0.18)
    gone = [w for w in sc.warnings if w.startswith("/World/A:")]
    nope = [w for w in sc.warnings if w.startswith("/World/B:")]
    assert len(gone) == 1 and len(nope) == 1, sc.warnings
    assert "MaterialX file could not be composed" in gone[0]
    assert "mtlx_missing.mtlx does not exist" in gone[0]
    assert "grey 0.18" in gone[0] and "Fix:" in gone[0]
    assert "no surfacematerial named 'M_Nope'" in nope[0] and "M_Red" in nope[0]
    assert not any("fix the binding" in w for w in sc.warnings)
    found = check_stage(Usd.Stage.Open(str(DATA / "mtlx_broken.usda")))
    bad = [w for w in found.warnings if "MaterialX file could not be composed" in w]
    assert len(bad) == 2, found.warnings  # once per file
    assert not any("fix the binding" in w for w in found.warnings)


# ------------------------------------------------------------------------ displayColor


def test_display_color_through_a_primvar_reader_is_per_prim():
    sc, _ = _scene("displaycolor_reader.usda")
    by_prim = {m.path: sc.materials[int(m.material[0])] for m in sc.meshes}
    np.testing.assert_allclose(by_prim["/World/Lime"].albedo, [0.325, 0.825, 0], rtol=1e-6)
    np.testing.assert_allclose(by_prim["/World/Blue"].albedo, [0.014, 0.199, 0.912], rtol=1e-6)
    # no displayColor: the reader's fallback, as USD renders it, and said with the fix
    np.testing.assert_allclose(by_prim["/World/NoColor"].albedo, 0.0)
    w = [x for x in sc.warnings if x.startswith("/World/NoColor:")]
    assert len(w) == 1 and "fallback (0, 0, 0)" in w[0] and "author primvars:displayColor" in w[0]
    assert not any("using its fallback" in x for x in sc.warnings)


def test_display_color_of_unbound_meshes():
    sc, _ = _scene("displaycolor_unbound.usda")
    by_prim = {m.path: sc.materials[int(m.material[0])] for m in sc.meshes}
    np.testing.assert_allclose(by_prim["/World/Lime"].albedo, [0.325, 0.825, 0], rtol=1e-6)
    np.testing.assert_allclose(by_prim["/World/Varying"].albedo, [0.5, 0.5, 0.5], rtol=1e-6)
    w = [x for x in sc.warnings if x.startswith("/World/Varying:")]
    assert len(w) == 1 and "mean (0.5, 0.5, 0.5)" in w[0] and "Fix:" in w[0]


# ------------------------------------------------------------------ unreadable textures


def test_unreadable_albedo_textures_use_a_named_substitute():
    sc, mats = _scene("badtexture.usda")
    # missing file, no fallback authored: the prim's displayColor (what usdview shows)
    np.testing.assert_allclose(mats["/World/Looks/Missing"].albedo, [0.6, 0.5, 0.4], rtol=1e-6)
    # corrupt file under an authored constant: the constant
    np.testing.assert_allclose(mats["/World/Looks/Corrupt"].albedo, [0.7, 0.7, 0.2], rtol=1e-6)
    # MaterialX image node, no displayColor: standard_surface's default base_color (0.8)
    want = _stdlib_default("ND_standard_surface_surfaceshader", "base_color")
    np.testing.assert_allclose(mats["/World/Looks/MtlxMissing"].albedo, want, rtol=1e-6)
    for prim, value, what in (
        ("/World/Floor", "(0.6, 0.5, 0.4)", "the displayColor of /World/Floor"),
        ("/World/Wall", "(0.7, 0.7, 0.2)", "the constant authored on diffuseColor"),
        ("/World/Tile", "(0.8, 0.8, 0.8)", "the default base_color"),
    ):
        w = [x for x in sc.warnings if x.startswith(f"{prim}:")]
        assert len(w) == 1, (prim, sc.warnings)
        assert "cannot read texture" in w[0] and "badtexture_" in w[0]
        assert value in w[0] and what in w[0] and "Fix:" in w[0]
        assert "fallback used" not in w[0]
    assert not any(np.allclose(m.albedo, 0) for m in sc.materials)


def test_unreadable_texture_message_reaches_the_cli_json(tmp_path, capsys):
    stage = DATA / "badtexture.usda"
    out = tmp_path / "out.lightmaps.usda"
    argv = ["bake", str(stage), "-o", str(out), "--dry-run", "--json"]
    code = cli.main(argv)
    rep = json.loads(capsys.readouterr().out)
    assert code == 0
    text = json.dumps(rep)
    assert "the displayColor of /World/Floor" in text
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", *argv], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert "the constant authored on diffuseColor" in proc.stdout
    assert not out.exists()  # a dry run writes nothing


# ---------------------------------------------------------------------------- the bake


def _corner_view_factor(a, b, h):
    """Cosine-weighted view factor from a point to an a x b rectangle parallel to it at
    distance h, one corner below the point (the standard closed form)."""
    x, y = a / h, b / h
    sx, sy = math.sqrt(1 + x * x), math.sqrt(1 + y * y)
    return (x / sx * math.atan(y / sx) + y / sy * math.atan(x / sy)) / (2 * math.pi)


def _square_view_factor(px, py, half, h):
    """From (px, py) at height h to the square [-half, half]^2 (the point above it)."""
    return sum(
        _corner_view_factor(half - sx * px, half - sy * py, h) for sx in (1, -1) for sy in (1, -1)
    )


@pytest.mark.slow
def test_bounce_from_a_mtlx_floor_has_its_colour(tmp_path, capsys):
    """A black receiver facing a red floor (an .mtlx material) lit by a sun of illuminance
    pi: its irradiance is albedo x F (F: view factor of the lit floor), so I_z = rho x F."""
    from usdahd.numerics import sh as shmod
    from usdahd.usd import schema

    out = tmp_path / "bounce.lightmaps.usda"
    argv = ["bake", str(DATA / "mtlx_bounce.usda"), "-o", str(out), "--resolution", "8"]
    argv += ["--samples", "512", "--bounces", "2", "--no-denoise", "--quiet"]
    assert cli.main(argv) == 0, capsys.readouterr()
    stage = Usd.Stage.Open(str(out))

    def iz(prim):
        res = schema.read_results(stage.GetPrimAtPath(prim))
        side = schema.read_record_pixels(res, "sh", schema.SH_SIDECAR_CHANNELS)
        cover = side[..., -1] > 0
        return shmod.iz(side[cover][:, :27].reshape(-1, 3, 9).astype(np.float64)).mean(0)

    rho = 0.9 * np.array([0.8, 0.1, 0.1])
    # the floor (20 m, normal incidence, I_z = E / pi = 1); the receiver's shadow is 1e-4
    np.testing.assert_allclose(iz("/World/Floor"), 1.0, rtol=0.01)
    # receiver: 0.2 m square 1 m up; F averaged over its area (floor minus its shadow)
    g = (np.arange(8) + 0.5) / 8 * 0.2 - 0.1
    f = np.mean(
        [
            _square_view_factor(x, y, 10.0, 1.0) - _square_view_factor(x, y, 0.1, 1.0)
            for x in g
            for y in g
        ]
    )
    got = iz("/World/Receiver")
    np.testing.assert_allclose(got, rho * f, rtol=0.02)
    assert abs(got[0] / got[1] - 8.0) < 0.5  # red : green of the floor's base colour


# ----------------------------------------------------------------- production assets


@pytest.mark.slow
@pytest.mark.skipif(not (ASSETS / "OpenChessSet").is_dir(), reason="usd-wg/assets not fetched")
def test_open_chess_set_materials_are_not_grey():
    sc = load_scene(Usd.Stage.Open(str(ASSETS / "OpenChessSet" / "chess_set.usda")))
    textured = [m for m in sc.materials if m.albedo_tex is not None]
    assert len(textured) >= 13, [m.name for m in sc.materials]
    assert not any("fix the binding" in w for w in sc.warnings)
    mean = {m.name: m.albedo_tex.outputs().reshape(-1, 3).mean(0) for m in textured}
    pairs = [
        (v, mean[k.replace("White", "Black")[:-1] + "B"])
        for k, v in mean.items()
        if k.endswith("_W") and k.replace("White", "Black")[:-1] + "B" in mean
    ]
    assert len(pairs) >= 6, sorted(mean)
    assert all(w.mean() > 1.5 * b.mean() for w, b in pairs)  # each white piece is lighter
    # the King's albedo against the files decoded here: sRGB formula x (1 - metallic)
    import OpenImageIO as oiio

    tex = ASSETS / "OpenChessSet" / "assets" / "King" / "tex"
    metal = oiio.ImageBuf(str(tex / "king_shared_metallic.jpg")).get_pixels(oiio.FLOAT)
    for side in ("black", "white"):
        base = oiio.ImageBuf(str(tex / f"king_{side}_base_color.jpg")).get_pixels(oiio.FLOAT)
        want = (_srgb_to_linear(base[..., :3]) * (1 - metal[..., :1])).reshape(-1, 3).mean(0)
        got = mean[f"/ChessSet/{side.title()}/King/Materials/M_King_{side[0].upper()}"]
        np.testing.assert_allclose(got, want, rtol=0.01)


@pytest.mark.skipif(not (ASSETS / "Teapot").is_dir(), reason="usd-wg/assets not fetched")
def test_teapot_display_color_is_lime():
    sc = load_scene(Usd.Stage.Open(str(ASSETS / "Teapot" / "Teapot.usd")))
    albedo = [m.albedo for m in sc.materials]
    assert any(np.allclose(a, [0.325, 0.825, 0.0], atol=1e-6) for a in albedo), albedo


# ----------------------------------------------------------------- pattern nodes (unit)

_GRAPH_STAGE = """#usda 1.0
(
    defaultPrim = "World"
    upAxis = "Z"
)

def Xform "World"
{
    def Mesh "Plane" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
        texCoord2f[] primvars:st1 = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
        uniform token subdivisionScheme = "none"
        rel material:binding = </World/M>
    }

    def Material "M"
    {
        token outputs:mtlx:surface.connect = </World/M/S.outputs:out>

        def Shader "S"
        {
            uniform token info:id = "ND_standard_surface_surfaceshader"
            BODY
            token outputs:out
        }

        def Shader "Img"
        {
            uniform token info:id = "ND_image_color3"
            asset inputs:file = @./mtlx_albedo.png@ (
                colorSpace = "srgb_texture"
            )
            color3f outputs:out
        }
        NODES
    }
}
"""


def _graph_scene(tmp_path, body, nodes=""):
    shutil.copy(DATA / "mtlx_albedo.png", tmp_path)
    text = _GRAPH_STAGE.replace("BODY", body).replace("NODES", nodes)
    (tmp_path / "g.usda").write_text(text)
    sc = load_scene(Usd.Stage.Open(str(tmp_path / "g.usda")))
    return sc, sc.materials[int(sc.meshes[0].material[0])]


def test_affine_nodes_and_an_extracted_channel_as_metalness(tmp_path):
    body = """color3f inputs:base_color.connect = </World/M/Add.outputs:out>
            float inputs:metalness.connect = </World/M/Blue.outputs:out>"""
    nodes = """
        def Shader "Mul"
        {
            uniform token info:id = "ND_multiply_color3FA"
            color3f inputs:in1.connect = </World/M/Img.outputs:out>
            float inputs:in2 = 0.5
            color3f outputs:out
        }

        def Shader "Add"
        {
            uniform token info:id = "ND_add_color3"
            color3f inputs:in1.connect = </World/M/Mul.outputs:out>
            color3f inputs:in2 = (0.1, 0, 0)
            color3f outputs:out
        }

        def Shader "Blue"
        {
            uniform token info:id = "ND_extract_color3"
            color3f inputs:in.connect = </World/M/Img.outputs:out>
            int inputs:index = 2
            float outputs:out
        }
"""
    sc, m = _graph_scene(tmp_path, body, nodes)
    want = (ALBEDO_PNG * 0.5 + [0.1, 0, 0]) * (1 - ALBEDO_PNG[2])
    np.testing.assert_allclose(_albedo(m), want, rtol=3e-3)
    assert not any("does not evaluate" in w for w in sc.warnings)


def test_a_node_the_bake_cannot_evaluate_is_named_with_the_value_used(tmp_path):
    body = """color3f inputs:base_color.connect = </World/M/Noise.outputs:out>"""
    nodes = """
        def Shader "Noise"
        {
            uniform token info:id = "ND_noise2d_color3"
            color3f outputs:out
        }
"""
    sc, m = _graph_scene(tmp_path, body, nodes)
    np.testing.assert_allclose(m.albedo, [0.8, 0.8, 0.8], rtol=1e-6)
    w = [x for x in sc.warnings if "ND_noise2d_color3" in x]
    assert len(w) == 1 and "/World/M/Noise" in w[0] and "does not evaluate" in w[0]
    assert "(0.8, 0.8, 0.8)" in w[0] and "Fix:" in w[0]


def test_textures_on_different_texcoords_are_not_combined_silently(tmp_path):
    body = """color3f inputs:base_color.connect = </World/M/Img.outputs:out>
            float inputs:metalness.connect = </World/M/Metal.outputs:out>"""
    nodes = """
        def Shader "Metal"
        {
            uniform token info:id = "ND_image_float"
            asset inputs:file = @./mtlx_albedo.png@
            float2 inputs:texcoord.connect = </World/M/UV1.outputs:out>
            float outputs:out
        }

        def Shader "UV1"
        {
            uniform token info:id = "ND_geompropvalue_vector2"
            string inputs:geomprop = "st1"
            float2 outputs:out
        }
"""
    sc, m = _graph_scene(tmp_path, body, nodes)
    np.testing.assert_allclose(_albedo(m), ALBEDO_PNG, rtol=3e-3)  # metalness dropped
    w = [x for x in sc.warnings if "different texcoords" in x]
    assert len(w) == 1 and "'st1'" in w[0] and "Fix:" in w[0]


def test_composition_note_for_a_mtlx_reference():
    from usdahd.usd.materialx import composition_note

    stage = Usd.Stage.Open(str(DATA / "mtlx_file.usda"))
    errs = [str(e) for e in stage.GetCompositionErrors() if ".mtlx" in str(e)]
    assert errs, "usd-core composed the .mtlx reference: usdMtlx is present, update the docs"
    note = composition_note(errs[0])
    assert note.startswith("MaterialX file /") and "mtlx_look.mtlx could not be composed" in note
    assert "no usdMtlx" in note
    assert composition_note("Could not open asset @a.usda@ for reference") is None


def test_an_emission_texture_under_a_zero_weight_is_no_emitter(tmp_path):
    body = """color3f inputs:emission_color.connect = </World/M/Img.outputs:out>
            float inputs:emission = 0"""
    sc, m = _graph_scene(tmp_path, body)
    assert m.emission_tex is None and not m.emissive
    body = body.replace("float inputs:emission = 0", "float inputs:emission = 2")
    sc, m = _graph_scene(tmp_path, body)
    v = m.emission_tex.outputs().reshape(-1, 3)[0]
    np.testing.assert_allclose(v, 2 * ALBEDO_PNG, rtol=3e-3)


def test_an_untyped_prim_referencing_a_mtlx_material_is_read_and_not_blamed(tmp_path):
    text = (DATA / "mtlx_file.usda").read_text()
    text = text.replace('def Material "DirectLook" (', 'over "DirectLook" (')
    (tmp_path / "u.usda").write_text(text)
    for f in ("mtlx_look.mtlx", "mtlx_albedo.png"):
        shutil.copy(DATA / f, tmp_path)
    stage = Usd.Stage.Open(str(tmp_path / "u.usda"))
    sc = load_scene(stage)
    by_prim = {m.path: sc.materials[int(m.material[0])] for m in sc.meshes}
    np.testing.assert_allclose(by_prim["/World/Direct"].albedo, [0.72, 0.09, 0.09], rtol=1e-6)
    found = check_stage(stage)
    assert not any("material:binding" in w for w in found.warnings), found.warnings


@pytest.mark.parametrize(
    "ca, cha, cb, chb",
    [(3, (0, 1, 2), 1, (0,)), (1, (0,), 3, (0, 1, 2)), (3, (2,), 3, (0, 1, 2))]
    + [(4, (0, 1, 2), 1, (0, 0, 0)), (1, (0, 1, 2), 3, (1,)), (2, (3,), 3, (0, 1, 2))],
)
def test_texture_product_is_the_product_of_the_outputs(ca, cha, cb, chb):
    """Same grid: texel by texel, the product of the two UsdUVTexture-style outputs
    (Texture.outputs: channel padding, scale and bias), a one-channel value broadcast."""
    from usdahd.scene.types import Texture
    from usdahd.usd.materialx import texture_product

    rng = np.random.default_rng(7)

    def tex(c, ch):
        r = rng.random((6, 5, c), dtype=np.float32)
        return Texture("t", r, rng.random(4, dtype=np.float32), rng.random(4, dtype=np.float32), ch)

    a, b = tex(ca, cha), tex(cb, chb)
    oa, ob = a.outputs(), b.outputs()
    n = max(oa.shape[2], ob.shape[2])
    want = np.broadcast_to(oa, oa.shape[:2] + (n,)) * np.broadcast_to(ob, ob.shape[:2] + (n,))
    np.testing.assert_allclose(texture_product(a, b).outputs(), want, rtol=1e-6)


def test_materialx_documents_are_built_once_across_threads():
    """Validation runs its rules in parallel threads. The standard library and each ``.mtlx``
    document must be one object per process: a second copy built by a racing thread and then
    dropped by a cache orphans the node definitions taken from it (MaterialX raised "Requested
    root of orphaned element" inside Staleness on the usd-wg Standard Shader Ball)."""
    import threading

    from usdahd.usd import materialx as mtx

    mtx._LIBRARY.clear()
    path = str(DATA / "mtlx_look.mtlx")
    mtx._DOCUMENTS.pop(path, None)
    start = threading.Barrier(6)
    got = []

    def run():
        start.wait()
        got.append((mtx.library(), mtx.load_document(path)[0]))

    threads = [threading.Thread(target=run) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 6
    assert all(lib is got[0][0] for lib, _ in got)
    assert all(doc is got[0][1] and doc is not None for _, doc in got)
    # a node definition default read through the shared library stays valid
    np.testing.assert_allclose(
        mtx.nodedef_default("ND_open_pbr_surface_surfaceshader", "base_color"), [0.8] * 3, rtol=1e-6
    )
