"""Rule ``SchemaValues``: AhdLightmapAPI values are valid."""

from __future__ import annotations

from usdahd import models
from usdahd.usd import inspect, schema
from usdahd.validate.findings import Finding, RuleFindings

__all__ = ["check_schema_values"]

# ----------------------------------------------------------------------- rule 1: SchemaValues


def check_schema_values(prim) -> list[Finding]:
    """Rule SchemaValues (see RULES)."""
    r = RuleFindings("SchemaValues", prim)
    defn = inspect.api_definition()
    ns = schema.NAMESPACE + ":"
    version_attr = prim.GetAttribute(schema.property_name("baked:formatVersion"))
    old = int((version_attr.Get() if version_attr else 0) or 0) in schema.OLD_FORMAT_VERSIONS
    for attr in prim.GetAuthoredAttributes():
        name = attr.GetName()
        if not name.startswith(ns):
            continue
        adef = defn.GetAttributeDefinition(name) if defn else None
        if not adef and old:
            continue  # a property of the older layout: RebakeNeeded below says it all
        if not adef:
            r.warning(
                "UnknownProperty",
                f"{name} is not a property of {schema.API_NAME} (a typo or an old layout)",
                "rename or remove it; docs/schema.md lists the properties",
            )
            continue
        allowed = adef.GetMetadata("allowedTokens")
        if allowed:
            v = attr.Get()
            if v is not None and str(v) not in list(allowed):
                r.error(
                    "TokenNotAllowed",
                    f"{name} = {str(v)!r} is not one of its allowedTokens "
                    f"({', '.join(allowed)}); USD does not enforce allowedTokens",
                    f"author one of {', '.join(allowed)}",
                    property=name,
                    value=str(v),
                )
    inputs = schema.read_inputs(prim, validate=False)
    for p in schema.input_problems(inputs):
        if "is not one of" in p:
            continue  # reported generically above with the authored token
        r.error("InvalidInput", p, "author a valid value (docs/schema.md gives the ranges)")
    if inputs.model in models.REGISTRY and inputs.solver:
        try:
            mod = models.get(inputs.model)
            problem = models.choice_problem(
                inputs.model,
                "solver",
                inputs.solver,
                mod.SOLVERS,
                "ahdLightmap:solver = {value!r} is not a solver of model {model!r} ({allowed})",
            )
            if problem is not None:
                r.error(
                    "SolverNotInModel",
                    problem,
                    "author one of those, or an empty string for the model's default",
                )
        except Exception:
            pass
    version = prim.GetAttribute(schema.property_name("baked:formatVersion")).Get() or 0
    if int(version) == 0:
        if inputs.bake:
            r.warning(
                "NotBaked",
                "the prim has AhdLightmapAPI with bake on but no bake results "
                "(ahdLightmap:baked:formatVersion is 0)",
                "run usdahd bake on the stage, or set ahdLightmap:bake = false",
            )
        return r.out
    if int(version) in schema.OLD_FORMAT_VERSIONS:
        r.error(
            "RebakeNeeded",
            f"re-bake needed: ahdLightmap:baked:formatVersion = {version} is the texture layout "
            f"of an older usdahd; this one reads version "
            f"{', '.join(map(str, schema.KNOWN_FORMAT_VERSIONS))} (docs/schema.md, Versions). "
            "The textures are not checked",
            "re-bake the stage with this usdahd (usdahd bake --force)",
            version=int(version),
        )
        return r.out
    if int(version) not in schema.KNOWN_FORMAT_VERSIONS:
        r.error(
            "UnknownVersion",
            f"ahdLightmap:baked:formatVersion = {version} is not a version this usdahd reads "
            f"({', '.join(map(str, schema.KNOWN_FORMAT_VERSIONS))})",
            "re-bake with this usdahd, or validate with the usdahd that wrote it",
        )
        return r.out
    required = ["baked:resolution", "baked:model", "baked:ratio", "baked:uvPrimvar"]
    required += ["baked:contentHash", "baked:formatVersion"]
    for key in required:
        attr = prim.GetAttribute(schema.property_name(key))
        if not attr.HasAuthoredValue():
            r.error(
                "MissingProperty",
                f"{schema.property_name(key)} is not authored although the prim is baked",
                "re-bake the prim (usdahd bake writes every result property)",
            )
    try:
        results = schema.read_results(prim, validate=False)
    except Exception as exc:
        r.error("UnreadableRecord", f"the bake record cannot be read: {exc}", "re-bake the prim")
        return r.out
    for p in schema.result_problems(results):
        if "is not one of" in p and ("model" in p or "ratio" in p or "tangent" in p):
            continue  # the token check above names the property
        r.error("InvalidResult", p, "re-bake the prim")
    if results.model not in models.REGISTRY:
        return r.out
    try:
        mod = models.get(results.model)
    except Exception as exc:
        r.error("ModelUnavailable", f"model {results.model!r}: {exc}", "install a usdahd with it")
        return r.out
    problem = models.choice_problem(
        results.model,
        "ratio",
        results.ratio,
        mod.RATIOS,
        "baked ratio {value!r} is not a ratio type of model {model!r} ({allowed})",
    )
    if problem is not None:
        r.error("RatioNotInModel", problem, "re-bake the prim")
        return r.out
    problem = results.solver and models.choice_problem(
        results.model,
        "solver",
        results.solver,
        mod.SOLVERS,
        "baked solver {value!r} is not a solver of model {model!r}",
    )
    if problem:
        r.error("SolverNotInModel", problem, "re-bake the prim")
    if results.model != "hlsh" and results.factor("ratioScale") != 1.0:
        r.error(
            "FactorNotInModel",
            f"ahdLightmap:baked:ratioScale = {results.factor('ratioScale')} but only hlsh "
            "scales its ratio; engines decoding per docs/schema.md would read w_a outside [0, 1]",
            "re-bake the prim",
        )
    needed = [t.role for t in mod.layout(results.ratio)]
    for role in needed:
        if role not in results.textures:
            r.error(
                "MissingTexture",
                f"{schema.file_property_name(role)} is not authored but model "
                f"{results.model!r} needs it",
                "re-bake the prim",
            )
    want_packing = {t.role: t.packing for t in mod.layout(results.ratio)}
    for role in needed:
        got = results.packing.get(role)
        if role in results.textures and got != want_packing[role]:
            r.error(
                "Packing",
                f"{schema.packing_property_name(role)} = {got or '(not authored)'!r} but model "
                f"{results.model!r} with ratio {results.ratio!r} writes {want_packing[role]!r}",
                "re-bake the prim (engines read the channels as the packing attribute says)",
                property=schema.packing_property_name(role),
            )
    for role in results.textures:
        if role not in needed and role != schema.SIDECAR_ROLE:
            r.warning(
                "ExtraTexture",
                f"{schema.file_property_name(role)} is authored but model {results.model!r} "
                "does not use it (left over from another bake?)",
                "clear the property or re-bake the prim",
            )
    if schema.SIDECAR_ROLE not in results.textures:
        r.warning(
            "NoSidecar",
            "ahdLightmap:sidecar:sh is not authored, so IzCheck and EncodingError cannot run",
            "bake with the SH sidecar (usdahd bake writes it by default)",
        )
    return r.out
