"""usdahd/pipeline/settings.py: a ratio or solver the model does not offer is refused with
the name the user gave it (flag or schema input), through the one check in usdahd.models."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd import models
from usdahd.errors import ModelError, UsageError
from usdahd.pipeline.settings import BakeOptions, check_options, resolve_settings


def test_flags_the_model_lacks_are_named_as_flags():
    with pytest.raises(UsageError, match=r"^model 'sh_l2' supports --ratio none, not 'rgb'$"):
        check_options(BakeOptions(model="sh_l2", ratio="rgb"))
    with pytest.raises(UsageError, match=r"^model 'hl2' has --solver hemisphere, not 'golden'$"):
        check_options(BakeOptions(model="hl2", solver="golden"))
    with pytest.raises(UsageError, match=r"^model 'sh_l2' supports --ratio none, not 'rgb'$"):
        resolve_settings(BakeOptions(model="sh_l2", ratio="rgb"), {})
    check_options(BakeOptions(model="hhd", ratio="rgb", solver="direct"))  # offered: no error


def test_an_authored_ratio_the_model_lacks_falls_back_and_a_solver_is_refused():
    s = resolve_settings(BakeOptions(model="sh_l2"), {"ratio": "luminance"})
    assert s["ratio"] == "none"  # the schema fallback "luminance" on an SH model
    with pytest.raises(UsageError, match=r"^model 'hhd' has solvers golden, .*, not 'bogus'$"):
        resolve_settings(BakeOptions(model="hhd"), {"solver": "bogus"})


def test_fit_and_the_models_use_the_default_wording():
    sh = np.zeros((2, 3, 9))
    with pytest.raises(ModelError, match=r"^model 'hhd' supports ratio luminance, rgb, not 'x'$"):
        models.fit(sh, "hhd", ratio="x")
    with pytest.raises(ModelError, match=r"^model 'sh_l2' has solvers project, not 'x'$"):
        models.get("sh_l2").fit(sh, solver="x")
    assert models.choice_problem("hhd", "ratio", "rgb", ("luminance", "rgb")) is None
    text = "baked ratio {value!r} is not a ratio type of model {model!r} ({allowed})"
    assert models.choice_problem("m", "ratio", "q", ("a", "b"), text) == (
        "baked ratio 'q' is not a ratio type of model 'm' (a, b)"
    )


def test_one_setting_name_map_for_the_baker_and_the_staleness_rule():
    """usd.schema.SETTING_KEYS maps every bake input but ``bake`` to its settings-record key:
    the baker applies authored inputs through it and the validator compares them with the
    record through it, so an authored input the bake used never reads as drift."""
    from pxr import Usd, UsdGeom

    from usdahd.pipeline.settings import DEFAULTS, authored_inputs
    from usdahd.usd import schema
    from usdahd.validate.staleness import settings_drift

    assert set(schema.SETTING_KEYS) == set(schema.INPUT_KEYS) - {"bake"}
    assert set(schema.SETTING_KEYS.values()) <= set(DEFAULTS)
    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.Mesh.Define(stage, "/Quad").GetPrim()
    schema.apply(prim)
    schema.write_inputs(
        prim,
        model="sh_l2",
        ratio="none",
        solver="project",
        uv_primvar="lm",
        resolution=64,
        texel_density=8.0,
        samples=32,
        bounces=3,
    )
    authored = authored_inputs(prim)
    assert set(authored) == set(schema.SETTING_KEYS.values())
    assert authored["uv"] == "lm"
    settings = resolve_settings(BakeOptions(), authored)
    settings["resolution"] = [64, 64]  # the record holds (w, h) (pipeline.plan)
    assert settings_drift(prim, settings) == []
    settings.update(uv="st", samples=256)
    assert settings_drift(prim, settings) == [
        "ahdLightmap:uvPrimvar ('st' -> 'lm')",
        "ahdLightmap:samples (256 -> 32)",
    ]


def test_settings_drift_reads_a_hand_edited_record_of_the_wrong_type():
    """A settings record edited by hand (resolution stored as a plain int, a density as a
    string) is compared, not a TypeError/ValueError: an int resolution equal to the authored
    one is no drift; a value that cannot be the input's reads as drift naming that value."""
    from pxr import Usd, UsdGeom

    from usdahd.pipeline.settings import authored_inputs
    from usdahd.usd import schema
    from usdahd.validate.staleness import settings_drift

    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.Mesh.Define(stage, "/Quad").GetPrim()
    schema.apply(prim)
    schema.write_inputs(prim, resolution=64, samples=32)
    settings = resolve_settings(BakeOptions(), authored_inputs(prim))
    settings["resolution"] = 64
    assert settings_drift(prim, settings) == []
    settings["resolution"] = "64x64"
    settings["samples"] = None
    assert sorted(settings_drift(prim, settings)) == [
        "ahdLightmap:resolution ('64x64' -> 64)",
        "ahdLightmap:samples (None -> 32)",
    ]

    dense = UsdGeom.Mesh.Define(stage, "/Dense").GetPrim()
    schema.apply(dense)
    schema.write_inputs(dense, texel_density=8.0)
    settings = resolve_settings(BakeOptions(), authored_inputs(dense))
    settings["texel_density"] = "eight"
    assert settings_drift(dense, settings) == ["ahdLightmap:texelDensity ('eight' -> 8.0)"]
    settings["texel_density"] = [8.0]
    assert settings_drift(dense, settings) == ["ahdLightmap:texelDensity ([8.0] -> 8.0)"]
