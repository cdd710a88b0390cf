"""The reports ``usdahd validate --format`` writes: text, JSON, JUnit XML and SARIF 2.1.0.

Pure functions of the findings (no pxr): :func:`render` turns a :class:`Summary` into the text
of one format. docs/ci.md says what each format holds and how CI systems read it; the tests
validate the JUnit output against the JUnit XSDs of Jenkins (xunit-plugin ``junit-10.xsd``) and
of the Ant JUnit task (Windy Road ``JUnit.xsd``), and the SARIF output against the OASIS
SARIF 2.1.0 JSON schema.

JUnit: one ``<testcase>`` per prim x rule (``classname`` the prim path, ``name`` the rule); a
test case fails (``<failure>``) when it has an error finding, or a warning with ``--strict``,
so the report fails exactly when the exit status is 1; a rule that crashed (``InternalError``,
exit 2) is an ``<error>``; a rule that could not run (``Skipped``) is ``<skipped>``; the
other findings (warnings without ``--strict``, notes) are listed in the suite's
``<system-out>``.

SARIF: one run of the driver ``usdahd`` whose ``rules`` are the rules' one-sentence docs
(:data:`usdahd.validate.registry.RULES`, the plugInfo ``doc`` strings) plus the docs of the USD
built-in validators that reported; a result per finding, level error / warning / note (notes
that say a check passed are ``kind: pass``, those that say it did not run ``notApplicable``),
located by the layer file (``artifactLocation``, relative to ``%SRCROOT%`` = the working
directory when it is inside it, with the line of the prim's ``def``/``over`` in a ``.usda``
layer) and by the prim path (``logicalLocations``).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import socket
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from usdahd.validate.findings import Finding, findings_json

__all__ = [
    "Summary",
    "format_finding",
    "json_report",
    "render",
    "summary_line",
    "text",
    "write_atomic",
]

FORMATS = ("text", "json", "junit", "sarif")
#: The file extension docs/ci.md uses for each format (a hint only; any name works).
EXTENSIONS = {"text": ".txt", "json": ".json", "junit": ".xml", "sarif": ".sarif"}
SARIF_SCHEMA = (
    "https://docs.oasis-open.org/sarif/sarif/v2.1.0/errata01/os/schemas/sarif-schema-2.1.0.json"
)
SARIF_LEVEL = {"error": "error", "warning": "warning", "info": "note"}
#: JUnit classname of findings about the whole stage (USD reports them on the pseudo-root).
STAGE_PRIM = "/"


@dataclass
class Summary:
    """Everything a report needs, gathered by the CLI.

    stage : the stage file as given; findings : sorted findings; prims : baked prim paths;
    prim_rules : rules run on every baked prim; stage_rules : rules run once per stage;
    rule_docs : rule id -> one-sentence description; exit_code, strict; seconds : wall time;
    usd_diagnostics : USD's own messages while validating; version : usdahd's version.
    """

    stage: str
    findings: list[Finding]
    prims: list[str]
    prim_rules: list[str]
    stage_rules: list[str]
    rule_docs: dict[str, str]
    exit_code: int
    strict: bool = False
    seconds: float = 0.0
    usd_diagnostics: list[str] = field(default_factory=list)
    version: str = ""

    @property
    def counts(self) -> dict:
        return {
            s: sum(f.severity == s for f in self.findings) for s in ("error", "warning", "info")
        }


def render(fmt: str, s: Summary, quiet: bool = False) -> str:
    """The report of format ``fmt`` (one of :data:`FORMATS`) as text ending in a newline."""
    if fmt == "text":
        return text(s, quiet)
    if fmt == "json":
        return json_report(s) + "\n"
    if fmt == "junit":
        return junit(s)
    if fmt == "sarif":
        return sarif(s) + "\n"
    raise ValueError(f"unknown format {fmt!r}")


# ------------------------------------------------------------------------------------- text


def format_finding(f: Finding) -> str:
    where = f.prim if f.prim.startswith("@") else f"<{f.prim}>" if f.prim else "<stage>"
    return f"{f.severity:<7} {where} {f.rule}: {f.message}"


def text(s: Summary, quiet: bool = False) -> str:
    lines = [format_finding(f) for f in s.findings if not (quiet and f.severity == "info")]
    return "".join(ln + "\n" for ln in lines)


def summary_line(s: Summary) -> str:
    c = s.counts
    status = "FAILED" if s.exit_code else "ok"
    note = "" if s.prims else " (no prim has AhdLightmapAPI)"
    return (
        f"{s.stage}: {status}: {c['error']} error(s), {c['warning']} warning(s), "
        f"{c['info']} note(s) on {len(s.prims)} lightmapped prim(s){note}"
    )


def json_report(s: Summary) -> str:
    return json.dumps(
        {
            "stage": s.stage,
            "prims": s.prims,
            "findings": findings_json(s.findings),
            "counts": s.counts,
            "usd_diagnostics": s.usd_diagnostics,
            "exit_code": s.exit_code,
        },
        indent=2,
        sort_keys=True,
    )


# ------------------------------------------------------------------------------------ JUnit


def _cases(s: Summary) -> dict[tuple[str, str], list[Finding]]:
    """(prim, rule) -> its findings, in a stable order: every baked prim x prim rule, the
    stage rules on ``/``, then any other (prim, rule) a finding names."""
    cases: dict[tuple[str, str], list[Finding]] = {}
    for p in s.prims:
        for r in s.prim_rules:
            cases[(p, r)] = []
    reported = {f.rule for f in s.findings}
    for r in s.stage_rules:
        # A stage-wide validator that reported on prims is represented by those prims' cases.
        if r not in reported or any(f.rule == r and f.prim == STAGE_PRIM for f in s.findings):
            cases[(STAGE_PRIM, r)] = []
    for f in s.findings:
        cases.setdefault((f.prim or STAGE_PRIM, f.rule), []).append(f)
    return cases


def _fails(f: Finding, strict: bool) -> bool:
    return f.severity == "error" or (strict and f.severity == "warning")


def _finding_text(f: Finding) -> str:
    data = json.dumps(f.data, sort_keys=True) if f.data else ""
    return format_finding(f) + (f"\n  code: {f.code}" + (f"; data: {data}" if data else ""))


def _xml_safe(t: str) -> str:
    """Drop characters XML 1.0 cannot hold (control characters other than tab/newline)."""
    return re.sub("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]", "", t)


def junit(s: Summary) -> str:
    """JUnit XML (see the module doc), valid against both XSDs in tests/data/schemas/."""
    cases = _cases(s)
    root = ET.Element("testsuites")
    now = _dt.datetime.now(_dt.UTC).replace(tzinfo=None, microsecond=0).isoformat()
    suite = ET.SubElement(
        root,
        "testsuite",
        name=f"usdahd validate {s.stage}",
        package="usdahd.validate",
        id="0",
        timestamp=now,
        hostname=socket.gethostname() or "localhost",
        tests=str(len(cases)),
        failures="0",
        errors="0",
        skipped="0",
        time=f"{s.seconds:.3f}",
    )
    props = ET.SubElement(suite, "properties")
    for name, value in (
        ("stage", s.stage),
        ("usdahd.version", s.version),
        ("exit_code", str(s.exit_code)),
        ("strict", str(s.strict).lower()),
    ):
        ET.SubElement(props, "property", name=name, value=_xml_safe(value))
    failures = errors = skipped = 0
    other: list[str] = []
    for (prim, rule), found in cases.items():
        case = ET.SubElement(suite, "testcase", classname=prim, name=rule, time="0")
        crashed = [f for f in found if f.code == "InternalError"]
        failing = [f for f in found if _fails(f, s.strict) and f.code != "InternalError"]
        skips = [f for f in found if f.code == "Skipped"]
        if crashed or failing:
            # One element per case (the Ant schema allows one): every failing finding in it.
            bad = crashed + failing
            tag = "error" if crashed else "failure"
            first = bad[0]
            el = ET.SubElement(
                case,
                tag,
                type=first.code,
                message=_xml_safe(f"{first.severity}: {first.message}"),
            )
            el.text = _xml_safe("\n".join(_finding_text(f) for f in bad))
            errors += bool(crashed)
            failures += not crashed
        elif skips:
            ET.SubElement(case, "skipped", message=_xml_safe(skips[0].message))
            skipped += 1
        other += [_finding_text(f) for f in found if f not in (crashed + failing)]
    suite.set("failures", str(failures))
    suite.set("errors", str(errors))
    suite.set("skipped", str(skipped))
    out = ET.SubElement(suite, "system-out")
    out.text = _xml_safe("\n".join([summary_line(s), *other]))
    err = ET.SubElement(suite, "system-err")
    err.text = _xml_safe("\n".join(f"usd: {d}" for d in s.usd_diagnostics))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


# ------------------------------------------------------------------------------------ SARIF


_PRIM_HEADER = re.compile(r'^\s*(?:def|over|class)\b[^"]*"([^"]+)"')


def prim_lines(text_: str) -> dict[str, int]:
    """Prim path -> 1-based line of its ``def``/``over``/``class`` in a ``.usda`` layer (prims
    inside variant blocks are left out: their path in the layer differs). A text scan that
    tracks braces outside strings; a layer it cannot follow just yields fewer lines."""
    out: dict[str, int] = {}
    stack: list[tuple[str, int]] = []  # (prim path, brace depth its block opened at)
    depth = parens = 0  # braces, and parentheses (metadata: its dictionaries are not blocks)
    pending: str | None = None  # a prim whose header was read and whose block is not open yet
    variant_depth: list[int] = []
    for no, line in enumerate(text_.splitlines(), 1):
        bare = re.sub(r'"(?:[^"\\]|\\.)*"|@[^@]*@', '""', line).split("#", 1)[0]
        m = _PRIM_HEADER.match(line)
        if m and not variant_depth and parens == 0:
            parent = stack[-1][0] if stack else ""
            pending = f"{parent}/{m.group(1)}"
            out.setdefault(pending, no)
        elif re.match(r"^\s*variantSet\b", line) and parens == 0:
            variant_depth.append(depth)
        for ch in bare:
            if ch == "(":
                parens += 1
            elif ch == ")":
                parens = max(parens - 1, 0)
            elif ch == "{":
                if pending is not None and parens == 0:
                    stack.append((pending, depth))
                    pending = None
                depth += 1
            elif ch == "}":
                depth -= 1
                if stack and stack[-1][1] == depth:
                    stack.pop()
                if variant_depth and variant_depth[-1] == depth:
                    variant_depth.pop()
    return out


def _artifact_uri(stage: str) -> tuple[str, str | None]:
    """(uri, uriBaseId): relative to %SRCROOT% (the working directory) when inside it."""
    path = Path(stage).resolve()
    try:
        rel = path.relative_to(Path.cwd().resolve())
    except ValueError:
        return path.as_uri(), None
    return rel.as_posix(), "%SRCROOT%"


def _rule_descriptor(rule: str, doc: str, level: str) -> dict:
    text_ = doc or f"{rule} (no description registered)."
    d = {
        "id": rule,
        "name": rule.split(":")[-1],
        "shortDescription": {"text": text_},
        "fullDescription": {"text": text_},
        "defaultConfiguration": {"level": level},
        "help": {
            "text": f"{text_} docs/validate.md, Rules, says what it checks and how to fix it."
        },
    }
    return d


def sarif(s: Summary) -> str:
    """SARIF 2.1.0 JSON (see the module doc), valid against the OASIS schema."""
    uri, base = _artifact_uri(s.stage)
    lines: dict[str, int] = {}
    usda = Path(s.stage).suffix == ".usda"
    if usda:
        try:
            lines = prim_lines(Path(s.stage).read_text(encoding="utf-8", errors="replace"))
        except OSError:
            lines = {}
    rule_ids = list(dict.fromkeys([*s.prim_rules, *s.stage_rules, *(f.rule for f in s.findings)]))
    default_level = {r: "error" for r in rule_ids}
    default_level["EncodingError"] = "warning"
    default_level["Composition"] = "warning"  # errors only when a baked prim goes through it
    rules = [_rule_descriptor(r, s.rule_docs.get(r, ""), default_level[r]) for r in rule_ids]
    index = {r: i for i, r in enumerate(rule_ids)}
    artifact = {"uri": uri, **({"uriBaseId": base} if base else {})}
    results = []
    for f in s.findings:
        prim = f.prim or STAGE_PRIM
        phys: dict = {"artifactLocation": {**artifact, "index": 0}}
        if usda:  # the prim's line, or the layer's first for what the scan cannot place
            phys["region"] = {"startLine": lines.get(prim, 1)}
        logical = {"fullyQualifiedName": prim, "name": prim.rsplit("/", 1)[-1] or prim}
        logical["kind"] = "object"
        result: dict = {
            "ruleId": f.rule,
            "ruleIndex": index[f.rule],
            "message": {"text": f.message},
            "locations": [{"physicalLocation": phys, "logicalLocations": [logical]}],
            "partialFingerprints": {
                "usdahdFinding/v1": hashlib.sha256(
                    f"{uri}|{prim}|{f.rule}|{f.code}".encode()
                ).hexdigest()
            },
            "properties": {"code": f.code, "severity": f.severity, "data": f.data},
        }
        if f.severity == "info" and f.code == "Skipped":
            result.update(kind="notApplicable", level="none")
        elif f.severity == "info" and f.code.endswith("Ok"):
            result.update(kind="pass", level="none")
        else:
            result["level"] = SARIF_LEVEL.get(f.severity, "note")
        results.append(result)
    run: dict = {
        "tool": {
            "driver": {
                "name": "usdahd",
                "version": s.version,
                "semanticVersion": s.version,
                "rules": rules,
            }
        },
        "invocations": [
            {
                "executionSuccessful": s.exit_code in (0, 1),
                "exitCode": s.exit_code,
                "toolExecutionNotifications": [
                    {"message": {"text": d}, "level": "note"} for d in s.usd_diagnostics
                ],
            }
        ],
        "artifacts": [{"location": dict(artifact), "roles": ["analysisTarget"]}],
        "results": results,
        "columnKind": "unicodeCodePoints",
    }
    if base:
        run["originalUriBaseIds"] = {base: {"uri": Path.cwd().resolve().as_uri().rstrip("/") + "/"}}
    return json.dumps(
        {"$schema": SARIF_SCHEMA, "version": "2.1.0", "runs": [run]}, indent=2, sort_keys=False
    )


def write_atomic(path: str, content: str) -> None:
    """Write a report file atomically (a reader never sees half a report)."""
    from usdahd.io_util import atomic_write_bytes

    atomic_write_bytes(os.fspath(path), content.encode("utf-8"))
