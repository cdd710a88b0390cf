"""Consistent advice (issue 41): EncodingError never recommends the model in use, recommends only
models it measured to fit closer, and a decode whose error is as large as the irradiance itself
is a warning, not a note (docs/validate.md, Thresholds).

Synthetic bakes (tests/data/validate/make_assets.py) with chosen radiance SH: texels lit from
below their tangent plane decode black with every IrradZ model (relative RMSE 1.2-1.4).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from usdahd import cli
from usdahd import validate as V
from usdahd.validate import irradiance

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "data" / "validate"))
import make_assets as MA  # noqa: E402


def from_below(share: float):
    """sh_fn: a ``share`` of the texels lit from below their tangent plane, the others by the
    usual hemispherical lighting."""

    def fn(n, rng):
        sh = MA.hemispherical_sh(n, rng)
        pick = np.nonzero(rng.uniform(size=n) < share)[0]
        sh[pick] = MA.below_horizon_sh(len(pick), rng)
        return sh

    return fn


def _encoding(layer: Path) -> list[V.Finding]:
    V.clear_caches()
    stage = Usd.Stage.Open(str(layer))
    return V.check_encoding_error(stage.GetPrimAtPath(MA.PRIM))


def _advised(message: str) -> list[str]:
    """Model names the message says fit closer."""
    m = re.search(r"of these texels \(\w+ [^)]*\): (.*?) fits? closer", message)
    return re.findall(r"(\w+) \(", m.group(1)) if m else []


def test_light_from_below_is_a_warning_with_measured_advice(tmp_path, capsys):
    layer = MA.bake(tmp_path / "b", model="hhd", sh_fn=from_below(1.0))
    (f,) = _encoding(layer)
    assert (f.severity, f.code) == ("warning", "HighModelError"), f.message
    assert f.data["relative_rmse"] > 1.0  # e.g. 1.3: as bad as a black lightmap
    assert f.data["below_horizon_texels"] == f.data["texels"]
    assert "decodes black" in f.message and "Fix:" in f.message
    assert _advised(f.message) == ["sh_l2"]  # measured, and never hhd itself
    # A warning: exit 0, 1 with --strict (the text line says what to do).
    assert cli.main(["validate", str(layer)]) == 0
    assert "warning </World/Quad> EncodingError: " in capsys.readouterr().out
    assert cli.main(["validate", "--strict", str(layer)]) == 1
    capsys.readouterr()


@pytest.mark.parametrize("model", V.models.names())
def test_advice_never_names_the_model_in_use(tmp_path, model):
    """Every model, with lighting it fits loosely (a fifth of the texels lit from below):
    whatever the note or warning advises is measured closer and is not the bake's model."""
    layer = MA.bake(tmp_path / "b", model=model, sh_fn=from_below(0.2), seed=3)
    found = _encoding(layer)
    for f in found:
        advised = _advised(f.message)
        assert model not in advised, f.message
        for name in advised:
            figure = float(re.search(rf"{name} \(([0-9.e+-]+)\)", f.message).group(1))
            own = float(re.search(rf"\({model} ([0-9.e+-]+)\)", f.message).group(1))
            assert figure < irradiance.ADVICE_FRACTION * own
        if f.severity == "info" and f.data.get("model_rmse", 0) <= V.MODEL_RMSE_NOTE:
            assert "loosely" not in f.message and not advised
    if model == "sh_l2":  # represents the L2 irradiance exactly: nothing fits closer
        assert [(f.severity, f.code) for f in found] == [("info", "EncodingError")]
        assert not _advised(found[0].message)


def test_note_thresholds(tmp_path):
    """A clean bake: a note without advice; a loose fit below 1: a note that names only
    measured closer models; the warning starts above OPTIONS.model_rmse_warning."""
    clean = _encoding(MA.bake(tmp_path / "clean", model="hhd"))
    assert [(f.severity, f.code) for f in clean] == [("info", "EncodingError")]
    assert "loosely" not in clean[0].message
    loose = _encoding(MA.bake(tmp_path / "loose", model="hl2", seed=1))
    (f,) = loose
    assert V.MODEL_RMSE_NOTE < f.data["model_rmse"] and f.data["relative_rmse"] < 1.0, f.data
    assert f.data["texel_share_above_warning"] <= V.OPTIONS.model_texel_share
    assert f.severity == "info" and "fits this lighting loosely" in f.message
    assert _advised(f.message) == ["sh_l2", "hhd"]
    # A fifth of the texels lit from below: the prim figure stays small (they are dim), but
    # every one of them is shaded worse than black, which is more than 5% of the texels.
    (w,) = _encoding(MA.bake(tmp_path / "below", model="hhd", sh_fn=from_below(0.2), seed=1))
    assert w.data["relative_rmse"] < 1.0 < 0.05 / w.data["texel_share_above_warning"] * 100
    assert (w.severity, w.code) == ("warning", "HighModelError"), w.message
