"""Smoke tests of the benchmark's cheapest pieces (benchmarks/run.py), in-process.

The soak runs every model on a few hundred adversarial texels; the invariant is the one the
full soak reports: no NaN/Inf anywhere in fit -> encode -> decode -> evaluate.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import common  # noqa: E402
import encoding_bench  # noqa: E402
import soak  # noqa: E402

from usdahd import models  # noqa: E402
from usdahd.commands import bench as bench_cmd  # noqa: E402
from usdahd.errors import UsageError  # noqa: E402

SOAK_TEXELS = 100  # per category


@pytest.fixture(scope="module")
def soak_data():
    return {cat: soak.texels(cat, SOAK_TEXELS, seed=7) for cat in soak.CATEGORIES}


def _variant_params():
    out = []
    for model, ratio in common.variants():
        out.append(pytest.param(model, ratio, id=f"{model}-{ratio}"))
    return out


@pytest.mark.parametrize(("model", "ratio"), _variant_params())
def test_soak_is_finite(soak_data, model, ratio):
    data = {c: x for c, x in soak_data.items() if c != "beyond float32"}
    row = soak.run_variant(model, ratio, data)
    assert row["texels"] == SOAK_TEXELS * len(data)
    assert row["nonfinite_total"] == 0, row["nonfinite_where"]
    # I(z) == I_z before quantization holds exactly for the IrradZ models (float32 rounding).
    if model in ("ahd", "hhd", "hlsh"):
        assert row["iz_worst_exact"] < 1e-6


@pytest.mark.parametrize(("model", "ratio"), _variant_params())
def test_soak_beyond_float32_is_finite(soak_data, model, ratio):
    row = soak.run_variant(model, ratio, {"beyond float32": soak_data["beyond float32"]})
    assert row["nonfinite_total"] == 0, row["nonfinite_where"]


def test_soak_categories_are_what_they_say():
    phys = soak.texels("physical", 200)
    # non-negative hemispherical radiance: I_z >= 0 in every channel
    assert (common.shm.iz(phys) >= 0).all()
    assert soak.texels("float16 input", 10).dtype == np.float16
    bad = soak.texels("NaN/Inf", 200)
    assert (~np.isfinite(bad)).any(axis=(1, 2)).mean() > 0.5


def test_soak_table_has_a_row_per_variant():
    variants = [("hhd", "luminance"), ("sh_l2", "none")]
    result = soak.soak(90, variant_list=variants)
    table = soak.soak_markdown(result)
    assert len(result["rows"]) == 2
    assert table.count("\n") == 1 + len(variants)  # header, rule, one line per row


def test_one_fit_row():
    fams = {
        "sky+sun": encoding_bench.envs.sky_sun(64),
        "black": np.zeros((16, 3, 9)),
    }
    result = encoding_bench.fit_table(
        fams, speed_texels=6000, repeats=1, cases=[("hhd", "luminance", "golden")]
    )
    (row,) = result["rows"]
    assert row["texels_per_s"] > 0 and np.isfinite(row["texels_per_s"])
    assert 0 <= row["errors"]["sky+sun"] < 1
    assert row["errors"]["black"] == 0
    assert "hhd" in encoding_bench.fit_markdown(result)


def test_hemi_errors_zero_for_exact_model():
    # sh_l2 stores the band-2 irradiance SH itself: its only error is float32 rounding.
    sh = encoding_bench.envs.sky_sun(32)
    p = models.fit(sh, "sh_l2").params
    err, energy = common.hemi_errors("sh_l2", p, sh)
    agg, per = common.relative_rmse(err, energy)
    assert agg < 1e-6 and per < 1e-6


def test_bytes_per_texel_follows_layout():
    # hhd luminance: I_z half RGB (6) + direction (u, v, w_a) unorm8 RGB (3)
    assert common.bytes_per_texel("hhd", "luminance") == 9
    assert common.bytes_per_texel("sh_l2", "none") == 27 * 2


def test_md_table_and_fmt():
    t = common.md_table(["a", "b"], [["x", 1.5], ["y", float("nan")]])
    assert t.splitlines()[2] == "| x | 1.5 |"
    assert "nan" in t.splitlines()[3]


def test_bench_command_imports_the_installed_harness():
    """``usdahd bench`` imports the installed usdahd-bench package (benchmarks/pyproject.toml),
    whose files are this checkout's benchmarks/ (an editable install)."""
    import importlib.metadata

    runner = bench_cmd.load_runner()
    assert runner.__name__ == "benchmarks.run"
    assert Path(runner.__file__).resolve() == REPO / "benchmarks" / "run.py"
    assert importlib.metadata.distribution(bench_cmd.HARNESS).metadata["Name"] == "usdahd-bench"


def test_bench_command_without_the_harness_names_the_install_command(tmp_path, capsys):
    """Without the harness installed, ``usdahd bench`` is a usage error (exit 2, also as JSON)
    naming the install command, in-process and as a subprocess; it never falls back to a
    checkout's files found by path. The subprocess runs outside the checkout with the
    ``benchmarks`` import blocked (``sys.modules`` entry None: Python's own way to make an
    import fail), as on a machine where only usdahd is installed."""
    import json
    import subprocess

    from usdahd import cli

    with pytest.raises(UsageError, match=r"pip install -e benchmarks/"):
        bench_cmd.load_runner("benchmarks.no_such_runner")
    with pytest.MonkeyPatch.context() as mp:  # in-process: the harness's import blocked
        mp.setitem(sys.modules, "benchmarks", None)
        mp.setitem(sys.modules, "benchmarks.run", None)
        assert cli.main(["bench", "--quick", "--json"]) == 2
    cap = capsys.readouterr()
    assert "pip install -e benchmarks/" in json.loads(cap.out)["error"]
    assert "usdahd bench: error: usdahd bench runs the benchmark harness" in cap.err
    code = (
        "import sys; sys.modules['benchmarks'] = None; from usdahd import cli; "
        "sys.exit(cli.main(sys.argv[1:]))"
    )
    for argv in (["bench", "--quick"], ["bench", "--quick", "--json"]):
        proc = subprocess.run(
            [sys.executable, "-c", code, *argv], capture_output=True, text=True, cwd=tmp_path
        )
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr
        text = json.loads(proc.stdout)["error"] if "--json" in argv else proc.stderr
        assert "usdahd-bench, which is not installed" in text
        assert "pip install -e benchmarks/" in text
    assert not list(tmp_path.iterdir())  # nothing written


def test_bench_command_reports_a_missing_dependency_of_the_harness_as_itself(tmp_path, monkeypatch):
    """A harness that is installed but lacks one of its own imports is not "not installed": the
    ModuleNotFoundError names the missing module."""
    (tmp_path / "harness_runner_x.py").write_text("import usdahd_no_such_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError, match="usdahd_no_such_dependency"):
        bench_cmd.load_runner("harness_runner_x")


def test_bench_unknown_section(tmp_path):
    runner = bench_cmd.load_runner()
    args = runner.parse_args(["--sections", "nope", "--out", str(tmp_path / "b.md")])
    with pytest.raises(UsageError, match="unknown --sections"):
        runner.run(args)


def test_run_names_an_unknown_reference_stage_before_any_work(capsys):
    """``--reference-stages`` takes file stems; a wrong one is a usage error listing the
    choices, raised before the first section starts (the full run takes hours)."""
    import run as bench_run

    assert bench_run.main(["--sections", "reference", "--reference-stages", "nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown reference stage nope; choose from cornell_box, pillar_room" in err
    assert "section" not in err.split("error:")[0]  # nothing ran before the message
    assert bench_run.main(["--sections", "fit", "--reference-stages", "cornell_box"]) == 2
    assert "--sections fit leaves that section out; add reference" in capsys.readouterr().err


def test_report_header_names_the_command_that_reproduces_it():
    import run as bench_run

    args = bench_run.parse_args(["--reference-stages", "cornell_box", "floor_lamp"])
    assert bench_run.command(args) == (
        "python benchmarks/run.py --reference-stages cornell_box floor_lamp"
    )
    args = bench_run.parse_args(["--quick", "--sections", "fit"])
    assert bench_run.command(args) == "python benchmarks/run.py --quick --sections fit"
    assert bench_run.command(bench_run.parse_args([])) == "python benchmarks/run.py"


def test_bench_command_runs_what_run_py_runs(capsys):
    """``usdahd bench`` is benchmarks/run.py: the same default sections, and a wrong reference
    stage is the same usage error (exit 2, also as JSON), in-process and as a subprocess."""
    import json
    import subprocess

    import run as bench_run

    from usdahd import cli

    assert bench_cmd.SECTIONS == bench_run.DEFAULT_SECTIONS
    argv = ["bench", "--sections", "reference", "--reference-stages", "nope", "--json"]
    assert cli.main(argv) == 2
    cap = capsys.readouterr()
    assert "usdahd bench: error: unknown reference stage nope; choose from" in cap.err
    assert json.loads(cap.out)["exit_code"] == 2
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", *argv], capture_output=True, text=True, cwd=REPO
    )
    assert proc.returncode == 2, proc.stderr
    assert "unknown reference stage nope" in json.loads(proc.stdout)["error"]


def test_reference_summary_names_the_largest_ratio_and_stages_not_reached():
    import run as bench_run

    ttq128 = [
        {"stage": "a", "renderer": "usdahd", "ratio": 0.05},
        {"stage": "b", "renderer": "usdahd", "ratio": 0.17},
        {"stage": "c", "renderer": "usdahd", "ratio": 0.08},
        {"stage": "a", "renderer": "usdahd (warm)", "ratio": 0.04},
        {"stage": "b", "renderer": "usdahd (warm)", "ratio": None},
    ]
    lines = bench_run.reference_summary({128: ttq128})
    assert lines[0] == (
        "- usdahd vs Cycles (as a command), usdahd's time to Cycles' 1024-spp error over "
        "Cycles' time: at 128² at most 0.17x on 3 stages (largest: b; median 0.08x, target "
        "<= 0.1x: **missed**)."
    )
    assert lines[1] == (
        "- usdahd vs Cycles (as a call in a running process), usdahd's time to Cycles' "
        "1024-spp error over Cycles' time: at 128² not reached on b; at most 0.04x on the 1 "
        "other stages (largest: a; median 0.04x, target <= 0.1x: **missed**)."
    )
    # no stage reached at a size: that size says so and misses its target
    (line,) = bench_run.reference_summary(
        {32: [{"stage": "b", "renderer": "usdahd", "ratio": None}]}
    )
    assert line.endswith("at 32² not reached on b, target <= 0.3x: **missed**.")


def test_reference_summary_states_the_worst_ratio_at_each_size():
    """Issue 43: one run, both sizes; the summary line of each usdahd timing gives the worst
    ratio at 128² and at 32² against that size's target (0.1 and 0.3); a size without a target
    (the quick plan's) has no verdict."""
    import run as bench_run

    def ttq(ratios, ren="usdahd"):
        return [{"stage": s, "renderer": ren, "ratio": r} for s, r in ratios.items()]

    by_size = {
        128: ttq({"a": 0.08, "b": 0.03}) + ttq({"a": 0.05, "b": 0.02}, "usdahd (warm)"),
        32: ttq({"a": 0.12, "b": 0.31}) + ttq({"a": 0.10, "b": 0.25}, "usdahd (warm)"),
        16: ttq({"a": 0.5}),
    }
    cmd, warm = bench_run.reference_summary(by_size)
    assert (
        "at 128² at most 0.08x on 2 stages (largest: a; median 0.06x, target <= 0.1x: met)" in cmd
    )
    assert "at 32² at most 0.31x on 2 stages (largest: b; median 0.21x, target <= 0.3x: " in cmd
    assert cmd.endswith("at 16² at most 0.50x on 1 stages (largest: a; median 0.50x).")
    assert "0.31x" in cmd and "**missed**" in cmd.split("at 32²")[1]
    assert warm.startswith("- usdahd vs Cycles (as a call in a running process)")
    assert "at 128² at most 0.05x" in warm and "at 32² at most 0.25x" in warm
    assert "missed" not in warm and "16²" not in warm


def test_reference_section_runs_both_sizes_in_one_run(tmp_path, monkeypatch):
    """The reference section's plans hold 128² and 32² (full) or two small sizes (quick), and
    run_section runs every size of the plan in the one call: each size's rows, args and plot
    come back, and the report has a subsection per size, the summary a ratio per size. Run
    on fake stage results (no Cycles needed): bench_stage is replaced by rows that record the
    resolution each call was made at."""
    import reference_bench as rb
    import run as bench_run

    assert [c["resolution"] for c in rb.SECTION_PLANS["full"]] == [128, 32]
    assert all(1024 in c["cycles_samples"] for c in rb.SECTION_PLANS["full"])
    assert len(rb.SECTION_PLANS["quick"]) == 2
    calls = []

    def fake_stage(path, resolution, samples, truth_spp, bpy, **kw):
        calls.append((path.stem, resolution))
        t = 1.0 if resolution == 16 else 2.0
        return [
            {"stage": path.stem, "renderer": "cycles", "spp": 1024, "seconds": 10.0,
             "seconds_runs": [10.0], "rel_rmse": 0.02},
            {"stage": path.stem, "renderer": "usdahd", "spp": 16, "seconds": t,
             "seconds_runs": [t], "rel_rmse": 0.01},
        ]  # fmt: skip

    monkeypatch.setattr(rb.runner, "find_bpy", lambda _=None: "bpy")
    monkeypatch.setattr(rb, "bench_stage", fake_stage)
    got = rb.run_section("quick", tmp_path, stages=["cornell_box", "floor_lamp"])
    sizes = [c["resolution"] for c in rb.SECTION_PLANS["quick"]]
    assert calls == [(s, r) for r in sizes for s in ("cornell_box", "floor_lamp")]
    assert [one["args"]["resolution"] for one in got["sizes"]] == sizes
    assert all(r["resolution"] == one["args"]["resolution"] for one in got["sizes"]
               for r in one["rows"])  # fmt: skip
    md = rb.section(got)
    for s in sizes:
        assert f"## usdahd vs Cycles at {s}² per mesh" in md
    summary = bench_run.section_summary({"reference": got})
    assert f"at {sizes[0]}² at most 0.10x on 2 stages" in summary
    assert f"at {sizes[1]}² at most 0.20x on 2 stages" in summary


def test_compile_package_writes_the_bytecode_a_pip_install_would(tmp_path):
    """reference_bench times the ``usdahd bake`` command with the package byte-compiled first
    (an editable install under PYTHONDONTWRITEBYTECODE=1 never writes it, and compiling ~100
    modules in every process cost 0.45 s of CPU): every module gets its .pyc, once."""
    import reference_bench as rb

    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for f in ("__init__.py", "a.py", "sub/__init__.py", "sub/b.py"):
        (pkg / f).write_text("X = 1\n")
    assert rb.compile_package(pkg) == 4
    assert len(list(pkg.rglob("__pycache__/*.pyc"))) == 4
    assert rb.compile_package(pkg) == 0  # up to date: nothing rewritten


def test_regeneration_keeps_hand_run_sections():
    """benchmarks/run.py rewrites docs/benchmarks.md from scratch; hand-run sections between
    ``<!-- BEGIN kept: ... -->`` and ``<!-- END kept -->`` are carried over, in order."""
    import run as bench_run

    text = (
        "# old\n\n<!-- BEGIN kept: a -->\n## A\n| x |\n<!-- END kept -->\n\ngenerated\n\n"
        "<!-- BEGIN kept: b -->\nB\n<!-- END kept -->\n"
    )
    got = bench_run.kept_blocks(text)
    assert got == [
        "<!-- BEGIN kept: a -->\n## A\n| x |\n<!-- END kept -->",
        "<!-- BEGIN kept: b -->\nB\n<!-- END kept -->",
    ]
    assert bench_run.kept_blocks("# nothing kept\n") == []


def test_denoise_cost_table_gives_the_plain_cpu_to_the_defaults_error():
    """benchmarks/denoise_cost.py: --no-denoise's error falls as 1/sqrt(samples) from its
    largest count and its CPU is linear between its two largest counts, so the CPU it needs
    to reach the default's error follows; the error ratio is default / plain."""
    import denoise_cost as dc

    def row(variant, spp, err, cpu):
        return {"stage": "s", "resolution": 32, "spp": spp, "variant": variant,
                "net_rel": err, "cpu": cpu}  # fmt: skip

    rows = [row("plain", 64, 0.04, 0.2), row("plain", 256, 0.02, 0.5)]
    rows += [row("default", 64, 0.02, 1.0), row("default", 256, 0.01, 1.3)]
    lines = dc.table(rows).splitlines()
    # at 64 spp the default's 2 % is plain's own at 256 spp: 0.5 s; at 256 spp its 1 % needs
    # 4x the samples (1024), 0.5 + 768 * 0.3 / 192 = 1.7 s
    assert lines[2] == "| s | 32² | 64 | 4.00 % / 0.20 | 2.00 % / 1.00 | 0.50 | 0.50 (256 spp) |"
    assert lines[3] == "| s | 32² | 256 | 2.00 % / 0.50 | 1.00 % / 1.30 | 0.50 | 1.70 (1024 spp) |"
    # the truth's noise is taken out in quadrature: 5 % against a truth of 3 % noise is 4 %
    t = np.linspace(1.0, 2.0, 16).reshape(4, 4)
    m = np.ones((4, 4), bool)
    d = np.where(np.arange(16).reshape(4, 4) % 2, 1, -1) * 0.06 * t.mean()  # rms/2 = 3 %
    e = np.where(np.arange(16).reshape(4, 4) % 2, 1, -1) * 0.05 * t.mean()
    got = dc.net_error({"/p": (t + e, m)}, {"/p": (t, m, d)})
    assert got == pytest.approx(0.04)


def test_reference_bench_stages_take_the_sections_names(capsys):
    """``reference_bench.py --stages`` resolves the same names as run.py's reference section
    (the shared Cornell boxes beside the checkout included) and rejects an unknown one with
    exit 2 naming the file, before it looks for a bpy interpreter."""
    import reference_bench as rb

    names = [p.stem for p in rb.section_stages()]
    assert rb.stage_paths(names) == rb.section_stages()
    assert rb.stage_paths(["cornell_box"]) == [REPO / "samples" / "cornell_box.usda"]
    with pytest.raises(UsageError, match=r"nope\.usda: no such stage"):
        rb.stage_paths(["nope"])
    assert rb.main(["--stages", "nope", "--bpy-python", "/no/such/python"]) == 2
    assert "nope.usda: no such stage" in capsys.readouterr().err
