"""Lighting scenarios (usdahd.usd.scenarios): naming a variant, selecting it without touching the
source, authoring it into an override layer, finding the scenarios of a folder (issue 13)."""

from __future__ import annotations

from pathlib import Path

import pytest

import usdahd.usd  # noqa: F401  (registers the plugins first)
from tests.scenes import baked_mean_iz
from usdahd.errors import UsageError
from usdahd.usd import scenarios as S

STAGE = """#usda 1.0
(
    defaultPrim = "World"
)

def Xform "World" (
    variants = {
        string lighting = "day"
    }
    prepend variantSets = "lighting"
)
{
    def Mesh "Ground"
    {
    }
    variantSet "lighting" = {
        "day" {
            def DistantLight "Sun"
            {
                float inputs:intensity = 3
            }
        }
        "night" {
            def SphereLight "Lamp"
            {
                float inputs:intensity = 10
            }
        }
    }
}

def Xform "Props" (
    prepend variantSets = ["lamps", "look"]
)
{
    variantSet "lamps" = {
        "night" {
        }
        "off" {
        }
    }
    variantSet "look" = {
        "worn" {
        }
    }
}
"""


@pytest.fixture
def stage(tmp_path):
    from pxr import Usd

    path = tmp_path / "scene.usda"
    path.write_text(STAGE)
    return Usd.Stage.Open(str(path))


def test_resolve_every_spelling(stage):
    night = S.Scenario("/World", "lighting", "night")
    assert S.resolve(stage, "/World{lighting=night}") == night
    assert S.resolve(stage, "lighting=night") == night
    assert S.resolve(stage, "day") == S.Scenario("/World", "lighting", "day")
    assert S.resolve(stage, "off") == S.Scenario("/Props", "lamps", "off")
    assert night.spec() == "/World{lighting=night}" and night.name == "night"


@pytest.mark.parametrize(
    "text, expect",
    [
        ("night", "is ambiguous: /World{lighting=night}, /Props{lamps=night}"),
        ("dusk", "no variant 'dusk'; the stage's variants: /World{lighting=day}"),
        ("lighting=off", "no variant 'off' in a variant set 'lighting'"),
        ("/Props{lighting=day}", "no variant 'day' in a variant set 'lighting' on /Props"),
        ("../x", "a scenario is a variant name of letters, digits"),
        ("", "a scenario is a variant name"),
    ],
)
def test_bad_scenarios_name_the_flag_the_choices_and_the_fix(stage, text, expect):
    with pytest.raises(UsageError) as e:
        S.resolve(stage, text)
    msg = str(e.value)
    assert msg.startswith(f"--scenario {text!r}") and expect in msg
    assert "Fix:" in msg or "give NAME" in msg


def test_no_variant_sets(tmp_path):
    from pxr import Usd

    st = Usd.Stage.CreateInMemory()
    st.DefinePrim("/A")
    with pytest.raises(UsageError, match="the stage has no variant sets"):
        S.resolve(st, "night")


def test_select_uses_the_session_layer_only(stage):
    root_text = stage.GetRootLayer().ExportToString()
    S.select(stage, S.resolve(stage, "lighting=night"))
    assert stage.GetPrimAtPath("/World/Lamp") and not stage.GetPrimAtPath("/World/Sun")
    assert stage.GetRootLayer().ExportToString() == root_text
    assert not stage.GetRootLayer().dirty


def test_override_layer_composes_the_scenario_and_records_it(stage, tmp_path):
    from pxr import Sdf, Usd

    night = S.resolve(stage, "lighting=night")
    out = S.default_output(Path(stage.GetRootLayer().realPath), night.name)
    assert [S.name_of(t) for t in ("night", "lighting=night", "/World{lighting=night}")] == [
        "night"
    ] * 3
    assert out.name == "scene.night.lightmaps.usda"
    assert S.default_output(Path("a/scene.usda"), None) == Path("a/scene.lightmaps.usda")
    layer = Sdf.Layer.CreateNew(str(out))
    layer.subLayerPaths.append("./scene.usda")
    S.author(layer, night)
    layer.Save()
    composed = Usd.Stage.Open(str(out))
    assert composed.GetPrimAtPath("/World/Lamp") and not composed.GetPrimAtPath("/World/Sun")
    assert composed.GetPrimAtPath("/World").GetSpecifier() == Sdf.SpecifierDef  # still a def
    assert S.of_layer(Sdf.Layer.FindOrOpen(str(out))) == night
    # a plain layer beside it is not a scenario; the folder lists the one scenario
    (tmp_path / "other.lightmaps.usda").write_text("#usda 1.0\n")
    (tmp_path / "broken.lightmaps.usda").write_text("not usd")
    assert S.list_layers(tmp_path) == {"night": out}


# ------------------------------------------------------------------- bake --scenario end to end

FAST = ["--resolution", "8", "--samples", "16", "--bounces", "0", "--quiet"]


def _lights(intensity: float) -> str:
    return (
        '            def Xform "Lights"\n            {\n'
        '                def DomeLight "UniformSky"\n                {\n'
        f"                    float inputs:intensity = {intensity}\n"
        "                    bool inputs:normalize = 0\n                }\n            }\n"
    )


def _scenario_stage(tmp_path: Path) -> Path:
    """samples/open_plane.usda (I_z = 1 under its uniform dome) with the dome moved into a
    ``lighting`` variant set on /World: day = intensity 1, night = 0.25."""
    text = (Path(__file__).resolve().parents[2] / "samples" / "open_plane.usda").read_text()
    start = text.index('    def Xform "Lights"')
    end = text.index('    def Scope "Looks"')
    base = tmp_path / "base.usda"
    base.write_text(text[:start] + text[end:])
    stage = tmp_path / "level.usda"
    stage.write_text(
        '#usda 1.0\n(\n    defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Y"\n'
        '    subLayers = [@./base.usda@]\n)\n\nover "World" (\n'
        '    variants = {\n        string lighting = "day"\n    }\n'
        '    prepend variantSets = "lighting"\n)\n{\n    variantSet "lighting" = {\n'
        '        "day" {\n' + _lights(1.0) + "        }\n"
        '        "night" {\n' + _lights(0.25) + "        }\n    }\n}\n"
    )
    return stage


_iz = baked_mean_iz


def test_bake_two_scenarios_into_one_folder(tmp_path, capsys):
    import json

    from pxr import Usd

    from usdahd import cli
    from usdahd.usd import schema

    stage = _scenario_stage(tmp_path)
    before = {p.name: p.read_bytes() for p in (tmp_path / "level.usda", tmp_path / "base.usda")}
    assert cli.main(["bake", str(stage), "--scenario", "day", *FAST]) == 0
    capsys.readouterr()
    assert cli.main(["bake", str(stage), "--scenario", "lighting=night", "--json", *FAST]) == 0
    report = json.loads(capsys.readouterr().out)
    day, night = tmp_path / "level.day.lightmaps.usda", tmp_path / "level.night.lightmaps.usda"
    assert report["output"] == str(night) and report["scenario"] == "/World{lighting=night}"
    assert {p.name: p.read_bytes() for p in (tmp_path / "level.usda", tmp_path / "base.usda")} == (
        before
    )
    # each layer keeps its own lighting (I_z = dome radiance: 1 and 0.25, no bounce)
    assert abs(_iz(day) - 1.0) < 0.02 and abs(_iz(night) - 0.25) < 0.005
    # each layer composes the lighting it was baked with, and records it
    st = Usd.Stage.Open(str(night))
    light = st.GetPrimAtPath("/World/Lights/UniformSky")
    assert light.GetAttribute("inputs:intensity").Get() == 0.25
    assert S.of_layer(st.GetRootLayer()) == S.Scenario("/World", "lighting", "night")
    (prim,) = schema.prims_with_api(st)
    assert schema.read_results(prim).settings["scenario"] == "/World{lighting=night}"
    assert S.list_layers(tmp_path) == {"day": day, "night": night}
    # both validate clean (Staleness recomputes each scenario's own scene hash)
    for layer in (day, night):
        assert cli.main(["validate", "--quiet", "--strict", str(layer)]) == 0, layer
    # switching the variant in the night layer makes it stale: the lights differ from the bake
    st.GetRootLayer().GetPrimAtPath("/World").variantSelections["lighting"] = "day"
    st.GetRootLayer().Save()
    assert cli.main(["validate", "--quiet", str(night)]) == 1
    assert "Staleness" in capsys.readouterr().out


def test_bad_scenario_fails_before_tracing(tmp_path, capsys):
    stage = _scenario_stage(tmp_path)
    from usdahd import cli

    for text, expect in [
        ("dusk", "no variant 'dusk'; the stage's variants: /World{lighting=day}"),
        ("../up", "a scenario is a variant name"),
    ]:
        assert cli.main(["bake", str(stage), "--scenario", text, *FAST]) == 2
        err = capsys.readouterr().err
        assert expect in err and "Traceback" not in err
    assert not list(tmp_path.glob("*.lightmaps.usda")) and not (tmp_path / "lightmaps").exists()


def test_scenario_bake_as_a_subprocess(tmp_path):
    import subprocess
    import sys

    stage = _scenario_stage(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), "--scenario", "night", *FAST],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "level.night.lightmaps.usda").is_file()
