"""``usdahd validate STAGE``: asset-CI checks of a baked stage through USD's validation framework.

A thin CLI over :func:`usdahd.validate.run.validate_file`, which runs a ``ValidationContext``
of our validators (keyword ``UsdAhdValidators``, see :mod:`usdahd.validate`) plus the built-in
validators that matter for a baked stage (:data:`usdahd.validate.BUILTIN_VALIDATORS`), so its
findings are the ones any UsdValidation run with our plugin path reports. One line per finding::

    error   </World/Quad> IzCheck: 3 texel(s) exceed the tolerance: ... Fix: re-bake the prim.

Exit status: 0 clean, 1 errors (warnings too with ``--strict``), 2 the stage could not be
validated (unreadable stage, validators missing, a rule that crashed).
"""

from __future__ import annotations

import json
import sys

from usdahd.errors import UsageError


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
        help="retrace samples per texel (default 256, split into independent batches)",
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
    for rule in v.STAGE_RULES:  # Lightmapped, Composition
        print(f"{rule.name:<{width}}  {rule.description} (per stage)", file=out)
    from usdahd.validate import retrace as rt

    print(f"{rt.RULE:<{width}}  {rt.DESCRIPTION} (--retrace N)", file=out)
    print(
        f"\n(UsdValidation validators {v.PLUGIN_NAME}:<rule>, keyword {v.KEYWORD}; "
        f"{rt.RULE} has keyword {rt.KEYWORD}; also run: {', '.join(v.BUILTIN_VALIDATORS)})",
        file=out,
    )


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
    from usdahd.validate.run import validate_file

    try:
        if retrace is not None:
            rt.OPTIONS = retrace
        report = validate_file(args.stage, args.prim, retrace=retrace is not None)
    finally:
        v.OPTIONS.iz_tolerance, v.OPTIONS.rmse_warning = old
        rt.OPTIONS = old_rt
    findings, baked, usd_notes = report.findings, report.prims, report.usd_diagnostics
    for ln in report.stderr:  # our own stderr output (progress, notices) is passed on as it was
        print(ln, file=sys.stderr)
    code = exit_code(findings, args.strict)
    counts = {s: sum(f.severity == s for f in findings) for s in ("error", "warning", "info")}
    if args.json:
        print(
            json.dumps(
                {
                    "stage": args.stage,
                    "prims": baked,
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
            print(f"  usd: {n}", file=sys.stderr)  # whole: the cause ends the message
    if not args.quiet:
        status = "FAILED" if code else "ok"
        note = "" if baked else " (no prim has AhdLightmapAPI)"
        print(
            f"{args.stage}: {status}: {counts['error']} error(s), {counts['warning']} "
            f"warning(s), {counts['info']} note(s) on {len(baked)} lightmapped prim(s){note}",
            file=sys.stderr,
        )
    return code
