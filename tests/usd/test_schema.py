"""AhdLightmapAPI: registration, prim definition against schema/schema.usda, generator drift,
helper round trips and bad values (issue 3)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import usdahd.usd  # noqa: F401  (registers the plugin before any stage exists)
from usdahd.errors import SchemaError
from usdahd.models import REGISTRY
from usdahd.models.base import ROLES
from usdahd.numerics import sh as sh_mod
from usdahd.usd import schema as S

from pxr import Gf, Sdf, Tf, Usd, UsdGeom  # isort: skip

REPO = Path(__file__).resolve().parents[2]
SCHEMA_SRC = REPO / "schema" / "schema.usda"
RESOURCES = REPO / "plugins" / "usdAhd" / "resources"


_LAYERS = []  # keep the source layer alive while its specs are in use


def _source_props():
    layer = Sdf.Layer.FindOrOpen(str(SCHEMA_SRC))
    _LAYERS.append(layer)
    cls = layer.GetPrimAtPath("/" + S.API_NAME)
    assert cls, f"{SCHEMA_SRC} has no class {S.API_NAME}"
    return {p.name: p for p in cls.properties}


def _definition():
    d = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(S.API_NAME)
    assert d is not None, "AhdLightmapAPI has no prim definition"
    return d


@pytest.fixture
def stage_with_mesh(tmp_path):
    """A saved source layer with a Mesh and an Xform, opened through an override layer."""
    src = Usd.Stage.CreateNew(str(tmp_path / "src.usda"))
    UsdGeom.Mesh.Define(src, "/World/Mesh")
    UsdGeom.Xform.Define(src, "/World/Xf")
    src.GetRootLayer().Save()
    over = Sdf.Layer.CreateNew(str(tmp_path / "over.usda"))
    over.subLayerPaths.append("./src.usda")
    over.Save()
    stage = Usd.Stage.Open(over)
    stage.SetEditTarget(stage.GetRootLayer())
    return stage


# ----------------------------------------------------------------------------- registration


def test_schema_registers_as_single_apply_api():
    info = Usd.SchemaRegistry.FindSchemaInfo(S.API_NAME)
    assert info is not None
    assert info.kind == Usd.SchemaKind.SingleApplyAPI
    assert info.type.typeName == S.SCHEMA_TYPE_NAME
    assert Tf.Type.FindByName(S.SCHEMA_TYPE_NAME) == info.type


def test_can_apply_on_mesh_not_on_xform(stage_with_mesh):
    mesh = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    xf = stage_with_mesh.GetPrimAtPath("/World/Xf")
    assert mesh.CanApplyAPI(S.API_NAME)
    assert not xf.CanApplyAPI(S.API_NAME)
    S.apply(mesh)
    assert S.has_api(mesh) and mesh.GetAppliedSchemas() == [S.API_NAME]
    with pytest.raises(SchemaError, match=r"</World/Xf>.*Mesh"):
        S.apply(xf)
    assert S.prims_with_api(stage_with_mesh) == [mesh]


def test_apply_keeps_source_layer_byte_identical(stage_with_mesh, tmp_path):
    before = (tmp_path / "src.usda").read_bytes()
    S.apply(stage_with_mesh.GetPrimAtPath("/World/Mesh"))
    stage_with_mesh.GetRootLayer().Save()
    assert (tmp_path / "src.usda").read_bytes() == before
    assert S.API_NAME in (tmp_path / "over.usda").read_text()


# ------------------------------------------------------------- definition against the source


def test_every_property_comes_back_from_the_prim_definition():
    src = _source_props()
    d = _definition()
    assert sorted(d.GetPropertyNames()) == sorted(src)
    for name, spec in src.items():
        prop = d.GetAttributeDefinition(name)
        assert prop, name
        assert name.startswith(S.NAMESPACE + ":"), name
        assert prop.GetTypeName() == spec.typeName, name
        assert prop.GetVariability() == spec.variability == Sdf.VariabilityUniform, name
        assert prop.GetFallbackValue() == spec.default, name
        assert list(prop.GetMetadata("allowedTokens") or []) == list(
            spec.GetInfo("allowedTokens") or []
        ), name
        doc = spec.GetInfo("documentation")
        assert prop.GetDocumentation() == doc, name  # the whole doc survives as userDocBrief
        # one sentence: ends with a period, no other sentence break.
        assert doc.endswith(".") and ". " not in doc[:-1] and "\n" not in doc, name


def test_tokens_have_allowed_tokens_and_match_the_registry():
    d = _definition()
    for name in d.GetPropertyNames():
        prop = d.GetAttributeDefinition(name)
        if prop.GetTypeName() == Sdf.ValueTypeNames.Token:
            allowed = list(prop.GetMetadata("allowedTokens") or [])
            assert allowed, f"{name} is a token without allowedTokens"
            assert prop.GetFallbackValue() in allowed, name
    for key in ("model", "baked:model"):
        allowed = d.GetAttributeDefinition(S.property_name(key)).GetMetadata("allowedTokens")
        assert tuple(allowed) == tuple(REGISTRY) == S.MODELS, key
    for key in ("ratio", "baked:ratio"):
        allowed = d.GetAttributeDefinition(S.property_name(key)).GetMetadata("allowedTokens")
        assert tuple(allowed) == S.RATIOS, key
    frames = d.GetAttributeDefinition(S.property_name("baked:tangentFrame"))
    assert tuple(frames.GetMetadata("allowedTokens")) == S.TANGENT_FRAMES


def test_asset_roles_match_model_roles_with_colorspace():
    d = _definition()
    assets = sorted(
        n for n in d.GetPropertyNames() if d.GetAttributeDefinition(n).GetTypeName() == "asset"
    )
    assert assets == sorted(S.file_property_name(r) for r in S.FILE_ROLES)
    texture_roles = [n.split(":")[-1] for n in assets if ":texture:" in n]
    assert sorted(texture_roles) == sorted(ROLES)
    for role in S.FILE_ROLES:
        prop = d.GetAttributeDefinition(S.file_property_name(role))
        assert prop.GetMetadata("colorSpace") == S.COLOR_SPACES[role], role
    hdr = {r for r, cs in S.COLOR_SPACES.items() if cs == "lin_rec709_scene"}
    assert hdr == {"iz", "ambient", "directional"}
    assert set(Gf.ColorSpaceNames.__dict__) >= {"LinearRec709", "Raw"}


def test_dataclass_defaults_and_factors_are_the_schema_fallbacks():
    d = _definition()
    defaults = S.BakeInputs()
    for fname, key in S.INPUT_KEYS.items():
        fallback = d.GetAttributeDefinition(S.property_name(key)).GetFallbackValue()
        assert getattr(defaults, fname) == pytest.approx(fallback), fname
    for name, value in S.FACTORS.items():
        fallback = d.GetAttributeDefinition(S.property_name(f"baked:{name}")).GetFallbackValue()
        assert fallback == value, name
    version = d.GetAttributeDefinition(S.property_name("baked:formatVersion"))
    assert version.GetFallbackValue() == 0 and S.FORMAT_VERSION in S.KNOWN_FORMAT_VERSIONS
    assert len(S.SH_SIDECAR_CHANNELS) == 28 and S.SH_SIDECAR_CHANNELS[-1] == "A"


# --------------------------------------------------------------------------- generated files


def test_plug_info_has_real_values():
    text = (RESOURCES / "plugInfo.json").read_text()
    assert "@PLUG_INFO" not in text
    info = json.loads("".join(line for line in text.splitlines() if not line.startswith("#")))
    (plugin,) = info["Plugins"]
    assert plugin["Type"] == "resource" and plugin["Name"] == "usdAhd"
    assert plugin["ResourcePath"] and plugin["Root"]
    t = plugin["Info"]["Types"][S.SCHEMA_TYPE_NAME]
    assert t["bases"] == ["UsdAPISchemaBase"]
    assert t["schemaKind"] == "singleApplyAPI"
    assert t["schemaIdentifier"] == S.API_NAME == t["alias"]["UsdSchemaBase"]
    assert t["apiSchemaCanOnlyApplyTo"] == ["Mesh"]


@pytest.mark.skipif(importlib.util.find_spec("jinja2") is None, reason="usdGenSchema needs jinja2")
def test_generated_files_match_the_generator():
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pxr.Usd.usdGenSchema",
            "--validate",
            str(SCHEMA_SRC),
            str(RESOURCES),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, (
        "plugins/usdAhd/resources drifted from schema/schema.usda; regenerate with "
        "python -m pxr.Usd.usdGenSchema schema/schema.usda plugins/usdAhd/resources\n"
        + proc.stdout
        + proc.stderr
    )


# ------------------------------------------------------------------------------ round trips


def _nondefault_inputs():
    return S.BakeInputs(
        bake=False,
        model="hlsh",
        ratio="rgb",
        solver="direct",
        uv_primvar="lightmapUV",
        resolution=512,
        texel_density=40.5,
        samples=1024,
        bounces=5,
    )


def test_inputs_round_trip(stage_with_mesh, tmp_path):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    S.apply(prim)
    assert S.read_inputs(prim) == S.BakeInputs()
    assert S.read_results(prim) is None and not S.is_baked(prim)
    want = _nondefault_inputs()
    S.write_inputs(prim, want)
    stage_with_mesh.GetRootLayer().Save()
    again = Usd.Stage.Open(str(tmp_path / "over.usda"))
    assert S.read_inputs(again.GetPrimAtPath("/World/Mesh")) == want
    S.write_inputs(prim, model="ahd")  # keyword form changes only that field
    assert S.read_inputs(prim) == want.replace(model="ahd")


def _results(tmp_path, roles=("iz", "direction", "ratio", "sh")):
    files = {r: str(tmp_path / "lightmaps" / f"Mesh_{r}.exr") for r in roles}
    return S.BakeResults(
        model="hlsh",
        ratio="rgb",
        solver="direct",
        uv_primvar="lightmapUV",
        resolution=(256, 128),
        textures=files,
        factors={k: 2.0 ** (i + 1) for i, k in enumerate(S.FACTORS)},
        content_hash="sha256:" + "ab" * 32,
        part_hashes={"geometry": "sha256:01", "lights": "sha256:02", "settings": "sha256:03"},
        settings={"samples": 1024, "bounces": 5, "denoise": False, "seed": 7, "dilate": 2.5},
        generator="usdahd 0.1.0",
    )


def test_results_round_trip_relative_paths_and_colorspace(stage_with_mesh, tmp_path):
    (tmp_path / "lightmaps").mkdir()
    want = _results(tmp_path)
    for f in want.textures.values():
        Path(f).write_bytes(b"")  # only resolution of the path is tested here
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    assert not S.has_api(prim)
    S.write_results(prim, want)  # applies the API
    stage_with_mesh.GetRootLayer().Save()
    layer_text = (tmp_path / "over.usda").read_text()
    assert "@./lightmaps/Mesh_iz.exr@" in layer_text
    assert str(tmp_path) not in layer_text  # nothing absolute in the override layer

    again = Usd.Stage.Open(str(tmp_path / "over.usda"))
    p = again.GetPrimAtPath("/World/Mesh")
    got = S.read_results(p)
    assert {r: str(Path(f).resolve()) for r, f in got.textures.items()} == {
        r: str(Path(f).resolve()) for r, f in want.textures.items()
    }
    assert got.asset_paths == {r: f"./lightmaps/Mesh_{r}.exr" for r in want.textures}
    for name in ("model", "ratio", "solver", "uv_primvar", "resolution", "factors"):
        assert getattr(got, name) == getattr(want, name), name
    for name in ("tangent_frame", "content_hash", "part_hashes", "settings", "generator"):
        assert getattr(got, name) == getattr(want, name), name
    assert got.format_version == S.FORMAT_VERSION
    for role in want.textures:
        attr = p.GetAttribute(S.file_property_name(role))
        assert attr.GetColorSpace() == S.COLOR_SPACES[role]
        assert attr.GetMetadata("colorSpace") == S.COLOR_SPACES[role]
    # Every result property is authored, so the layer describes the bake without the plugin.
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "over.usda"))
    spec = layer.GetPrimAtPath("/World/Mesh")
    for key in ["baked:" + k for k in S.FACTORS] + ["baked:formatVersion", "baked:resolution"]:
        assert S.property_name(key) in spec.properties, key


def test_packing_and_digests_are_authored_and_read_back(stage_with_mesh, tmp_path):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    res = _results(tmp_path)
    res.digests = {r: "sha256:" + f"{i:02x}" * 32 for i, r in enumerate(res.textures)}
    S.write_results(prim, res)
    got = S.read_results(prim)
    assert got.digests == res.digests
    want = S.layout_packing("hlsh", "rgb")
    assert got.packing == want
    assert want["direction"] == "R=u:snorm8b G=v:snorm8b B=_:reserved"
    assert prim.GetAttribute("ahdLightmap:texture:ratio:packing").Get() == want["ratio"]
    assert prim.GetAttribute("ahdLightmap:sidecar:sh:digest").Get() == res.digests["sh"]
    # a re-bake with another model clears the old roles' packing and digests as well
    other = _results(tmp_path, roles=("ambient", "sh"))
    other.model, other.ratio = "hemisphere", "none"
    S.write_results(prim, other)
    again = S.read_results(prim)
    assert set(again.packing) == {"ambient"} and set(again.digests) == set()
    assert not prim.GetAttribute("ahdLightmap:texture:iz:digest").HasAuthoredValue()
    bad = _results(tmp_path)
    bad.digests = {"iz": "md5:00"}
    with pytest.raises(SchemaError, match="digest of iz must be 'sha256:<hex>'"):
        S.write_results(prim, bad)


def test_version_1_bake_says_rebake_needed(stage_with_mesh, tmp_path):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    S.write_results(prim, _results(tmp_path))
    prim.GetAttribute("ahdLightmap:baked:formatVersion").Set(1)
    with pytest.raises(
        SchemaError, match="format version 1 was written by an older usdahd: re-bake"
    ):
        S.read_results(prim)


def test_file_digest_is_sha256_of_the_bytes(tmp_path):
    import hashlib

    f = tmp_path / "x.bin"
    f.write_bytes(b"lightmap")
    assert S.file_digest(f) == "sha256:" + hashlib.sha256(b"lightmap").hexdigest()


def test_rebake_clears_roles_the_new_model_does_not_write(stage_with_mesh, tmp_path):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    S.write_results(prim, _results(tmp_path, roles=("ambient", "directional", "direction", "sh")))
    S.write_results(prim, _results(tmp_path))
    got = S.read_results(prim)
    assert set(got.textures) == {"iz", "direction", "ratio", "sh"}


def test_write_results_needs_a_layer_directory(tmp_path):
    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.Mesh.Define(stage, "/M").GetPrim()
    with pytest.raises(SchemaError, match="anonymous layer"):
        S.write_results(prim, _results(tmp_path))
    S.write_results(prim, _results(tmp_path / "x"), layer_dir=tmp_path)  # explicit is fine
    assert S.read_results(prim).asset_paths["iz"] == "./x/lightmaps/Mesh_iz.exr"


def test_relative_asset_path_outside_the_layer_directory(tmp_path):
    assert S.relative_asset_path(tmp_path / "a" / "b.exr", tmp_path / "c") == "../a/b.exr"
    assert S.relative_asset_path(tmp_path / "c" / "b.exr", tmp_path / "c") == "./b.exr"


# ------------------------------------------------------------------------------- bad values


def test_bad_inputs_raise_clear_errors(stage_with_mesh):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    with pytest.raises(SchemaError, match="does not have AhdLightmapAPI"):
        S.read_inputs(prim)
    S.apply(prim)
    with pytest.raises(SchemaError, match=r"ahdLightmap:model = 'bogus' is not one of ahd"):
        S.write_inputs(prim, model="bogus")
    with pytest.raises(SchemaError, match="samples = 0 must be >= 1"):
        S.write_inputs(prim, samples=0)
    with pytest.raises(SchemaError, match="unknown bake input"):
        S.write_inputs(prim, colour="red")
    with pytest.raises(SchemaError, match="must be int"):
        S.write_inputs(prim, resolution=1.5)
    assert S.read_inputs(prim) == S.BakeInputs()  # nothing was authored by the failures


def test_bogus_authored_token_is_reported_not_enforced_by_usd(stage_with_mesh):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    S.apply(prim)
    # USD does not enforce allowedTokens: a raw Set succeeds, our reader catches it.
    assert prim.GetAttribute("ahdLightmap:ratio").Set("bogus")
    with pytest.raises(SchemaError, match=r"</World/Mesh>: ahdLightmap:ratio = 'bogus'"):
        S.read_inputs(prim)
    raw = S.read_inputs(prim, validate=False)
    assert raw.ratio == "bogus"
    assert S.input_problems(raw) == [
        "ahdLightmap:ratio = 'bogus' is not one of " + ", ".join(S.RATIOS)
    ]


def test_bad_results_raise_clear_errors(stage_with_mesh, tmp_path):
    prim = stage_with_mesh.GetPrimAtPath("/World/Mesh")
    good = _results(tmp_path)
    cases = {
        "unknown decode factor|no schema property": {"factors": {"gamma": 2.2}},
        "resolution": {"resolution": (0, 16)},
        "unknown texture role": {"textures": {"albedo": "/tmp/a.exr"}},
        "format version 7": {"format_version": 7},
        "izScale = -1": {"factors": {"izScale": -1.0}},
        "JSON": {"settings": {"bad": object()}},
    }
    for pattern, change in cases.items():
        bad = S.BakeResults(**{**good.__dict__, **change})
        with pytest.raises(SchemaError, match=pattern):
            S.write_results(prim, bad)
    S.write_results(prim, good)
    prim.GetAttribute("ahdLightmap:baked:settings").Set("not json")
    with pytest.raises(SchemaError, match="baked:settings is not JSON"):
        S.read_results(prim)
    prim.GetAttribute("ahdLightmap:baked:settings").Set("{}")
    prim.GetAttribute("ahdLightmap:baked:formatVersion").Set(99)
    with pytest.raises(SchemaError, match="format version 99"):
        S.read_results(prim)
    assert S.read_results(prim, validate=False).format_version == 99
    with pytest.raises(SchemaError, match="unknown texture role"):
        S.file_property_name("albedo")
    with pytest.raises(SchemaError, match="unknown decode factor"):
        good.factor("gamma")


# ------------------------------------------------------------------ docs/schema.md is correct

DOC = REPO / "docs" / "schema.md"
from tests import docs_decoder as DD  # noqa: E402  (the decoder written from docs/schema.md alone)


def test_doc_layout_block_is_generated_from_the_writers_table():
    """The layout tables on the page are exactly what usdahd.models.layout_docs renders from the
    models' own layout() (the table the writer uses); regenerate with
    python -m usdahd.models.layout_docs docs/schema.md."""
    from usdahd.models import layout_docs

    text = DOC.read_text()
    assert layout_docs.splice(text) == text, "docs/schema.md layouts drifted from the code"
    assert layout_docs.main(["--check", str(DOC)]) == 0


def test_layout_docs_check_fails_on_drift(tmp_path):
    from usdahd.models import layout_docs

    page = tmp_path / "schema.md"
    row = "| ahd, hhd | luminance | direction | PNG 8-bit | `R=u:snorm8b G=v:snorm8b B=w_a:unorm8`"
    assert row in DOC.read_text()
    page.write_text(DOC.read_text().replace(row, row.replace("B=w_a:unorm8", "B=w_a:snorm8b")))
    assert layout_docs.main(["--check", str(page)]) == 1
    assert layout_docs.main([str(page)]) == 0 and page.read_text() == DOC.read_text()
    page.write_text("no block here")
    with pytest.raises(ValueError, match="no generated block"):
        layout_docs.splice(page.read_text())


def test_doc_layouts_match_implemented_models_and_schema():
    layouts = DD.parse_layouts()
    assert {m for m, _ in layouts} == set(REGISTRY)
    codes = DD.parse_codes()
    from usdahd.models import names

    for name in names():
        mod = _model(name)
        for ratio in mod.RATIOS:
            got = [(t.role, t.packing, t.color_space) for t in mod.layout(ratio)]
            doc = [
                (
                    t["role"],
                    " ".join(
                        f"{c}={q}:{k}" + (f"*{f}" if f else "") for c, q, k, f in t["packing"]
                    ),
                    t["color_space"],
                )
                for t in layouts[(name, ratio)]
            ]
            assert got == doc, f"docs/schema.md layout of {name}/{ratio}"
            for t in mod.layout(ratio):
                assert t.role in ROLES and 3 <= len(t.channels) <= 4
                assert t.color_space == S.COLOR_SPACES[t.role]
                assert set(t.codes) <= codes
                assert t.extension in (".exr", ".png")
                assert all(f is None or f in S.FACTORS for f in t.scales)


def _model(name):
    from usdahd.errors import ModelError
    from usdahd.models import get

    try:
        return get(name)
    except ModelError:
        return None


def _doc_examples() -> dict[str, dict[str, np.ndarray]]:
    text = DOC.read_text()
    out = {}
    for block in text.split("<!-- example: ")[1:]:
        name = block.split(" -->", 1)[0]
        body = block.split("```text\n", 1)[1].split("```", 1)[0]
        vals = {}
        for line in body.strip().splitlines():
            k, v = (s.strip() for s in line.split("=", 1))
            vals[k] = v if k == "model" else np.array([float(x) for x in v.split()])
        out[name] = vals
    return out


@pytest.mark.parametrize("name", ["hhd luminance", "hlsh luminance"])
def test_doc_worked_example_decodes(name):
    """docs/schema.md "Worked examples": every printed intermediate follows from the inputs."""
    ex = _doc_examples()[name]
    tol = 1.5e-6  # values are printed with 6 decimals
    iz = ex["iz_stored"].astype(np.float16).astype(np.float64)
    assert np.array_equal(iz, ex["iz_stored"]), "example I_z must be exact in float16"
    np.testing.assert_allclose(iz * ex["izScale"], ex["I_z"], atol=tol)
    codes = ex["direction_codes"]
    uv = (codes[:2] - 128) / 127
    np.testing.assert_allclose(uv, ex["uv"], atol=tol)
    d = DD._hemioct(uv[0], uv[1])
    p = d * (np.abs(ex["p"]).sum() / np.abs(d).sum())
    np.testing.assert_allclose(p, ex["p"], atol=tol)
    np.testing.assert_allclose(d, ex["d"], atol=tol)
    np.testing.assert_allclose(ex["normal"] @ d, ex["n_dot_d"], atol=tol)
    signed = ex["model"] == "hlsh"
    wa = ((codes[2] - 128) / 127 if signed else codes[2] / 255) * ex["ratioScale"]
    np.testing.assert_allclose(wa, ex["w_a"], atol=tol)
    np.testing.assert_allclose(wa * ex["I_z"], ex["C_a"], atol=tol)
    np.testing.assert_allclose(ex["I_z"] * (1 - wa) / d[2], ex["C_d"], atol=tol)
    stored = {"iz": ex["iz_stored"].astype(np.float16)[None], "direction": codes[None]}
    stored["direction"] = stored["direction"].astype(np.uint8)
    factors = {"izScale": float(ex["izScale"][0]), "ratioScale": float(ex["ratioScale"][0])}
    layout = DD.parse_layouts()[(ex["model"], "luminance")]
    q = DD.quantities(layout, stored, factors)
    got = DD.irradiance(ex["model"], "luminance", q, ex["normal"][None])[0]
    np.testing.assert_allclose(got, ex["I"], atol=tol)
    at_z = DD.irradiance(ex["model"], "luminance", q, np.array([[0.0, 0.0, 1.0]]))[0]
    np.testing.assert_allclose(at_z, ex["I_z"], rtol=1e-12)  # IrradZ: I(z) = I_z exactly
    mod = _model(ex["model"])
    params = mod.decode(stored, ratio="luminance", factors=factors)
    np.testing.assert_allclose(mod.evaluate(params, ex["normal"][None])[0], ex["I"], rtol=2e-6)


def _random_stored(layout, rng, n):
    out = {}
    for tex in layout:
        cols = []
        for _c, q, code, _f in tex["packing"]:
            if code == "half":
                lo = 0.0 if q.startswith(("I_z", "C")) else -1.0
                cols.append(rng.uniform(lo, 4.0, n).astype(np.float16))
            elif code == "snorm8b" and q in ("u", "v"):
                cols.append(rng.integers(2, 255, n).astype(np.uint8))  # documented 2..254
            elif code == "reserved":
                cols.append(np.full(n, 128, np.uint8))
            else:
                cols.append(rng.integers(0, 256, n).astype(np.uint8))
        out[tex["role"]] = np.stack(cols, axis=-1)
    return out


def test_doc_decoders_match_implemented_models_on_random_codes():
    """For every model and ratio, the page's formulas == usdahd's decode + evaluate."""
    layouts = DD.parse_layouts()
    rng = np.random.default_rng(3)
    normals = sh_mod.fibonacci_sphere(64, hemisphere=True)
    from usdahd.models import names

    for name in names():
        mod = _model(name)
        for ratio in mod.RATIOS:
            stored = _random_stored(layouts[(name, ratio)], rng, len(normals))
            factors = {k: 2.0 for k in S.FACTORS}
            got = mod.evaluate(mod.decode(stored, ratio=ratio, factors=factors), normals)
            q = DD.quantities(layouts[(name, ratio)], stored, factors)
            want = DD.irradiance(name, ratio, q, normals)
            scale = np.abs(want).max()
            # float32 decoders against float64 formulas: C_d = ... / d_z amplifies by <= 127.
            np.testing.assert_allclose(got, want, atol=1e-4 * scale, err_msg=f"{name}/{ratio}")
