"""usdahd validate: the UsdValidation plugin, the rules on clean and one-defect assets, the CLI.

Assets are synthetic bakes built in a temporary directory by tests/data/validate/make_assets.py
(no committed binaries): every bad asset breaks exactly one rule.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdValidation  # noqa: I001

import usdahd.usd  # noqa: F401  (registers the plugins first)
from usdahd import cli
from usdahd import validate as V
from usdahd.numerics import encoding
from usdahd.usd import plugin

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "data" / "validate"))
import make_assets as MA  # noqa: E402


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """{"clean": layer path, defect: layer path} for every defect of make_assets.DEFECTS."""
    top = tmp_path_factory.mktemp("validate")
    out = {"clean": MA.make_clean(top / "clean")}
    for name in MA.DEFECTS:
        out[name] = MA.make_bad(top / "bad" / name, name, top / "clean")
    return out


def _findings(layer: Path) -> list[V.Finding]:
    from usdahd.usd.stage import open_stage
    from usdahd.validate.run import validate_stage

    return validate_stage(open_stage(str(layer)))


def _ours(findings, severities=("error", "warning")):
    return [f for f in findings if f.rule in V.RULE_NAMES and f.severity in severities]


# ------------------------------------------------------------------------------ the plugin


def test_pluginfo_declares_every_rule_with_its_description():
    info = json.loads(
        "\n".join(
            line
            for line in (ROOT / "plugins/usdAhdValidators/plugInfo.json").read_text().splitlines()
            if not line.lstrip().startswith("#")
        )
    )
    (plug,) = info["Plugins"]
    assert plug["Type"] == "python" and plug["Name"] == V.PLUGIN_NAME
    declared = plug["Info"]["Validators"]
    # + the opt-in Retrace rule (own keyword; checked in tests/test_retrace.py)
    assert list(declared) == [*V.RULE_NAMES, *(r.name for r in V.STAGE_RULES), "Retrace"]
    for rule in V.STAGE_RULES:  # stage validators: no schema type
        assert declared[rule.name] == {"doc": rule.description, "keywords": [V.KEYWORD]}
    schema_types = json.loads(
        (ROOT / "plugins/usdAhd/resources/plugInfo.json").read_text().split("\n", 3)[3]
    )["Plugins"][0]["Info"]["Types"]
    for rule in V.RULES:
        d = declared[rule.name]
        assert d["doc"] == rule.description
        assert rule.description.endswith(".") and rule.description.count(". ") == 0
        assert d["keywords"] == [V.KEYWORD]
        # The TfType name, not the bare schema name: with the latter the validator never runs.
        assert d["schemaTypes"] == [plugin.SCHEMA_TYPE_NAME]
        assert plugin.SCHEMA_TYPE_NAME in schema_types


def test_validators_registered_under_the_keyword():
    reg = UsdValidation.ValidationRegistry()
    names = {m.name for m in reg.GetValidatorMetadataForKeyword(V.KEYWORD)}
    stage_rules = [r.name for r in V.STAGE_RULES]
    assert names == {V.validator_name(r) for r in [*V.RULE_NAMES, *stage_rules]}
    for r in stage_rules:
        assert reg.GetOrLoadValidatorByName(V.validator_name(r)) is not None
    for r in V.RULE_NAMES:
        assert reg.GetOrLoadValidatorByName(V.validator_name(r)) is not None
    assert V.register() == []  # idempotent


def test_exception_in_a_rule_is_reported_not_raised(assets, monkeypatch):
    def boom(prim):
        raise RuntimeError("synthetic failure")

    monkeypatch.setitem(V.CHECKS, "UVSet", boom)
    stage = Usd.Stage.Open(str(assets["clean"]))
    ctx = UsdValidation.ValidationContext(keywords=[V.KEYWORD])
    errors = ctx.Validate(stage)  # must not raise: one exception would abort the whole run
    bad = [V.finding_from_usd(e) for e in errors if e.GetName() == "InternalError"]
    assert len(bad) == 1 and bad[0].rule == "UVSet" and "synthetic failure" in bad[0].message
    assert cli.main(["validate", str(assets["clean"])]) == 2


# ----------------------------------------------------------------------------------- rules


def test_clean_asset_has_no_errors_or_warnings(assets):
    found = _findings(assets["clean"])
    assert _ours(found) == []
    assert [f for f in found if f.severity != "info"] == []
    iz = [f for f in found if f.rule == "IzCheck"]
    assert [f.code for f in iz] == ["IzOk"]
    assert iz[0].data["max_relative"] <= V.FORMAT_RELATIVE_TOLERANCE["half"]
    assert iz[0].data["worst_error_over_tolerance"] <= 1.0
    assert iz[0].data["texels"] > 100
    enc = [f for f in found if f.rule == "EncodingError"]
    assert enc[0].data["relative_rmse"] < V.OPTIONS.rmse_warning


@pytest.mark.parametrize("defect", list(MA.DEFECTS))
def test_bad_asset_fails_exactly_its_rule(assets, defect):
    rule = MA.DEFECTS[defect][0]
    found = _ours(_findings(assets[defect]))
    assert found, f"{defect}: no finding"
    assert {f.rule for f in found} == {rule}, [(f.rule, f.message) for f in found]
    for f in found:
        assert f.prim == MA.PRIM and "Fix:" in f.message


def test_bad_asset_details(assets):
    iz = _ours(_findings(assets["corrupted_iz"]))[0]
    assert iz.code == "IzMismatch" and iz.data["failing"] == 1
    assert 0.009 < iz.data["max_relative"] < 0.011  # the texel was scaled by 1.01
    ys, xs = MA._covered(assets["corrupted_iz"].parent)
    assert tuple(iz.data["worst_texel"]) == (xs[7], ys[7])
    stale = _ours(_findings(assets["moved_light"]))[0]
    assert stale.data["changed"] == ["lights"]
    tok = _ours(_findings(assets["bogus_token"]))[0]
    assert tok.code == "TokenNotAllowed" and "ahdLightmap:ratio" in tok.message
    mir = _ours(_findings(assets["mirrored_directions"]))
    assert [(f.rule, f.code, f.data["suspect_role"]) for f in mir] == [
        ("IzCheck", "CodeMismatch", "direction")
    ]
    enc = _ours(_findings(assets["light_from_below"]))[0]
    assert (enc.severity, enc.code) == ("warning", "HighModelError")
    assert enc.data["relative_rmse"] > V.OPTIONS.model_rmse_warning
    rep = _ours(_findings(assets["replaced_texture"]))
    assert [(f.code, f.data["property"]) for f in rep] == [
        ("TextureReplaced", "ahdLightmap:texture:direction")
    ]


def _edited_copy(assets, tmp_path, edit):
    import shutil

    d = tmp_path / "copy"
    shutil.copytree(assets["clean"].parent, d)
    layer = d / MA.LAYER
    stage = Usd.Stage.Open(str(layer))
    stage.SetEditTarget(stage.GetRootLayer())
    edit(stage.GetPrimAtPath(MA.PRIM))
    stage.GetRootLayer().Save()
    return layer


def test_changed_setting_is_stale_and_named(assets, tmp_path):
    layer = _edited_copy(assets, tmp_path, lambda p: p.GetAttribute("ahdLightmap:model").Set("ahd"))
    found = _ours(_findings(layer))
    assert {f.rule for f in found} == {"Staleness"}
    assert "ahdLightmap:model ('hhd' -> 'ahd')" in found[0].message


def test_unknown_version_and_bad_resolution_are_schema_errors(assets, tmp_path):
    def edit(p):
        p.GetAttribute("ahdLightmap:baked:formatVersion").Set(7)

    found = _ours(_findings(_edited_copy(assets, tmp_path, edit)))
    assert any(f.rule == "SchemaValues" and f.code == "UnknownVersion" for f in found)

    def edit2(p):
        p.GetAttribute("ahdLightmap:baked:resolution").Set(Gf.Vec2i(0, 16))

    found = _ours(_findings(_edited_copy(assets, tmp_path / "b", edit2)))
    assert any(f.rule == "SchemaValues" and "resolution" in f.message for f in found)


def test_version_1_bake_is_rebake_needed_not_a_corrupt_texture(assets, tmp_path):
    from pxr import Sdf

    def edit(p):
        p.GetAttribute("ahdLightmap:baked:formatVersion").Set(1)
        # what a version-1 bake also carried: a 27-channel coefficients role, gone in v2
        p.CreateAttribute(
            "ahdLightmap:texture:coefficients", Sdf.ValueTypeNames.Asset, custom=False
        ).Set(Sdf.AssetPath("./lightmaps/quad.coefficients.exr"))

    layer = _edited_copy(assets, tmp_path, edit)
    found = _ours(_findings(layer))
    assert [(f.rule, f.code) for f in found] == [("SchemaValues", "RebakeNeeded")]
    assert "re-bake needed" in found[0].message and "usdahd bake --force" in found[0].message
    assert cli.main(["validate", str(layer)]) == 1


def test_packing_attribute_that_disagrees_with_the_layout_is_an_error(assets, tmp_path):
    def edit(p):
        p.GetAttribute("ahdLightmap:texture:direction:packing").Set("R=v:snorm8b G=u:snorm8b")

    found = _ours(_findings(_edited_copy(assets, tmp_path, edit)))
    assert [(f.rule, f.code) for f in found] == [("SchemaValues", "Packing")]
    assert "R=u:snorm8b G=v:snorm8b B=w_a:unorm8" in found[0].message


def test_colour_space_metadata_is_checked(assets, tmp_path):
    layer = _edited_copy(
        assets, tmp_path, lambda p: p.GetAttribute("ahdLightmap:texture:iz").SetColorSpace("raw")
    )
    found = _ours(_findings(layer))
    assert [(f.rule, f.code) for f in found] == [("Textures", "ColorSpace")]


# ------------------------------------------------------------------- numerics of the rules


def test_half_tolerance_bounds_float16_rounding():
    """FORMAT_RELATIVE_TOLERANCE["half"] bounds encode/decode error over the normal range."""
    rng = np.random.default_rng(1)
    x = np.concatenate(
        [
            10.0 ** rng.uniform(-4, 4.5, 200000),
            # worst cases: just below the midpoint between two float16 values
            (1.0 + (np.arange(1024) + 0.4999) / 1024.0) * 2.0 ** rng.integers(-14, 15, 1024),
        ]
    )
    h, s = encoding.encode_half(x)
    rel = np.abs(encoding.decode_half(h, s).astype(np.float64) - x) / x
    assert rel.max() <= 2.0**-11 * (1 + 1e-6) <= V.FORMAT_RELATIVE_TOLERANCE["half"]


def _strict_overlap_brute(uv, res, eps=1e-4):
    """Reference: texels whose centre is farther than eps texels inside the edges of two or
    more triangles (every centre against every triangle, in pixel space)."""
    w, h = res
    ys, xs = np.mgrid[0:h, 0:w]
    q = np.stack([xs + 0.5, ys + 0.5], axis=-1).reshape(-1, 2)
    px = np.stack([uv[..., 0] * w, (1.0 - uv[..., 1]) * h], axis=-1)
    count = np.zeros(len(q), np.int32)
    for p in px:
        e1, e2 = p[1] - p[0], p[2] - p[0]
        area2 = e1[0] * e2[1] - e1[1] * e2[0]
        inside = np.ones(len(q), bool)
        for i in range(3):
            a, b = p[i], p[(i + 1) % 3]
            e, r = b - a, q - a
            d = (e[0] * r[:, 1] - e[1] * r[:, 0]) * np.sign(area2) / np.linalg.norm(e)
            inside &= d > eps
        count += inside
    return np.nonzero(count >= 2)[0]


def test_uvset_overlap_is_the_bakers_statistic():
    """The UVSet rule counts with the baker's rasteriser (numerics.raster): the same covered
    texels as bake.texels.rasterize and the same overlap count the baker's unwrap decision
    (pipeline.plan._uv_problem) reads, so a UV set the baker keeps passes and one it
    re-unwraps fails."""
    from usdahd.bake import texels as tx
    from usdahd.numerics.raster import UV_OVERLAP_LIMIT
    from usdahd.pipeline.plan import _uv_problem

    rng = np.random.default_rng(2)
    res = (37, 29)
    for n in (1, 3, 40):
        uv = rng.uniform(0, 1, (n, 3, 2))
        covered, over, xy = V.overlap_statistic(uv, res)
        ref = _strict_overlap_brute(uv, res)
        assert over == len(ref) and np.array_equal(xy[:, 1] * res[0] + xy[:, 0], ref)
        pts = np.concatenate([uv.reshape(-1, 2), np.zeros((3 * n, 1))], axis=1)
        t = tx.rasterize(tx.mesh_from_arrays(pts, np.arange(3 * n).reshape(n, 3), uv=uv), res)
        assert (covered, over) == (len(t), t.stats["overlap_texels"])
        rejects = _uv_problem(t) is not None
        assert rejects == (over > UV_OVERLAP_LIMIT * covered)
        assert rejects == (n > 1)  # one triangle cannot overlap; these random ones do
    # Two triangles of a quad whose diagonal passes through texel centres: no overlap.
    quad = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    assert V.overlap_statistic(quad, (8, 8))[:2] == (64, 0)


def test_uvset_overlap_counts_on_the_overlapping_asset(assets):
    """What the switch to the baker's statistic changed (the finding itself did not): the
    validator's own top-left rasteriser counted 16 of 240 centre-covered texels; the baker's
    counts 244 covered texels (conservative: 4 edge texels more) and 12 overlapping ones (the 4
    centres on the reused cell's diagonal lie strictly inside neither triangle)."""
    (f,) = [f for f in _findings(assets["overlapping_uvs"]) if f.code == "UVOverlap"]
    assert (f.data["overlapping"], f.data["covered"]) == (12, 244)
    assert "12 of 244 covered texels" in f.message


# --------------------------------------------------------------------------------- the CLI


def test_cli_exit_codes_and_output(assets, capsys):
    assert cli.main(["validate", str(assets["clean"])]) == 0
    assert cli.main(["validate", str(assets["corrupted_iz"])]) == 1
    out = capsys.readouterr().out
    assert f"<{MA.PRIM}> IzCheck:" in out and "Fix:" in out
    # warnings pass unless --strict
    assert cli.main(["validate", str(assets["light_from_below"])]) == 0
    assert cli.main(["validate", "--strict", str(assets["light_from_below"])]) == 1
    # a looser tolerance accepts the 1% corruption
    assert cli.main(["validate", "--tolerance", "0.02", str(assets["corrupted_iz"])]) == 0
    assert V.OPTIONS.iz_tolerance is None  # restored
    assert cli.main(["validate", "--prim", MA.PRIM, str(assets["moved_light"])]) == 1
    capsys.readouterr()
    assert cli.main(["validate", "--json", str(assets["moved_light"])]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["exit_code"] == 1 and report["prims"] == [MA.PRIM]
    stale = [f for f in report["findings"] if f["rule"] == "Staleness"]
    assert stale[0]["data"]["changed"] == ["lights"]


def test_cli_errors_and_rule_list(tmp_path, capsys, assets):
    assert cli.main(["validate", str(tmp_path / "missing.usda")]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n(((\n")
    assert cli.main(["validate", str(bad)]) == 2
    assert cli.main(["validate", "--prim", "/Nope", str(assets["clean"])]) == 2
    assert "no such prim" in capsys.readouterr().err
    assert cli.main(["validate", "--list-rules"]) == 0
    out = capsys.readouterr().out
    for rule in V.RULES:
        assert f"{rule.name}" in out and rule.description in out


_PLAIN = textwrap.dedent(
    """
    import json, sys
    from pxr import Usd, UsdValidation
    reg = UsdValidation.ValidationRegistry()
    metas = list(reg.GetValidatorMetadataForKeyword("UsdAhdValidators"))
    metas += [reg.GetValidatorMetadata(n) for n in sys.argv[1].split(",")]
    assert not [m for m in sys.modules if m.split(".")[0] == "usdahd"]  # nothing imported yet
    ctx = UsdValidation.ValidationContext(metadata=metas, includeAllAncestors=False)
    out = {}
    for path in sys.argv[2:]:
        found = []
        stage = Usd.Stage.Open(path)  # keep it alive: error sites hold a weak pointer
        for e in ctx.Validate(stage):
            prims = [str(s.GetPrim().GetPath()) for s in e.GetSites() if s.GetPrim()]
            found.append([e.GetValidator().GetMetadata().name, str(e.GetName()),
                          str(e.GetType().displayName), prims, e.GetMessage()])
        out[path] = sorted(found)
    assert "usdahd.validate" in sys.modules  # loaded by Plug for the plugin, not by us
    print(json.dumps(out))
    """
)


def _plain_env():
    env = {k: v for k, v in os.environ.items() if not k.startswith("PXR_")}
    env["PXR_PLUGINPATH_NAME"] = plugin.plugin_path()
    # usdahd is importable the way an installed package is; the script never imports it.
    env["PYTHONPATH"] = str(ROOT)
    return env


def _plain_findings(paths: list[str]) -> dict:
    """Findings of a plain UsdValidation run (usdahd not imported by the caller): path -> sorted
    [validator, code, type, prims, message] rows."""
    proc = subprocess.run(
        [sys.executable, "-c", _PLAIN, ",".join(V.BUILTIN_VALIDATORS), *paths],
        env=_plain_env(),
        capture_output=True,
        text=True,
        timeout=300,
        cwd=str(ROOT),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_plain_usd_validation_gives_the_same_findings(assets):
    paths = [str(p) for p in assets.values()]
    plain = _plain_findings(paths)
    sev = {"error": "Error", "warning": "Warn", "info": "Info"}
    for p in paths:
        ours = []
        for f in _findings(Path(p)):
            name = V.validator_name(f.rule) if f.rule in V.RULE_NAMES else f.rule
            prims = [] if f.prim.startswith("@") else [f.prim]
            ours.append([name, f.code, sev[f.severity], prims, f.message])
        assert sorted(ours) == [list(x) for x in plain[p]], p


def test_plain_usd_validation_fails_a_stage_without_lightmaps(tmp_path):
    """The stage rule Lightmapped runs in any UsdValidation pipeline (usdahd not imported by the
    caller): a CI job pointed at the unbaked source stage gets an error, not a green run."""
    src = tmp_path / "source.usda"
    src.write_text('#usda 1.0\ndef Mesh "Plane" {}\n')
    found = _plain_findings([str(src)])[str(src)]
    ours = [f for f in found if f[0] == V.validator_name(V.STAGE_RULE.name)]
    assert [(f[1], f[2], f[3]) for f in ours] == [("NoAhdLightmapAPI", "Error", ["/"])]
    assert "no prim of" in ours[0][4] and "NAME.lightmaps.usda" in ours[0][4]


def test_no_lightmaps_also_with_prim_selection(tmp_path, capsys):
    """Stage validators do not run on a --prim subtree: the CLI adds the same finding once."""
    src = tmp_path / "source.usda"
    src.write_text('#usda 1.0\ndef Mesh "Plane" {}\n')
    for extra in ([], ["--prim", "/Plane"]):
        assert cli.main(["validate", "--json", *extra, str(src)]) == 1
        report = json.loads(capsys.readouterr().out)
        codes = [(f["rule"], f["code"], f["prim"]) for f in report["findings"]]
        assert codes.count((V.STAGE_RULE.name, "NoAhdLightmapAPI", "/")) == 1, codes


def test_no_lightmaps_from_the_python_api(tmp_path):
    """validate_stage and validate_file (the Python API) give the CLI's NoAhdLightmapAPI error on
    a stage without AhdLightmapAPI, for the whole stage and for a prim selection (which the
    UsdValidation stage validator does not run on), exactly once."""
    from usdahd.usd.stage import open_stage
    from usdahd.validate.run import validate_file, validate_stage

    src = tmp_path / "source.usda"
    src.write_text('#usda 1.0\ndef Mesh "Plane" {}\n')
    for prims in (None, ["/Plane"]):
        found = validate_stage(open_stage(str(src)), prims)
        assert [(f.rule, f.code, f.severity, f.prim) for f in found] == [
            (V.STAGE_RULE.name, "NoAhdLightmapAPI", "error", "/")
        ], prims
        assert "no prim of" in found[0].message and "usdahd bake" in found[0].message
        report = validate_file(str(src), prims)
        assert [f.code for f in report.findings] == ["NoAhdLightmapAPI"] and report.prims == []


def test_lightmapped_stage_has_no_no_lightmaps_finding(assets):
    from usdahd.usd.stage import open_stage
    from usdahd.validate.run import validate_stage

    layer = assets["clean"]
    stage = open_stage(str(layer))
    prim = str(next(iter(V.schema.prims_with_api(stage))).GetPath())
    for prims in (None, [prim]):
        assert not any(f.code == "NoAhdLightmapAPI" for f in validate_stage(stage, prims))


def test_module_entry_point_subprocess(assets):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PXR_PLUGINPATH_NAME", None)
    codes = {}
    for key in ("clean", "moved_light"):
        proc = subprocess.run(
            [sys.executable, "-m", "usdahd", "validate", "--quiet", str(assets[key])],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        codes[key] = (proc.returncode, proc.stdout)
    assert codes["clean"] == (0, "")
    assert codes["moved_light"][0] == 1 and "Staleness" in codes["moved_light"][1]


# ------------------------------------------------------------------------- real bakes

# A fresh bake of every sample validating clean is tested in tests/test_bake.py.


# ------------------------------------------------------------- IzCheck: derived tolerance


def _sensitivities(bake):
    """(n, channels, 3) |I(z; code + 1 step) - I(z)| (max of both sides) per stored channel."""
    base = V.decoded_iz(bake, bake.channels)
    out, where = [], []
    for role, codes in bake.channels.items():
        for j, code in enumerate(bake.layout[role].codes):
            if code == "reserved":
                continue
            worst = np.zeros_like(base)
            for up in (True, False):
                moved = dict(bake.channels)
                c = codes.copy()
                c[:, j] = V.code_step(codes[:, j], up)
                moved[role] = c
                worst = np.maximum(worst, np.abs(V.decoded_iz(bake, moved) - base))
            out.append(worst)
            where.append((role, j))
    return np.stack(out, axis=1), where


VARIANTS = [(m, r) for m in V.models.names() for r in V.models.get(m).RATIOS]


@pytest.mark.parametrize("variant", VARIANTS, ids=[f"{m}-{r}" for m, r in VARIANTS])
def test_iz_tolerance_is_the_quantization_and_one_flipped_code_is_caught(tmp_path, variant):
    """Clean right after the bake; one code moved by one step (the next float16 or 8-bit code,
    away from the reference) in the texel channel that carries most of the texel's
    quantization budget is an IzMismatch naming that texel."""
    model, ratio = variant
    layer = MA.bake(tmp_path / "b", model=model, ratio=ratio, seed=5)
    stage = Usd.Stage.Open(str(layer))
    prim = stage.GetPrimAtPath(MA.PRIM)
    (clean,) = V.check_iz(prim)
    assert clean.code == "IzOk" and clean.data["worst_error_over_tolerance"] <= 1.0
    bake = V.load_bake(prim)
    sens, where = _sensitivities(bake)
    # The documented bound: half a step per channel, summed (plus TOLERANCE_SLACK).
    tol = V.quantization_tolerance(bake)
    np.testing.assert_allclose(tol, 0.5 * sens.sum(axis=1) * (1 + V.TOLERANCE_SLACK), rtol=1e-9)
    # Share of one channel in a texel colour's quantization budget at z.
    share = sens / np.maximum(sens.sum(axis=1, keepdims=True), 1e-300)
    texel, k, colour = np.unravel_index(np.argmax(share), share.shape)
    assert share[texel, k, colour] > 0.55, f"{variant}: no channel dominates I(z) anywhere"
    role, j = where[k]
    ref_err = V.decoded_iz(bake, bake.channels)[texel] - _reference(bake)[texel]
    x, y = (int(v) for v in bake.xy[texel])
    img = V.read_image(bake.results.textures[role])
    name = bake.layout[role].channels[j]
    for up in (True, False):
        moved = dict(bake.channels)
        c = bake.channels[role].copy()
        c[texel, j] = V.code_step(c[texel : texel + 1, j], up)[0]
        moved[role] = c
        if np.sign(
            V.decoded_iz(bake, moved)[texel, colour]
            - V.decoded_iz(bake, bake.channels)[texel, colour]
        ) == np.sign(ref_err[colour] or 1.0):
            break
    path = Path(bake.results.textures[role])

    ox, oy = bake.results.rect()[:2] if bake.results.atlas else (0, 0)  # in its atlas page

    def flip(a):
        a[y + oy, x + ox, list(img.channel_names).index(name)] = c[texel, j]
        return a

    recorded = bake.results.digests[role]
    MA._edit_image(path, flip)  # re-records the digest: a bake that wrote one bad code
    V.clear_caches()
    stage = Usd.Stage.Open(str(layer))
    prim = stage.GetPrimAtPath(MA.PRIM)
    (found,) = V.check_iz(prim)
    assert found.code == "IzMismatch" and found.data["failing"] == 1, found.message
    assert tuple(found.data["worst_texel"]) == (x, y)
    # The same flip behind the layer's back (digest as baked): Textures names the file, for
    # any code, also those I(z) cannot see.
    prim.GetAttribute(V.schema.digest_property_name(role)).Set(recorded)
    codes = [f.code for f in V.check_textures(prim) if f.severity == "error"]
    assert codes == ["TextureReplaced"]


def _reference(bake):
    z = np.broadcast_to([0.0, 0.0, 1.0], bake.sh.shape[:-2] + (3,))
    res = bake.results
    if res.model in V.IRRADZ:
        return np.maximum(V.shm.iz(bake.sh), 0.0)
    fitted = V.models.fit(bake.sh, res.model, ratio=res.ratio, solver=res.solver or None)
    return bake.mod.evaluate(V.models.representable(fitted, bake.mod), z).astype(np.float64)


def test_rules_reading_the_bake_say_why_they_skip():
    """IzCheck, EncodingError and TexelValues load the bake through one helper
    (validate.loading.load_for): an unbaked prim gives each the same info finding."""
    from pxr import UsdGeom

    from usdahd.usd import schema

    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.Mesh.Define(stage, "/Quad").GetPrim()
    schema.apply(prim)
    for rule, check in (
        ("IzCheck", V.check_iz),
        ("EncodingError", V.check_encoding_error),
        ("TexelValues", V.check_texel_values),
    ):
        (f,) = check(prim)
        assert (f.rule, f.severity, f.code) == (rule, "info", "Skipped")
        assert f.message == f"{rule} did not run: the prim is not baked; see SchemaValues."
