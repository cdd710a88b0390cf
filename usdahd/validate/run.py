"""What ``usdahd validate STAGE`` runs: our validators (keyword ``UsdAhdValidators``) plus the
built-in validators that matter for a baked stage (:data:`BUILTIN_VALIDATORS`) through one
``ValidationContext`` (:mod:`usdahd.usd.validation`), so its findings are the ones any
UsdValidation run with our plugin path reports; the CLI (:mod:`usdahd.commands.validate`)
only handles arguments and prints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from usdahd.usd import diagnostics, instances, schema
from usdahd.usd import validation as usd_validation
from usdahd.usd.stage import open_stage
from usdahd.validate.composition import check_composition
from usdahd.validate.findings import Finding, finding_from_usd
from usdahd.validate.plugin import check_lightmapped
from usdahd.validate.registry import (
    BUILTIN_VALIDATORS,
    COMPOSITION_RULE,
    KEYWORD,
    RULE_NAMES,
    STAGE_RULES,
    validator_name,
)

__all__ = ["validate_file"]

#: The built-in validator that walks every layer a stage depends on, unselected variants
#: included, and raises (pxr's Tf.ErrorException: no findings at all) on one that does not
#: parse; validate_stage then runs without it (the Composition rule names that layer).
DEPENDENCY_VALIDATOR = "usdUtilsValidators:MissingReferenceValidator"

SEVERITY_ORDER = {"error": 0, "warning": 1, "info": 2}


def context(retrace: bool = False, builtins=BUILTIN_VALIDATORS):
    """The ValidationContext ``usdahd validate`` uses: our keyword plus the ``builtins`` (plus
    the opt-in Retrace validator with ``retrace``). Raises StageError when ours are not
    registered."""
    from usdahd.validate import retrace as rt

    required = [validator_name(r) for r in (*RULE_NAMES, *(r.name for r in STAGE_RULES))]
    extra = rt.validator_name() if retrace else None
    return usd_validation.context(KEYWORD, required, builtins, extra)


def validate_stage(stage, prims: list[str] | None = None, retrace: bool = False) -> list[Finding]:
    """Run the validation context on a stage (or the prims at ``prims`` and their
    descendants); returns the findings sorted by prim, severity, rule and code.

    retrace : also run the opt-in Retrace rule (settings in usdahd.validate.retrace.OPTIONS).
    Lightmapped is a UsdValidation stage validator, which USD runs on a whole stage only: with
    ``prims`` on a stage without AhdLightmapAPI its ``NoAhdLightmapAPI`` error is added here,
    so an API caller pointed at the wrong stage gets the same failure as ``usdahd validate``.
    Raises UsageError for a ``prims`` path that is not on the stage.
    """
    # Instance entries are checked as mesh records at their keys (usdahd.usd.instances).
    with instances.record_view(stage) as missing:
        try:
            errors = usd_validation.run_context(context(retrace), stage, prims)
            skipped = None
        except Exception as exc:
            if not diagnostics.is_usd_error(exc):
                raise
            skipped = "; ".join(diagnostics.exception_causes(exc))
            rest = tuple(b for b in BUILTIN_VALIDATORS if b != DEPENDENCY_VALIDATOR)
            errors = usd_validation.run_context(context(retrace, rest), stage, prims)
        findings = [finding_from_usd(e) for e in errors]
    findings += missing_instance_records(missing, prims)
    if not any(f.code == "NoAhdLightmapAPI" for f in findings):
        findings = check_lightmapped(stage) + findings
    if prims and not any(f.rule == COMPOSITION_RULE.name for f in findings):
        findings = check_composition(stage) + findings  # stage validators skip a --prim run
    if skipped is not None:
        findings.append(_dependency_skipped(skipped))
    findings = _drop_restated(findings)
    findings.sort(key=lambda f: (f.prim, SEVERITY_ORDER.get(f.severity, 3), f.rule, f.code))
    return findings


def missing_instance_records(missing: list, prims: list[str] | None = None) -> list[Finding]:
    """``SchemaValues`` error ``NoInstanceRecord`` for each instance copy without a record of
    its own (usdahd.usd.instances.record_view), within ``prims`` when given."""
    out = []
    for key, why in missing:
        if prims and not any(key == p or key.startswith(p.rstrip("/") + "/") for p in prims):
            continue
        out.append(
            Finding(
                "SchemaValues",
                "error",
                key,
                "NoInstanceRecord",
                f"{why}: every instance copy of a baked prototype mesh gets its own lightmap "
                "(docs/schema.md, Instances). Fix: re-bake the stage (usdahd bake)",
            )
        )
    return out


def _dependency_skipped(cause: str) -> Finding:
    name = DEPENDENCY_VALIDATOR.split(":", 1)[1]
    return Finding(
        COMPOSITION_RULE.name,
        "info",
        "/",
        "DependencyCheckSkipped",
        f"USD's {name} stopped on a layer that does not parse ({cause}) and was left out of "
        "this run: asset paths outside the lightmaps (material textures) are not checked for "
        "existence on this stage; the Composition warnings name that layer. Fix: repair or "
        "remove the arc to it",
    )


def _drop_restated(findings: list) -> list:
    """Drop MissingReferenceValidator's ``UnresolvableDependency`` for a layer a Composition
    finding reports (a missing layer in an unselected variant: one problem, one finding)."""
    reported = {
        os.path.normpath(str(f.data.get("resolved") or f.data.get("asset")))
        for f in findings
        if f.rule == COMPOSITION_RULE.name and (f.data.get("resolved") or f.data.get("asset"))
    }
    return _drop_unresolvable(findings, reported)


def _drop_unresolvable(findings: list, paths: set) -> list:
    """``findings`` without USD's ``UnresolvableDependency`` findings whose quoted path (the
    first '...' of the message, normalised) is in ``paths``."""
    if not paths:
        return findings
    out = []
    for f in findings:
        if f.code == "UnresolvableDependency":
            quoted = f.message.split("'")
            if len(quoted) >= 3 and os.path.normpath(quoted[1]) in paths:
                continue
        out.append(f)
    return out


def dedupe(findings: list, stage_dir: Path) -> list:
    """Drop USD's MissingReferenceValidator finding for a texture our Textures rule already
    reported missing (one missing file, one finding)."""
    missing = set()
    for f in findings:
        asset = (getattr(f, "data", None) or {}).get("asset")
        if f.code == "MissingFile" and asset:
            missing.add(os.path.normpath(str(stage_dir / asset)))
    return _drop_unresolvable(findings, missing)


@dataclass
class Report:
    """What validating a stage file gave.

    findings : sorted, deduplicated; prims : paths of the prims with AhdLightmapAPI;
    usd_diagnostics : USD's own TfDiagnostic messages while validating (sorted, unique);
    stderr : other lines written to stderr meanwhile (progress, notices), in order.
    """

    findings: list[Finding]
    prims: list[str]
    usd_diagnostics: list[str] = field(default_factory=list)
    stderr: list[str] = field(default_factory=list)


def validate_file(path: str, prims: list[str] | None = None, retrace: bool = False) -> Report:
    """Open the stage at ``path`` and validate it (or ``prims``), with USD's C++ diagnostics
    captured instead of interleaved with the findings.

    A stage without AhdLightmapAPI gives ``NoAhdLightmapAPI`` (:func:`validate_stage`), with
    or without ``prims``. Raises StageError (unreadable stage, validators missing) and
    UsageError.
    """
    with usd_validation.captured_stderr_fd() as lines, diagnostics.capture() as usd:
        stage = open_stage(path)
        baked = [str(p.GetPath()) for p in schema.prims_with_api(stage) if not p.IsInstanceProxy()]
        baked += sorted(k for k in schema.stage_records(stage, errors=[]) if k not in baked)
        findings = validate_stage(stage, prims, retrace=retrace)
    findings = dedupe(findings, Path(path).resolve().parent)
    # USD's own messages: trapped on this thread, printed (secondary threads) to fd 2; each
    # once, without those a finding already reports (composition errors, the dependency walk's
    # messages about layers the Composition rule names).
    reported = [
        str(v)
        for f in findings
        if f.rule == COMPOSITION_RULE.name
        for k, v in f.data.items()
        if k in ("asset", "resolved")
    ]
    notes = []
    for d in [*usd, *diagnostics.from_stderr_lines(lines)]:
        if d.restates_composition or any(r and r in d.message for r in reported):
            continue
        if d.message not in notes:
            notes.append(d.message)
    return Report(
        findings,
        baked,
        sorted(notes),
        [ln for ln in lines if not usd_validation.is_usd_diagnostic(ln)],
    )
