"""Registration of the rules with UsdValidation (prim validators + the stage rule ``Lightmapped``)
and the plain-function path :func:`run_rule`. The UsdValidation calls themselves (tasks, error
conversion, the registry) are in :mod:`usdahd.usd.validation`.
"""

from __future__ import annotations

from usdahd.usd import schema
from usdahd.usd import validation as usd_validation
from usdahd.validate.atlas import check_atlas
from usdahd.validate.composition import check_composition
from usdahd.validate.findings import FINDING_DATA, Finding
from usdahd.validate.irradiance import check_encoding_error, check_iz
from usdahd.validate.loading import LOCK
from usdahd.validate.registry import COMPOSITION_RULE, RULE_NAMES, STAGE_RULE, validator_name
from usdahd.validate.schema_values import check_schema_values
from usdahd.validate.staleness import check_staleness
from usdahd.validate.texel_values import check_texel_values
from usdahd.validate.textures import check_textures
from usdahd.validate.uvset import check_uv_set

__all__ = ["CHECKS", "check_lightmapped", "register", "run_rule"]

# ------------------------------------------------------------------------------ registration

CHECKS = {
    "SchemaValues": check_schema_values,
    "Textures": check_textures,
    "TexelValues": check_texel_values,
    "IzCheck": check_iz,
    "EncodingError": check_encoding_error,
    "Staleness": check_staleness,
    "UVSet": check_uv_set,
    "Atlas": check_atlas,
}
assert tuple(CHECKS) == RULE_NAMES


def run_rule(rule: str, prim) -> list[Finding]:
    """Run one rule on one prim; an exception becomes an ``InternalError`` error finding.

    (An exception escaping a Python validator would abort the whole UsdValidation run.)
    """
    if not schema.has_api(prim):
        return []
    try:
        return CHECKS[rule](prim)
    except Exception as exc:  # noqa: BLE001 - reported, never raised (see above)
        msg = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0][:300] if str(exc) else ''}"
        return [
            Finding(
                rule,
                "error",
                str(prim.GetPath()),
                "InternalError",
                f"rule {rule} could not run: {msg}. Fix: report this as a usdahd bug "
                "(with the stage) and check the prim by hand.",
            )
        ]


def _recorded(rule: str):
    """``run_rule(rule, prim)``, keeping each finding's data in FINDING_DATA (UsdValidation
    carries only the message; ``usdahd validate --json`` adds the numbers back from there)."""

    def check(prim):
        found = run_rule(rule, prim)
        with LOCK:
            for f in found:
                FINDING_DATA[(f.rule, f.prim, f.code, f.message)] = f.data
            while len(FINDING_DATA) > 10000:
                FINDING_DATA.pop(next(iter(FINDING_DATA)))
        return found

    return check


def _task(rule: str):
    """The UsdValidation prim task of a rule."""
    return usd_validation.prim_task(rule, _recorded(rule))


def register() -> list[str]:
    """Register every rule's implementation with UsdValidation (idempotent).

    Only rules whose metadata the plugInfo declared are registered (USD refuses the others);
    returns the names registered by this call.
    """
    done = []
    for rule in RULE_NAMES:
        name = validator_name(rule)
        if usd_validation.register_validator(name, _task(rule)):
            done.append(name)
    name = validator_name(STAGE_RULE.name)
    if usd_validation.register_validator(name, _stage_task, stage=True):
        done.append(name)
    name = validator_name(COMPOSITION_RULE.name)
    if usd_validation.register_validator(name, _composition_task, stage=True):
        done.append(name)
    return done


def check_lightmapped(stage) -> list[Finding]:
    """Rule Lightmapped on a whole stage: one ``NoAhdLightmapAPI`` error on ``/`` when no prim
    has the API (nothing else would be validated, and a CI job must not stay green)."""
    if any(True for _ in schema.prims_with_api(stage)) or schema.instance_carriers(stage):
        return []  # mesh records, or instance records only (a PointInstancer's copies)
    layer = stage.GetRootLayer()
    where = layer.realPath or layer.identifier
    return [
        Finding(
            STAGE_RULE.name,
            "error",
            "/",
            "NoAhdLightmapAPI",
            f"no prim of {where} has {schema.API_NAME} applied, so there is no lightmap to "
            "validate. Fix: validate the baked override layer (usually NAME.lightmaps.usda), or "
            "bake the stage with usdahd bake",
        )
    ]


#: The UsdValidation stage task of Lightmapped.
_stage_task = usd_validation.stage_task(STAGE_RULE.name, check_lightmapped)


def _recorded_stage(check):
    """``check(stage)``, keeping each finding's data in FINDING_DATA (see :func:`_recorded`)."""

    def run(stage):
        found = check(stage)
        with LOCK:
            for f in found:
                FINDING_DATA[(f.rule, f.prim, f.code, f.message)] = f.data
        return found

    return run


#: The UsdValidation stage task of Composition.
_composition_task = usd_validation.stage_task(
    COMPOSITION_RULE.name, _recorded_stage(check_composition)
)
