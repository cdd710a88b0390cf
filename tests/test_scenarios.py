"""Lighting scenarios (usdahd.usd.scenarios): naming a variant, selecting it without touching the
source, authoring it into an override layer, finding the scenarios of a folder (issue 13)."""

from __future__ import annotations

from pathlib import Path

import pytest

import usdahd.usd  # noqa: F401  (registers the plugins first)
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
    out = S.default_output(Path(stage.GetRootLayer().realPath), night)
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
