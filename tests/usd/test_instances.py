"""Every instance copy baked (issue 39 item 2): scenegraph instances and PointInstancer
instances each get their own lightmap on the prototype's UVs, recorded outside the prototype
(on the instance prim / the PointInstancer), checked by validate and drawn by preview.

The stage is tests/instance_scene.py: sun + sky, a roof over half of the copies.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.instance_scene import (
    HIDDEN,
    OPEN_POINTS,
    OPEN_SKY_OCCLUSION,
    POINTS,
    ROOFED_POINTS,
    SCENEGRAPH,
    top_iz,
    write_stage,
)
from tests.scenes import ROOT
from tests.stats import assert_mean
from usdahd import cli
from usdahd.numerics import sh as shmod

ARGS = ["--resolution", "16", "--samples", "64", "--bounces", "0", "--no-denoise"]
PI = "/World/Pawns"
SG_KEYS = [f"{p}/Box" for p in SCENEGRAPH]
PI_KEYS = [f"{PI}/instance_{i}/Box" for i in range(len(POINTS)) if i not in HIDDEN]
OPEN = [k for k in SG_KEYS if "open" in k] + [f"{PI}/instance_{i}/Box" for i in OPEN_POINTS]
ROOFED = [k for k in SG_KEYS if "roofed" in k] + [f"{PI}/instance_{i}/Box" for i in ROOFED_POINTS]
#: The top (+y) face's UV chart in instance_scene._box: chart 3 (column 0, row 1).
TOP_CHART = ((0.02, 1 / 3 - 0.02), (0.52, 0.98))


def _bake(stage, *extra, capsys=None):
    code = cli.main(["bake", str(stage), *ARGS, "--json", *extra])
    out = capsys.readouterr()
    return code, json.loads(out.out), out.err


def _records(layer):
    from pxr import Usd

    from usdahd.usd import schema

    return schema.stage_records(Usd.Stage.Open(str(layer)))


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """(stage, layer, first bake's report): one bake shared by the read-only tests."""
    d = tmp_path_factory.mktemp("instances")
    stage = write_stage(d / "inst.usda")
    code = cli.main(["bake", str(stage), *ARGS, "--json", "--quiet"])
    assert code == 0
    return stage, d / "inst.lightmaps.usda"


def _top_iz(res) -> np.ndarray:
    """(n, 3) I_z of the covered texels of the top face's chart, from the SH sidecar."""
    from usdahd.usd import schema

    side = schema.read_record_pixels(res, "sh", channels=schema.SH_SIDECAR_CHANNELS)
    h, w = side.shape[:2]
    ys, xs = np.nonzero(side[..., -1] > 0)
    u, v = (xs + 0.5) / w, 1.0 - (ys + 0.5) / h
    (u0, u1), (v0, v1) = TOP_CHART
    inside = (u > u0 + 1 / w) & (u < u1 - 1 / w) & (v > v0 + 1 / h) & (v < v1 - 1 / h)
    sh = side[ys[inside], xs[inside]][:, :27].astype(np.float64).reshape(-1, 3, 9)
    return shmod.iz(sh)


def test_every_instance_is_baked_and_recorded_outside_the_prototype(baked):
    from pxr import Sdf, Usd

    from usdahd.usd import schema

    stage, layer = baked
    recs = _records(layer)
    assert sorted(recs) == sorted(["/World/Ground", "/World/Roof", *SG_KEYS, *PI_KEYS])
    # every copy its own texel set: its own file, or its own rectangle of an atlas page
    rects = {(res.textures["iz"], res.page, tuple(res.scale_offset)) for res in recs.values()}
    assert len(rects) == len(recs)
    assert all(res.atlas for res in recs.values())  # the default bake packs atlas pages
    for key in SG_KEYS + PI_KEYS:
        assert recs[key].resolution == (16, 16) and recs[key].uv_primvar == "st"
    # Nothing is authored inside a prototype or under an instance: no de-instancing.
    out = Sdf.Layer.FindOrOpen(str(layer))
    specs = []
    out.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(p))
    prims = {str(p) for p in specs if p.IsPrimPath()}
    assert not any(p.startswith("/Proto") or "/Prototypes" in p for p in prims)
    assert not any(p.startswith(tuple(SCENEGRAPH)) and p not in SCENEGRAPH for p in prims)
    st = Usd.Stage.Open(str(layer))
    for carrier in [*SCENEGRAPH, PI]:
        prim = st.GetPrimAtPath(carrier)
        assert prim.HasAPI(schema.INSTANCE_API_NAME), carrier
    assert all(st.GetPrimAtPath(p).IsInstance() for p in SCENEGRAPH)  # still instances
    # The PointInstancer's arrays are indexed like positions; the hidden instance has none.
    pi = st.GetPrimAtPath(PI)
    versions = list(pi.GetAttribute("ahdInstances:baked:formatVersion").Get())
    assert len(versions) == len(POINTS) and list(pi.GetAttribute("ahdInstances:meshes").Get())
    assert [i for i, v in enumerate(versions) if v == 0] == list(HIDDEN)


def test_open_top_face_matches_the_analytic_sky_and_sun(baked):
    """An open copy's top face sees the sky (radiance SKY) and the sun: I_z = SKY +
    SUN sin(elevation) / pi per channel, within 5 standard errors of the texels' mean plus the
    share of the sky the distant roof hides (instance_scene.OPEN_SKY_OCCLUSION)."""
    _, layer = baked
    recs = _records(layer)
    want = np.array(top_iz())
    for key in OPEN:
        iz = _top_iz(recs[key])
        assert len(iz) >= 8, key
        for c in range(3):
            assert_mean(iz[:, c], want[c], rel=OPEN_SKY_OCCLUSION, what=(key, c))


def test_roofed_copies_are_darker_and_their_own(baked):
    from usdahd.usd import schema

    _, layer = baked
    recs = _records(layer)
    open_mean = np.mean([_top_iz(recs[k]).mean() for k in OPEN])
    for key in ROOFED:
        iz = _top_iz(recs[key]).mean()
        assert iz < 0.5 * open_mean, (key, iz, open_mean)  # no sun and no sky overhead
        mine = schema.read_record_pixels(recs[key], "iz")
        for k in OPEN:  # its own lightmap: not a copy of an open instance's rectangle
            assert not np.array_equal(mine, schema.read_record_pixels(recs[k], "iz")), (key, k)


def test_validate_is_clean(baked, capsys):
    _, layer = baked
    code = cli.main(["validate", str(layer), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0, report
    bad = [f for f in report["findings"] if f["severity"] != "info"]
    assert not bad
    checked = {f["prim"] for f in report["findings"] if f["rule"] == "IzCheck"}
    assert set(SG_KEYS + PI_KEYS) <= checked  # every entry checked like a mesh record


def test_preview_draws_each_copy_with_its_own_lightmap(baked):
    from usdahd.preview.meshes import baked_meshes

    _, layer = baked
    recs = _records(layer)
    _, meshes, _ = baked_meshes(str(layer))
    drawn = {m.path: (m, res) for m, res, *_ in meshes}
    assert set(SG_KEYS + PI_KEYS) <= set(drawn)
    for key in SG_KEYS + PI_KEYS:
        mesh, res = drawn[key]
        assert res.textures == recs[key].textures
    # each copy at its own place: the scenegraph copies' centres are their translations
    for carrier, (x, z) in SCENEGRAPH.items():
        c = np.asarray(drawn[f"{carrier}/Box"][0].points).mean(axis=0)
        np.testing.assert_allclose(c[[0, 2]], [x, z], atol=1e-6)


def test_unchanged_rebake_traces_no_ray_and_moving_one_copy_changes_only_its_inputs(
    tmp_path, capsys
):
    """A re-bake of an unchanged stage traces 0 rays and writes nothing. Moving one copy
    changes that copy's own inputs (``geometry``: its world transform) and nothing of the
    others but the scene they see (``scene_geometry``: the moved copy shadows and bounces),
    so each record is hashed per copy, not per prototype."""
    stage = write_stage(tmp_path / "inst.usda")
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 0
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 0 and not rep["written"]
    assert {p["status"] for p in rep["prims"]} == {"skipped"}
    assert sum(p.get("rays", 0) for p in rep["prims"]) == 0
    moved = "/World/Instances/open_1"
    write_stage(stage, moved={moved: (15.0, 2.0)})
    # validate (before the re-bake) names the moved copy's own geometry as changed
    code = cli.main(["validate", str(tmp_path / "inst.lightmaps.usda"), "--json"])
    found = json.loads(capsys.readouterr().out)["findings"]
    stale = {f["prim"]: f["data"]["changed"] for f in found if f["code"] == "Stale"}
    assert code == 1 and "geometry" in stale[f"{moved}/Box"]
    assert stale[f"{PI}/instance_0/Box"] == ["scene_geometry"]
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 0
    reasons = {p["path"]: p.get("reason", "") for p in rep["prims"]}
    assert "geometry" in reasons[f"{moved}/Box"].split(": ")[1].split(", ")
    for key, why in reasons.items():
        if key != f"{moved}/Box":
            assert why == "changed: scene_geometry", (key, why)
    assert cli.main(["validate", str(tmp_path / "inst.lightmaps.usda"), "--quiet"]) == 0


def test_validate_reports_a_copy_without_its_own_record(tmp_path, capsys):
    from pxr import Usd, Vt

    stage = write_stage(tmp_path / "inst.usda")
    assert _bake(stage, capsys=capsys)[0] == 0
    layer = tmp_path / "inst.lightmaps.usda"
    st = Usd.Stage.Open(str(layer))
    attr = st.GetPrimAtPath(PI).GetAttribute("ahdInstances:baked:formatVersion")
    v = list(attr.Get())
    v[1] = 0
    attr.Set(Vt.IntArray(v))
    st.GetRootLayer().Save()
    code = cli.main(["validate", str(layer), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 1
    bad = [f for f in report["findings"] if f["severity"] == "error"]
    assert [(f["prim"], f["code"]) for f in bad] == [(f"{PI}/instance_1/Box", "NoInstanceRecord")]
    assert "re-bake" in bad[0]["message"]


def test_copies_of_a_baked_prototype_prim_get_their_own_records(tmp_path, capsys):
    """The prototype is a visible, baked mesh that instances reference: its record used to
    reach every copy through the instance (preview drew its lightmap on them, validate called
    them stale). Now each copy has its own record, and the copies' records are not the
    prototype's."""
    stage = write_stage(tmp_path / "inst.usda")
    text = stage.read_text().replace('class Xform "Proto"', 'def Xform "Proto"')
    stage.write_text(text)
    assert _bake(stage, capsys=capsys)[0] == 0
    layer = tmp_path / "inst.lightmaps.usda"
    recs = _records(layer)
    assert "/Proto/Box" in recs
    for key in SG_KEYS:
        assert recs[key].content_hash != recs["/Proto/Box"].content_hash
        own = (recs[key].textures, recs[key].scale_offset)
        assert own != (recs["/Proto/Box"].textures, recs["/Proto/Box"].scale_offset)
    from usdahd.preview.meshes import baked_meshes

    drawn = {m.path: res for m, res, *_ in baked_meshes(str(layer))[1]}
    assert all(
        (drawn[k].textures, drawn[k].scale_offset) == (recs[k].textures, recs[k].scale_offset)
        for k in SG_KEYS
    )
    assert cli.main(["validate", str(layer), "--quiet"]) == 0


def test_prototype_without_uvs_is_named_with_the_fix(tmp_path, capsys):
    from usdahd.usd.reader import load_scene

    stage = write_stage(tmp_path / "inst.usda", proto_uv=False)
    sc = load_scene(str(stage))
    assert not any(m.bake for m in sc.meshes if m.instance is not None)
    msgs = [w for w in sc.warnings if "prototype mesh has no lightmap UV set" in w]
    # one per prototype mesh: the scenegraph copies' reference target and the
    # PointInstancer's prototype (which references it too)
    assert len(msgs) == 1 and "</Proto/Box>" in msgs[0] and "8 instance copies" in msgs[0]
    for fix in ("author the UV set in the asset", "instanceable = false", "usdahd bake"):
        assert fix in msgs[0]
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 0
    assert sorted(p["path"] for p in rep["prims"]) == ["/World/Ground", "/World/Roof"]
    assert any("prototype mesh has no lightmap UV set" in w for w in rep["warnings"])


def test_prototype_without_uvs_subprocess(tmp_path):
    stage = write_stage(tmp_path / "inst.usda", proto_uv=False)
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *ARGS, "--resolution", "8"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert "prototype mesh has no lightmap UV set 'st'" in proc.stdout + proc.stderr
    assert "</Proto/Box>" in proc.stdout + proc.stderr


def test_a_uv_name_the_prototype_lacks_is_named_too(tmp_path):
    """--uv names a set the prototype lacks: the copies are not unwrapped (xatlas cannot author
    into a prototype) and the message names that set and the prototype mesh."""
    from usdahd.usd.reader import load_scene

    sc = load_scene(str(write_stage(tmp_path / "inst.usda")), uv_name="lm")
    assert not any(m.bake for m in sc.meshes if m.instance is not None)
    assert any("</Proto/Box>: prototype mesh has no lightmap UV set 'lm'" in w for w in sc.warnings)


# ------------------------------------------------------------------------------------ schema


def _instance_source_props():
    from pxr import Sdf

    from usdahd.usd import schema

    layer = Sdf.Layer.FindOrOpen(str(ROOT / "schema" / "schema.usda"))
    cls = layer.GetPrimAtPath("/" + schema.INSTANCE_API_NAME)
    assert cls, f"schema.usda has no class {schema.INSTANCE_API_NAME}"
    return layer, {p.name: p for p in cls.properties}


def test_instance_api_definition_matches_the_schema_source():
    """The plugin's generated definition of AhdInstanceLightmapAPI equals schema/schema.usda
    (types, fallbacks, colorSpace, allowedTokens, one-sentence docs)."""
    from pxr import Sdf, Usd

    from usdahd.usd import schema

    _layer, src = _instance_source_props()
    d = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(schema.INSTANCE_API_NAME)
    assert d is not None
    assert sorted(d.GetPropertyNames()) == sorted(src)
    for name, spec in src.items():
        prop = d.GetAttributeDefinition(name)
        assert name.startswith(schema.INSTANCE_NAMESPACE + ":"), name
        assert prop.GetTypeName() == spec.typeName, name
        assert prop.GetVariability() == spec.variability == Sdf.VariabilityUniform, name
        assert prop.GetFallbackValue() == spec.default, name
        assert (prop.GetMetadata("colorSpace") or "") == spec.GetInfo("colorSpace"), name
        assert list(prop.GetMetadata("allowedTokens") or []) == list(
            spec.GetInfo("allowedTokens") or []
        ), name
        doc = spec.GetInfo("documentation")
        assert doc.endswith(".") and ". " not in doc[:-1] and "\n" not in doc, name


def test_every_record_property_has_an_array_twin():
    """Each result property of AhdLightmapAPI (textures, sidecar, baked:*, digests, packing) has
    an ahdInstances: twin of its array type (and the atlas properties of issue 39)."""
    from pxr import Usd

    from usdahd.usd import schema

    reg = Usd.SchemaRegistry()
    mesh = reg.FindAppliedAPIPrimDefinition(schema.API_NAME)
    inst = reg.FindAppliedAPIPrimDefinition(schema.INSTANCE_API_NAME)
    results = [
        n for n in mesh.GetPropertyNames() if n.split(":")[1] in ("texture", "sidecar", "baked")
    ]
    assert len(results) > 40
    for name in results:
        twin = schema.instance_property_name(name.split(":", 1)[1])
        got = inst.GetAttributeDefinition(twin)
        assert got, twin
        want = mesh.GetAttributeDefinition(name).GetTypeName().arrayType
        assert got.GetTypeName() == want, name
    for key, t in (("atlas:page", "int[]"), ("atlas:scaleOffset", "float4[]")):
        assert (
            str(inst.GetAttributeDefinition(schema.instance_property_name(key)).GetTypeName()) == t
        )


def test_instance_records_round_trip_and_bad_keys(tmp_path):
    from pxr import Usd

    from usdahd.errors import SchemaError
    from usdahd.usd import schema

    stage_path = write_stage(tmp_path / "inst.usda")
    st = Usd.Stage.Open(str(stage_path))
    st.SetEditTarget(st.GetSessionLayer())
    pi = st.GetPrimAtPath(PI)
    count, cols = schema.instance_layout(pi)
    assert count == len(POINTS) and cols == [(0, "Box")]
    tex = tmp_path / "lightmaps" / "a.iz.exr"
    res = schema.BakeResults(
        model="hhd",
        ratio="luminance",
        solver="",
        uv_primvar="st",
        resolution=(8, 4),
        textures={"iz": str(tex)},
        factors={"izScale": 2.0},
        content_hash="sha256:00",
        settings={"uv": "st"},
    )
    key = schema.instance_key(PI, 3, "Box", True)
    assert key == f"{PI}/instance_3/Box"
    schema.write_instance_records(pi, {key: res}, layer_dir=tmp_path)
    got = schema.read_instance_records(pi)
    assert list(got) == [key]
    back = got[key]
    assert back.resolution == (8, 4) and back.factor("izScale") == 2.0
    assert back.asset_paths == {"iz": "./lightmaps/a.iz.exr"} and back.settings == {"uv": "st"}
    assert len(pi.GetAttribute("ahdInstances:texture:iz").Get()) == len(POINTS)
    assert pi.GetAttribute("ahdInstances:texture:iz").GetColorSpace() == "lin_rec709_scene"
    assert schema.instance_carrier(st, key) == PI
    assert schema.instance_carrier(st, "/World/Instances/open_0/Box") == "/World/Instances/open_0"
    assert schema.instance_carrier(st, "/World/Ground") is None
    with pytest.raises(SchemaError, match=r"instance_9/Box is not an instance entry"):
        schema.write_instance_records(pi, {f"{PI}/instance_9/Box": res}, layer_dir=tmp_path)
    bad = schema.BakeResults(**{**res.__dict__, "model": "nope"})
    with pytest.raises(SchemaError, match=r"instance_3/Box>: invalid bake results"):
        schema.write_instance_records(pi, {key: bad}, layer_dir=tmp_path)


def test_a_prototype_input_naming_a_missing_uv_set_fails_the_copies(tmp_path, capsys):
    """The prototype mesh authors ahdLightmap:uvPrimvar = "lm", which it lacks: its copies fail
    with the message naming the prototype mesh and the fix (never an xatlas unwrap of a
    prototype), the other prims bake."""
    stage = write_stage(tmp_path / "inst.usda")
    text = stage.read_text().replace(
        'class Xform "Proto"\n{\n    def Mesh "Box"\n    {\n',
        'class Xform "Proto"\n{\n    def Mesh "Box" (\n        prepend apiSchemas = '
        '["AhdLightmapAPI"]\n    )\n    {\n        uniform string ahdLightmap:uvPrimvar = "lm"\n',
    )
    assert 'ahdLightmap:uvPrimvar = "lm"' in text
    stage.write_text(text.replace("def Mesh \"Ground\"\n    {\n", "def Mesh \"Ground\" (\n"
                                  "        prepend apiSchemas = [\"AhdLightmapAPI\"]\n    )\n"
                                  "    {\n"))  # fmt: skip
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 1
    failed = {p["path"]: p.get("error", "") for p in rep["prims"] if p["status"] == "failed"}
    assert sorted(failed) == sorted(SG_KEYS + PI_KEYS)
    msg = failed[SG_KEYS[0]]
    assert "</Proto/Box>: prototype mesh has no lightmap UV set 'lm'" in msg
    assert "instanceable = false" in msg
    assert {p["path"] for p in rep["prims"] if p["status"] != "failed"} == {"/World/Ground"}


def test_a_stage_with_only_instance_records_is_lightmapped(tmp_path, capsys):
    """--prim the PointInstancer: the layer holds instance records only, and validate checks
    them (no NoAhdLightmapAPI error)."""
    stage = write_stage(tmp_path / "inst.usda")
    code, rep, _ = _bake(stage, "--prim", PI, capsys=capsys)
    assert code == 0 and sorted(p["path"] for p in rep["prims"]) == sorted(PI_KEYS)
    code = cli.main(["validate", str(tmp_path / "inst.lightmaps.usda"), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0, report["findings"]
    assert sorted(report["prims"]) == sorted(PI_KEYS)


def test_copies_of_a_prototype_without_normals_record_the_rule(baked):
    """The prototype authors no normals: each copy is traced with crease-angle normals, which
    the bake cannot author into the prototype; its record names the rule."""
    _, layer = baked
    recs = _records(layer)
    assert {recs[k].normals for k in SG_KEYS + PI_KEYS} == {"creaseAngle30"}


NESTED = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "Y"
)

class Xform "Inner"
{
MESH_INNER
}

class Xform "Outer"
{
    def Xform "in" (
        instanceable = true
        references = </Inner>
    )
    {
        double3 xformOp:translate = (0, 0, 2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
MESH_OWN
}

def Xform "World"
{
MESH_GROUND
    def Xform "o1" (
        instanceable = true
        references = </Outer>
    )
    {
        double3 xformOp:translate = (3, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }

    def PointInstancer "PI"
    {
        point3f[] positions = [(-3, 0, 0), (-3, 0, 3), (-3, 0, 6)]
        int[] protoIndices = [1, 0, 1]
        rel prototypes = [</World/PI/Protos/A>, </World/PI/Protos/B>]

        def Scope "Protos"
        {
            def Xform "A"
            {
MESH_A1
MESH_A2
            }
MESH_B
        }
    }

    def DomeLight "Sky"
    {
        float inputs:intensity = 1
    }
}
"""


def test_multi_mesh_prototypes_nested_instances_and_columns(tmp_path, capsys):
    """A PointInstancer of two prototypes (A: two meshes, B: a mesh itself) and a scenegraph
    instance whose prototype holds a mesh and a nested instance: every copy is baked, the
    PointInstancer's arrays are N x M with no entry where an instance uses the other
    prototype, keys follow the reader's names, and validate is clean."""
    from pxr import Usd

    from tests.instance_scene import _mesh
    from usdahd.usd import schema

    text = NESTED
    for tag, name, lo, hi, ind in (
        ("MESH_INNER", "m", (0, 0, 0), (1, 1, 1), "    "),
        ("MESH_OWN", "own", (0, 0, 0), (1, 0.5, 1), "    "),
        ("MESH_GROUND", "Ground", (-10, -0.1, -10), (10, 0, 10), "    "),
        ("MESH_A1", "a1", (0, 0, 0), (1, 1, 1), "                "),
        ("MESH_A2", "a2", (0, 1, 0), (0.5, 2, 0.5), "                "),
        ("MESH_B", "B", (0, 0, 0), (1, 0.3, 1), "            "),
    ):
        text = text.replace(tag, _mesh(name, lo, hi, indent=ind))
    stage = tmp_path / "nested.usda"
    stage.write_text(text)
    code, rep, _ = _bake(stage, "--resolution", "8", "--samples", "16", capsys=capsys)
    assert code == 0, rep
    want = [
        "/World/Ground",
        "/World/o1/in/m",
        "/World/o1/own",
        "/World/PI/instance_0",  # prototype B is the mesh itself
        "/World/PI/instance_1/a1",
        "/World/PI/instance_1/a2",
        "/World/PI/instance_2",
    ]
    assert sorted(p["path"] for p in rep["prims"]) == sorted(want)
    layer = tmp_path / "nested.lightmaps.usda"
    recs = _records(layer)
    assert sorted(recs) == sorted(want)
    st = Usd.Stage.Open(str(layer))
    pi = st.GetPrimAtPath("/World/PI")
    assert schema.instance_layout(pi) == (3, [(0, "a1"), (0, "a2"), (1, ".")])
    v = list(pi.GetAttribute("ahdInstances:baked:formatVersion").Get())
    assert [int(bool(x)) for x in v] == [0, 0, 1, 1, 1, 0, 0, 0, 1]
    o1 = st.GetPrimAtPath("/World/o1")
    assert list(o1.GetAttribute("ahdInstances:meshes").Get()) == ["in/m", "own"]
    assert o1.IsInstance()
    code = cli.main(["validate", str(layer), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0, [f for f in report["findings"] if f["severity"] != "info"]
    checked = {f["prim"] for f in report["findings"] if f["rule"] == "IzCheck"}
    assert checked == set(want)


def test_an_unusable_prototype_uv_set_fails_the_copies_with_the_fix(tmp_path, capsys):
    """The prototype's st exists but is degenerate (every UV the same point): a mesh would be
    unwrapped into a new set, a copy cannot be (its UVs live in the prototype)."""
    import re

    stage = write_stage(tmp_path / "inst.usda")
    text = stage.read_text()
    start = text.index('class Xform "Proto"')
    end = text.index('def Xform "World"')
    proto = re.sub(r"texCoord2f\[\] primvars:st = \[[^\]]*\]",
                   "texCoord2f[] primvars:st = [" + ", ".join(["(0.5, 0.5)"] * 24) + "]",
                   text[start:end])  # fmt: skip
    stage.write_text(text[:start] + proto + text[end:])
    code, rep, _ = _bake(stage, capsys=capsys)
    assert code == 1
    failed = {p["path"]: p.get("error", "") for p in rep["prims"] if p["status"] == "failed"}
    assert sorted(failed) == sorted(SG_KEYS + PI_KEYS)
    msg = failed[f"{PI}/instance_0/Box"]
    # the PointInstancer's prototype references /Proto: the message names the asset's mesh
    assert "inst.usda@</Proto/Box> has zero area" in msg and "cannot be unwrapped" in msg
    assert "fix the UV set in the asset" in msg


def test_an_unreadable_instance_record_is_an_error_naming_the_carrier(baked, tmp_path, capsys):
    import shutil

    from pxr import Usd, Vt

    _, layer = baked
    d = tmp_path / "copy"
    shutil.copytree(layer.parent, d)
    copy = d / layer.name
    st = Usd.Stage.Open(str(copy))
    attr = st.GetPrimAtPath(PI).GetAttribute("ahdInstances:baked:partHashes")
    v = list(attr.Get())
    v[0] = "{not json"
    attr.Set(Vt.StringArray(v))
    st.GetRootLayer().Save()
    code = cli.main(["validate", str(copy), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 1
    bad = [f for f in report["findings"] if f["severity"] == "error"]
    assert [(f["prim"], f["code"]) for f in bad] == [(PI, "NoInstanceRecord")]
    assert "ahdInstances:baked:partHashes is not JSON" in bad[0]["message"]


def test_validate_and_preview_subprocess(baked, tmp_path):
    """The CLI paths as subprocesses: validate exits 0 on the instances' layer and preview draws
    all ten records (two meshes, eight copies)."""
    _, layer = baked
    run = [sys.executable, "-m", "usdahd"]
    proc = subprocess.run([*run, "validate", str(layer), "--quiet"], capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = tmp_path / "p.png"
    proc = subprocess.run(
        [*run, "preview", str(layer), "-o", str(out), "--size", "64", "48", "--backend", "embree"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert "10 meshes" in proc.stdout and out.is_file()


def test_a_time_sampled_point_instancer_is_baked_and_validates(tmp_path, capsys):
    """positions only time-sampled (no default): the bake reads it at the stage's bake time,
    the records are laid out at the same sample, and validate finds them."""
    import re

    stage = write_stage(tmp_path / "inst.usda")
    text = re.sub(
        r"point3f\[\] positions = (\[[^\]]*\])",
        r"point3f[] positions.timeSamples = {\n 1: \1,\n 5: \1\n }",
        stage.read_text(),
    )
    stage.write_text(text)
    code, rep, _ = _bake(stage, "--resolution", "8", "--samples", "8", capsys=capsys)
    assert code == 0 and rep["time"] == 1.0
    assert set(PI_KEYS) <= {p["path"] for p in rep["prims"]}
    assert cli.main(["validate", str(tmp_path / "inst.lightmaps.usda"), "--quiet"]) == 0
