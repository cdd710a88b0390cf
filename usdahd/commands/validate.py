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

import json
import sys
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
    p.add_argument("--json", action="store_true", help="print a machine-readable report")
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
    p.add_argument("--list-rules", action="store_true", help="list the rules and exit")
    p.add_argument("--quiet", action="store_true", help="print errors and warnings only")
    p.set_defaults(func=run)
    return p


def list_rules(out=None) -> None:
    from usdahd import validate as v

    out = out or sys.stdout
    width = max(len(r.name) for r in v.RULES)
    for r in v.RULES:
        print(f"{r.name:<{width}}  {r.description}", file=out)
    print(
        f"\n(UsdValidation validators {v.PLUGIN_NAME}:<rule>, keyword {v.KEYWORD}; "
        f"also run: {', '.join(v.BUILTIN_VALIDATORS)})",
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


def context():
    """The ValidationContext ``usdahd validate`` uses: our keyword plus the built-ins."""
    from pxr import UsdValidation

    from usdahd import validate as v

    reg = UsdValidation.ValidationRegistry()
    metas = list(reg.GetValidatorMetadataForKeyword(v.KEYWORD))
    ours = {m.name for m in metas}
    missing = [v.validator_name(r) for r in v.RULE_NAMES if v.validator_name(r) not in ours]
    if missing:
        raise StageError(
            f"the usdahd validators are not registered ({', '.join(missing)}): USD's validation "
            "registry was created before usdahd registered its plugins; import usdahd first or "
            "set PXR_PLUGINPATH_NAME to the output of 'usdahd plugin-path'"
        )
    for name in v.BUILTIN_VALIDATORS:
        m = reg.GetValidatorMetadata(name)
        if m is not None:
            metas.append(m)
    return UsdValidation.ValidationContext(metadata=metas, includeAllAncestors=False)


def validate_stage(stage, prims: list[str] | None = None) -> list:
    """Run the validation context on a stage (or some prims); returns usdahd.validate.Finding."""
    from pxr import Sdf, Usd

    from usdahd import validate as v

    ctx = context()
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


def no_lightmaps_finding(path: str):
    """The error for a stage on which no prim has AhdLightmapAPI (nothing was validated)."""
    from usdahd import validate as v

    return v.Finding(
        "SchemaValues",
        "error",
        "/",
        "NoAhdLightmapAPI",
        f"no prim of {path} has {v.schema.API_NAME} applied, so there is no lightmap to "
        "validate. Fix: validate the baked override layer (usually NAME.lightmaps.usda), or "
        "bake the stage with usdahd bake",
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


def run(args) -> int:
    if args.list_rules:
        list_rules()
        return 0
    if not args.stage:
        raise UsageError("give a STAGE to validate (or --list-rules)")
    from usdahd import validate as v

    old = (v.OPTIONS.iz_tolerance, v.OPTIONS.rmse_warning)
    if args.tolerance is not None:
        if not args.tolerance > 0:
            raise UsageError(f"--tolerance {args.tolerance}: must be > 0")
        v.OPTIONS.iz_tolerance = args.tolerance
    if args.rmse_threshold is not None:
        if not args.rmse_threshold > 0:
            raise UsageError(f"--rmse-threshold {args.rmse_threshold}: must be > 0")
        v.OPTIONS.rmse_warning = args.rmse_threshold
    try:
        stage = _open(args.stage)
        from usdahd.usd import schema

        baked = [p for p in schema.prims_with_api(stage)]
        findings = validate_stage(stage, args.prim)
        if not baked:
            # A CI job pointed at the source stage (or the wrong file) must not stay green.
            findings.insert(0, no_lightmaps_finding(args.stage))
    finally:
        v.OPTIONS.iz_tolerance, v.OPTIONS.rmse_warning = old
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
    if not args.quiet:
        status = "FAILED" if code else "ok"
        note = "" if baked else " (no prim has AhdLightmapAPI)"
        print(
            f"{args.stage}: {status}: {counts['error']} error(s), {counts['warning']} "
            f"warning(s), {counts['info']} note(s) on {len(baked)} lightmapped prim(s){note}",
            file=sys.stderr,
        )
    return code
