"""usdahd/pipeline/settings.py: a ratio or solver the model does not offer is refused with
the name the user gave it (flag or schema input), through the one check in usdahd.models."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd import models
from usdahd.errors import ModelError, UsageError
from usdahd.pipeline.settings import BakeOptions, _check_options, resolve_settings


def test_flags_the_model_lacks_are_named_as_flags():
    with pytest.raises(UsageError, match=r"^model 'sh_l2' supports --ratio none, not 'rgb'$"):
        _check_options(BakeOptions(model="sh_l2", ratio="rgb"))
    with pytest.raises(UsageError, match=r"^model 'hl2' has --solver hemisphere, not 'golden'$"):
        _check_options(BakeOptions(model="hl2", solver="golden"))
    with pytest.raises(UsageError, match=r"^model 'sh_l2' supports --ratio none, not 'rgb'$"):
        resolve_settings(BakeOptions(model="sh_l2", ratio="rgb"), {})
    _check_options(BakeOptions(model="hhd", ratio="rgb", solver="direct"))  # offered: no error


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

    from usdahd.pipeline.settings import DEFAULTS, _authored_inputs
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
    authored = _authored_inputs(prim)
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
