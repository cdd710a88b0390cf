"""``usdahd validate STAGE``: asset-CI checks of a baked stage through USD's validation framework.

A thin CLI over ``UsdValidation``: it builds a ``ValidationContext`` from our validators
(keyword ``UsdAhdValidators``, see :mod:`usdahd.validate`) plus the built-in validators that
matter for a baked stage (:data:`usdahd.validate.BUILTIN_VALIDATORS`), so its findings are the
ones any UsdValidation run with our plugin path reports. One line per finding::

    error   </World/Quad> IzCheck: 3 texel(s) exceed the tolerance: ... Fix: re-bake the prim.

Exit status: 0 clean, 1 errors (warnings too with ``--strict``), 2 the stage could not be
validated (unreadable stage, validators missing, a rule that crashed).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from pathlib import Path

from usdahd.errors import StageError, UsageError

SEVERITY_ORDER = {"error": 0, "warning": 1, "info": 2}


def add_parser(sub):
    p = sub.add_parser(
        "validate",
        help="check a baked stage (schema values, textures, I_z, staleness, UVs)",
        description=(
            "Validate the AhdLightmapAPI bakes of a USD stage with USD's validation framework "
            "(our UsdAhdValidators plus USD's missing-reference, type and composition checks). "
            "Prints one line per finding: severity, <prim path>, rule, what is wrong and what to "
            "do. Exit status 0 clean, 1 errors (or warnings with --strict), 2 could not run."
        ),
    )
    p.add_argument("stage", nargs="?", help="the baked stage (usually NAME.lightmaps.usda)")
    p.add_argument(
        "--prim",
        action="append",
        default=None,
        metavar="PATH",
        help="validate only this prim and its descendants (repeatable)",
    )
    p.add_argument("--strict", action="store_true", help="warnings fail too (exit 1)")
    p.add_argument(
        "--tolerance",
        type=float,
        default=None,
        metavar="REL",
        help="relative I(z) tolerance of IzCheck (default: derived per texel from the "
        "textures' quantization, docs/validate.md)",
    )
    p.add_argument(
        "--rmse-threshold",
        type=float,
        default=None,
        metavar="REL",
        help="relative hemispherical RMSE the textures may add to the model's own fit before "
        "EncodingError warns (default 0.25)",
    )
    p.add_argument(
        "--retrace",
        type=int,
        default=None,
        metavar="N",
        help="also run the opt-in Retrace rule: re-trace I_z at N random covered texel centres "
        "per prim with the baker's integrator and compare with the bake (costs time; "
        "docs/validate.md gives the cost per texel)",
    )
    p.add_argument(
        "--retrace-samples",
        type=int,
        default=None,
        metavar="S",
        help="retrace samples per texel (default 4096, split into independent batches)",
    )
    p.add_argument(
        "--retrace-seed",
        type=int,
        default=None,
        metavar="SEED",
        help="random stream of the retrace (texel choice and tracing; default 0)",
    )
    p.add_argument("--list-rules", action="store_true", help="list the rules and exit")
    p.set_defaults(func=run)
    return p


def list_rules(out=None) -> None:
    from usdahd import validate as v

    out = out or sys.stdout
    width = max(len(r.name) for r in v.RULES)
    for r in v.RULES:
        print(f"{r.name:<{width}}  {r.description}", file=out)
    print(f"{v.STAGE_RULE.name:<{width}}  {v.STAGE_RULE.description} (per stage)", file=out)
    from usdahd.validate import retrace as rt

    print(f"{rt.RULE:<{width}}  {rt.DESCRIPTION} (--retrace N)", file=out)
    print(
        f"\n(UsdValidation validators {v.PLUGIN_NAME}:<rule>, keyword {v.KEYWORD}; "
        f"{rt.RULE} has keyword {rt.KEYWORD}; also run: {', '.join(v.BUILTIN_VALIDATORS)})",
        file=out,
    )


def _open(path: str):
    from pxr import Sdf, Usd

    if not Path(path).is_file():
        raise StageError(f"{path}: no such file")
    cached = Sdf.Layer.Find(str(path))
    if cached is not None:
        cached.Reload(force=True)  # a long-lived process may hold an older copy
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr raises Tf.ErrorException
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise StageError(f"{path}: not a readable USD stage ({first})") from None
    if stage is None:
        raise StageError(f"{path}: not a readable USD stage")
    return stage


def context(retrace: bool = False):
    """The ValidationContext ``usdahd validate`` uses: our keyword plus the built-ins (plus the
    opt-in Retrace validator with ``retrace``)."""
    from pxr import UsdValidation

    from usdahd import validate as v

    reg = UsdValidation.ValidationRegistry()
    metas = list(reg.GetValidatorMetadataForKeyword(v.KEYWORD))
    ours = {m.name for m in metas}
    names = [*v.RULE_NAMES, v.STAGE_RULE.name]
    missing = [v.validator_name(r) for r in names if v.validator_name(r) not in ours]
    if missing:
        raise StageError(
            f"the usdahd validators are not registered ({', '.join(missing)}): USD's validation "
            "registry was created before usdahd registered its plugins; import usdahd.usd first or "
            "set PXR_PLUGINPATH_NAME to the output of 'usdahd plugin-path'"
        )
    for name in v.BUILTIN_VALIDATORS:
        m = reg.GetValidatorMetadata(name)
        if m is not None:
            metas.append(m)
    if retrace:
        from usdahd.validate import retrace as rt

        m = reg.GetValidatorMetadata(rt.validator_name())
        if m is None or not reg.HasValidator(rt.validator_name()):
            raise StageError(
                f"the usdahd validator {rt.validator_name()} is not registered: its plugInfo "
                "(plugins/usdAhdValidators) is older than this usdahd; reinstall usdahd"
            )
        metas.append(m)
    return UsdValidation.ValidationContext(metadata=metas, includeAllAncestors=False)


def validate_stage(stage, prims: list[str] | None = None, retrace: bool = False) -> list:
    """Run the validation context on a stage (or some prims); returns usdahd.validate.Finding.

    retrace : also run the opt-in Retrace rule (settings in usdahd.validate.retrace.OPTIONS).
    """
    from pxr import Sdf, Usd

    from usdahd import validate as v

    ctx = context(retrace)
    if prims:
        selected = []
        for p in prims:
            try:
                prim = stage.GetPrimAtPath(Sdf.Path(p))
            except Exception:
                prim = None
            if not prim:
                raise UsageError(f"--prim {p}: no such prim on the stage")
            selected += list(Usd.PrimRange(prim))
        errors = ctx.Validate(selected)
    else:
        errors = ctx.Validate(stage)
    findings = [v.finding_from_usd(e) for e in errors]
    findings.sort(key=lambda f: (f.prim, SEVERITY_ORDER.get(f.severity, 3), f.rule, f.code))
    return findings


@contextlib.contextmanager
def captured_stderr_fd():
    """Capture what C++ code (USD's TfDiagnostic warnings) writes to file descriptor 2.

    Yields a list that holds the captured, non-empty lines after the block, so USD's own
    messages ("Ill-formed SdfPath", "Failed to resolve reference") do not interleave with the
    findings; :func:`run` reports them separately.
    """
    lines: list[str] = []
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded use): nothing to capture
        yield lines
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", errors="replace")
            lines += [ln.strip() for ln in text.splitlines() if ln.strip()]


def _is_usd_diagnostic(line: str) -> bool:
    """A line of USD's TfDiagnostic output (``Warning: in F at line N of x.cpp -- ...``)."""
    return line.startswith(("Warning: in ", "Error: in ", "Coding Error: in ", "Runtime Error"))


def _usd_diagnostic(line: str) -> str:
    """``Warning: in F at line N of /path/x.cpp -- message`` -> ``message``."""
    return line.split(" -- ", 1)[1] if " -- " in line else line


def dedupe(findings: list, stage_dir: Path) -> list:
    """Drop USD's MissingReferenceValidator finding for a texture our Textures rule already
    reported missing (one missing file, one finding)."""
    missing = set()
    for f in findings:
        asset = (getattr(f, "data", None) or {}).get("asset")
        if f.code == "MissingFile" and asset:
            missing.add(os.path.normpath(str(stage_dir / asset)))
    if not missing:
        return findings
    out = []
    for f in findings:
        if f.code == "UnresolvableDependency":
            quoted = f.message.split("'")
            if len(quoted) >= 3 and os.path.normpath(quoted[1]) in missing:
                continue
        out.append(f)
    return out


def format_finding(f) -> str:
    where = f.prim if f.prim.startswith("@") else f"<{f.prim}>" if f.prim else "<stage>"
    return f"{f.severity:<7} {where} {f.rule}: {f.message}"


def exit_code(findings, strict: bool) -> int:
    if any(f.code == "InternalError" for f in findings):
        return 2
    if any(f.severity == "error" for f in findings):
        return 1
    if strict and any(f.severity == "warning" for f in findings):
        return 1
    return 0


def _retrace_options(args, rt):
    """RetraceOptions from --retrace/--retrace-samples/--retrace-seed, or None (not asked)."""
    if args.retrace is None:
        if args.retrace_samples is not None or args.retrace_seed is not None:
            raise UsageError("--retrace-samples and --retrace-seed need --retrace N")
        return None
    if args.retrace < rt.MIN_TEXELS:
        raise UsageError(
            f"--retrace {args.retrace}: give at least {rt.MIN_TEXELS} texels per prim "
            "(64 is a good start)"
        )
    opts = rt.RetraceOptions(progress=None if args.quiet else _progress)
    if args.retrace_samples is not None:
        if args.retrace_samples < 2 * opts.min_batches:
            raise UsageError(
                f"--retrace-samples {args.retrace_samples}: give at least "
                f"{2 * opts.min_batches} ({opts.min_batches} batches of 2 or more samples)"
            )
        opts.samples = args.retrace_samples
    opts.texels = args.retrace
    if args.retrace_seed is not None:
        opts.seed = args.retrace_seed
    return opts


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(args) -> int:
    if args.list_rules:
        list_rules()
        return 0
    if not args.stage:
        raise UsageError("give a STAGE to validate (or --list-rules)")
    from usdahd import validate as v
    from usdahd.validate import retrace as rt

    retrace = _retrace_options(args, rt)
    old = (v.OPTIONS.iz_tolerance, v.OPTIONS.rmse_warning)
    old_rt = rt.OPTIONS
    if args.tolerance is not None:
        if not args.tolerance > 0:
            raise UsageError(f"--tolerance {args.tolerance}: must be > 0")
        v.OPTIONS.iz_tolerance = args.tolerance
    if args.rmse_threshold is not None:
        if not args.rmse_threshold > 0:
            raise UsageError(f"--rmse-threshold {args.rmse_threshold}: must be > 0")
        v.OPTIONS.rmse_warning = args.rmse_threshold
    try:
        with captured_stderr_fd() as usd_lines:
            stage = _open(args.stage)
            from usdahd.usd import schema

            baked = [p for p in schema.prims_with_api(stage)]
            if retrace is not None:
                rt.OPTIONS = retrace
            findings = validate_stage(stage, args.prim, retrace=retrace is not None)
            if not baked and not any(f.code == "NoAhdLightmapAPI" for f in findings):
                # The stage rule Lightmapped runs on a whole stage only, not on --prim subtrees;
                # a CI job pointed at the wrong file must not stay green either way.
                findings = v.check_lightmapped(stage) + findings
    finally:
        v.OPTIONS.iz_tolerance, v.OPTIONS.rmse_warning = old
        rt.OPTIONS = old_rt
    findings = dedupe(findings, Path(args.stage).resolve().parent)
    usd = [ln for ln in usd_lines if _is_usd_diagnostic(ln)]
    for ln in usd_lines:  # our own stderr output (progress, notices) is passed on as it was
        if not _is_usd_diagnostic(ln):
            print(ln, file=sys.stderr)
    usd_notes = sorted({_usd_diagnostic(ln) for ln in usd})
    code = exit_code(findings, args.strict)
    counts = {s: sum(f.severity == s for f in findings) for s in ("error", "warning", "info")}
    if args.json:
        print(
            json.dumps(
                {
                    "stage": args.stage,
                    "prims": [str(p.GetPath()) for p in baked],
                    "findings": v.findings_json(findings),
                    "counts": counts,
                    "usd_diagnostics": usd_notes,
                    "exit_code": code,
                },
                indent=2,
                sort_keys=True,
            )
        )
        return code
    for f in findings:
        if args.quiet and f.severity == "info":
            continue
        print(format_finding(f))
    if usd_notes and not args.quiet:
        print(
            f"note: USD printed {len(usd_notes)} diagnostic(s) while validating:", file=sys.stderr
        )
        for n in usd_notes[:10]:
            print(f"  usd: {n[:300]}", file=sys.stderr)
    if not args.quiet:
        status = "FAILED" if code else "ok"
        note = "" if baked else " (no prim has AhdLightmapAPI)"
        print(
            f"{args.stage}: {status}: {counts['error']} error(s), {counts['warning']} "
            f"warning(s), {counts['info']} note(s) on {len(baked)} lightmapped prim(s){note}",
            file=sys.stderr,
        )
    return code
