"""`usdahd fit` options beyond those tested with the models."""

import json
from pathlib import Path

import pytest

from usdahd import cli

SKY = str(Path(__file__).resolve().parents[2] / "samples" / "sh" / "sky_sun.npy")


def _report(capsys, *argv):
    assert cli.main(["fit", SKY, "--json", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def test_objective_rgb_lowers_the_rgb_error_of_a_luminance_ratio(capsys):
    lum = _report(capsys, "--model", "hhd")
    rgb = _report(capsys, "--model", "hhd", "--objective", "rgb")
    # The report's error is the summed RGB hemispherical error, what objective=rgb minimises.
    assert rgb["relative_rmse_mean"] < lum["relative_rmse_mean"]
    assert rgb["params"] == lum["params"]


def test_objective_on_a_model_without_it_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["fit", SKY, "--objective", "bogus"])
    assert exc.value.code == 2
    code = cli.main(["fit", SKY, "--model", "hlsh", "--objective", "rgb"])
    assert code == 2
    assert "objective" in capsys.readouterr().err
