"""``usdahd warmup`` (issue 16): compiles or loads every kernel a bake uses; afterwards a new
process (the next bake) finds all of them in numba's on-disk cache and compiles nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from usdahd import cli, models

REPO = Path(__file__).resolve().parents[2]

#: The kernels every default bake runs (tracing, rasterising, the default model's fit).
BAKE_KERNELS = {
    "usdahd.bake.kernels.integrate.native_pass",
    "usdahd.bake.kernels.integrate.native_result",
    "usdahd.bake.kernels.embree.intersect_batch",
    "usdahd.models.irradz.kernel._fit_kernel",
    "usdahd.numerics.noise._tile_stats_numba",
    "usdahd.numerics.noise._bends_numba",
    "usdahd.numerics.windows._box_mean_texels_numba",
    "usdahd.numerics.windows._neighbour_mean_numba",
    "usdahd.bake.blend._blend_chart_numba",
    "usdahd.numerics.cholesky._chol",
    "usdahd.numerics.cholesky._solve",
}


def test_warmup_in_process_then_a_new_process_compiles_nothing(capsys):
    assert cli.main(["warmup", "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["command"] == "warmup" and first["exit_code"] == 0
    ready = set(first["compiled"]) | set(first["loaded"])
    assert BAKE_KERNELS <= ready, BAKE_KERNELS - ready
    # every model, ratio and solver was fitted once
    expected = [
        f"{n}/{r}/{s}" for n in models.names() for r in models.get(n).RATIOS
        for s in models.get(n).SOLVERS
    ]  # fmt: skip
    assert first["fits"] == expected

    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    )
    out = subprocess.run(
        [sys.executable, "-m", "usdahd", "warmup", "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=True,
    )
    second = json.loads(out.stdout)
    assert second["compiled"] == [], "these kernels are not cached: " + ", ".join(
        second["compiled"]
    )
    assert BAKE_KERNELS <= set(second["loaded"])


def test_warmup_text_output_says_what_it_did(capsys):
    assert cli.main(["warmup"]) == 0
    out = capsys.readouterr().out
    # after the test above (or any earlier run) everything comes from the cache
    assert out.startswith("usdahd warmup: ")
    assert "kernels" in out and ("compiled" in out or "loaded from numba's cache" in out)


def test_warmup_in_one_process_reports_the_same_kernels(capsys):
    assert cli.main(["warmup", "--json", "--jobs", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["jobs"] == 1 and report["second_process_seconds"] is None
    assert BAKE_KERNELS <= set(report["compiled"]) | set(report["loaded"])
    assert 0 < report["bake_seconds"] <= report["seconds"]


def test_warmup_jobs_out_of_range_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["warmup", "--jobs", "3"])
    assert exc.value.code == 2
    assert "--jobs" in capsys.readouterr().err
