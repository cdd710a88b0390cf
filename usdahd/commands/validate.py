"""``usdahd validate STAGE``: asset-CI checks of a baked stage through USD's validation framework.

A thin CLI over :func:`usdahd.validate.run.validate_file`, which runs a ``ValidationContext``
of our validators (keyword ``UsdAhdValidators``, see :mod:`usdahd.validate`) plus the built-in
validators that matter for a baked stage (:data:`usdahd.validate.BUILTIN_VALIDATORS`), so its
findings are the ones any UsdValidation run with our plugin path reports. One line per finding::

    error   </World/Quad> IzCheck: 3 texel(s) exceed the tolerance: ... Fix: re-bake the prim.

Exit status: 0 clean, 1 errors (warnings too with ``--strict``), 2 the stage could not be
validated (unreadable stage, validators missing, a rule that crashed).

Reports (:mod:`usdahd.validate.report`, docs/ci.md): ``--format text|json|junit|sarif`` and
``-o FILE``, both repeatable and paired in order; with ``-o`` each report is written atomically
to its file and stdout keeps the findings (text, or JSON with ``--json``); without ``-o`` one
``--format`` replaces the text on stdout. Usage errors of these flags are raised before the
validation runs.
"""

from __future__ import annotations

import os
import sys
import time

from usdahd.errors import UsageError
from usdahd.version import __version__


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
        "per prim with the baker's integrator and compare with the bake, and replay the bake's "
        "own random stream at texels sized to catch a 1 %% rescale of the files "
        "(costs time; docs/validate.md gives the cost per texel and the power)",
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
    p.add_argument(
        "--format",
        action="append",
        default=None,
        choices=("text", "json", "junit", "sarif"),
        help="report format: text (default), json (= --json), junit (JUnit XML, one test case "
        "per prim x rule) or sarif (SARIF 2.1.0); repeatable, paired in order with -o "
        "(docs/ci.md)",
    )
    p.add_argument(
        "-o",
        "--output",
        action="append",
        default=None,
        metavar="FILE",
        help="write the report of the matching --format to FILE (atomically) and keep the "
        "findings on stdout; repeatable: --format junit -o v.xml --format sarif -o v.sarif",
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
    from usdahd.validate.report import format_finding as fmt

    return fmt(f)


def _reports(args) -> tuple[str | None, list[tuple[str, str]]]:
    """(format printed on stdout or None for the default, [(format, file)] to write).

    Without -o one --format replaces the text on stdout; with -o each --format goes to its
    file (paired in order) and stdout keeps the findings (text, or JSON with --json)."""
    formats, outputs = list(args.format or []), list(args.output or [])
    if not outputs:
        if len(formats) > 1:
            raise UsageError(
                f"--format given {len(formats)} times without -o: only one report fits on "
                "stdout; pair each --format with -o FILE"
            )
        fmt = formats[0] if formats else None
        if args.json and fmt not in (None, "json"):
            raise UsageError(
                f"--json and --format {fmt} both want stdout: write the {fmt} report to a file "
                f"with -o FILE"
            )
        return fmt, []
    if len(formats) != len(outputs):
        raise UsageError(
            f"{len(formats)} --format for {len(outputs)} -o: give one --format before each -o "
            "(--format junit -o v.xml --format sarif -o v.sarif)"
        )
    if len(set(outputs)) != len(outputs):
        raise UsageError("-o: the same file given twice; give each report its own file")
    for f in outputs:
        if os.path.isdir(f):
            raise UsageError(f"-o {f}: is a directory; give a file name (e.g. {f}/validate.xml)")
        parent = os.path.dirname(os.path.abspath(f))
        if not os.path.isdir(parent):
            raise UsageError(f"-o {f}: the folder {parent} does not exist; create it first")
        if not os.access(parent, os.W_OK):
            raise UsageError(f"-o {f}: the folder {parent} is not writable; choose another -o")
    return None, list(zip(formats, outputs))


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
    stdout_format, files = _reports(args)  # usage errors before the (long) validation
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
    from usdahd.validate import report as R
    from usdahd.validate.run import validate_file

    started = time.perf_counter()
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
    if args.prim:  # the reports' test cases are the prims that were validated
        under = [q.rstrip("/") for q in args.prim]
        baked = [p for p in baked if any(p == q or p.startswith(q + "/") for q in under)]
    summary = R.Summary(
        stage=args.stage,
        findings=findings,
        prims=baked,
        prim_rules=[*v.RULE_NAMES, *([rt.RULE] if retrace is not None else [])],
        stage_rules=[*(r.name for r in v.STAGE_RULES), *v.BUILTIN_VALIDATORS],
        rule_docs=rule_docs(),
        exit_code=code,
        strict=args.strict,
        seconds=time.perf_counter() - started,
        usd_diagnostics=usd_notes,
        version=__version__,
    )
    for fmt, path in files:
        R.write_atomic(path, R.render(fmt, summary))
        if not args.quiet:
            print(f"wrote the {fmt} report to {path}", file=sys.stderr)
    if args.json or stdout_format == "json":
        print(R.json_report(summary))
        return code
    if stdout_format in ("junit", "sarif"):
        sys.stdout.write(R.render(stdout_format, summary))
    else:
        sys.stdout.write(R.text(summary, quiet=bool(args.quiet)))
    if usd_notes and not args.quiet:
        print(
            f"note: USD printed {len(usd_notes)} diagnostic(s) while validating:", file=sys.stderr
        )
        for n in usd_notes[:10]:
            print(f"  usd: {n}", file=sys.stderr)  # whole: the cause ends the message
    if not args.quiet:
        print(R.summary_line(summary), file=sys.stderr)
    return code


def rule_docs() -> dict[str, str]:
    """Rule id -> one-sentence description: ours from the registry (the plugInfo docs), USD's
    built-ins from USD's validation registry."""
    from usdahd import validate as v
    from usdahd.usd.validation import validator_doc
    from usdahd.validate import retrace as rt

    docs = {r.name: r.description for r in (*v.RULES, *v.STAGE_RULES)}
    docs[rt.RULE] = rt.DESCRIPTION
    for name in v.BUILTIN_VALIDATORS:
        docs[name] = validator_doc(name)
    return docs
