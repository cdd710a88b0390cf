"""Rule names, descriptions (the plugInfo ``doc`` strings) and UsdValidation names."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "BUILTIN_VALIDATORS",
    "COMPOSITION_RULE",
    "KEYWORD",
    "PLUGIN_NAME",
    "RULES",
    "RULE_NAMES",
    "Rule",
    "STAGE_RULE",
    "STAGE_RULES",
    "validator_name",
]

# ------------------------------------------------------------------------------------ rules

#: Plug plugin name (= this module, see the module doc) and validator keyword.
PLUGIN_NAME = "usdahd.validate"
KEYWORD = "UsdAhdValidators"
#: Built-in validators that matter for a baked stage, run by ``usdahd validate`` too.
#: (usdValidation:CompositionErrorTest is replaced by our Composition rule, which tells composition
#: errors that touch a baked prim (errors) from the rest (warnings).)
BUILTIN_VALIDATORS = (
    "usdUtilsValidators:MissingReferenceValidator",
    "usdValidation:AttributeTypeMismatch",
)


@dataclass(frozen=True)
class Rule:
    """name : validator suffix; description : one sentence (also the plugInfo ``doc``)."""

    name: str
    description: str


RULES = (
    Rule(
        "SchemaValues",
        "AhdLightmapAPI values are valid: tokens within allowedTokens, required results "
        "authored, a known format version, positive resolutions, and settings the model supports.",
    ),
    Rule(
        "Textures",
        "Every lightmap texture resolves, opens with OpenImageIO, and has the resolution, "
        "channel count, data format and colour space the schema declares (UDIM sets complete; "
        "an atlas record's rectangle in its page).",
    ),
    Rule(
        "TexelValues",
        "Decoded texels hold no NaN/Inf, I_z >= 0, unit upper-hemisphere directions with "
        "d_z >= 1/127, and w_a, C_a, C_d within the model's range.",
    ),
    Rule(
        "IzCheck",
        "At every covered texel the I_z an engine decodes (quantization included) matches the "
        "irradiance in local z of the baked SH sidecar within the storage format's tolerance.",
    ),
    Rule(
        "EncodingError",
        "Reports the hemispherical RMSE of the decoded model against the baked SH irradiance "
        "per prim, warning when the textures add more than a threshold to the model's own fit.",
    ),
    Rule(
        "Staleness",
        "The bake's stored content hash still matches the current stage (geometry, UVs, "
        "lights, materials and settings unchanged since the bake).",
    ),
    Rule(
        "UVSet",
        "The lightmap UV primvar exists, lies in [0, 1], has no overlapping texels beyond a "
        "tolerance, and a sane texel density.",
    ),
    Rule(
        "Atlas",
        "A record in an atlas page has a whole-texel, 4-aligned rectangle inside its page, "
        "disjoint from and at least 2 texels away from the other rectangles of the page, "
        "whose records name the same page files.",
    ),
)
RULE_NAMES = tuple(r.name for r in RULES)

#: The one stage-level rule (a UsdValidation stage validator: no schema type, runs once per stage).
STAGE_RULE = Rule(
    "Lightmapped",
    "At least one prim of the stage has AhdLightmapAPI applied, so a CI job pointed at the "
    "source stage instead of its baked override layer fails.",
)


#: The second stage rule: composition problems, warnings unless a baked prim goes through them
#: (usdahd.validate.composition).
COMPOSITION_RULE = Rule(
    "Composition",
    "Composition problems of the stage (arcs USD could not compose, broken arcs in unselected "
    "variants) are reported once each: errors when a baked prim is composed through them, "
    "warnings otherwise.",
)
#: Every stage rule (UsdValidation stage validators: no schema type, run once per stage).
STAGE_RULES = (STAGE_RULE, COMPOSITION_RULE)


def validator_name(rule: str) -> str:
    """UsdValidation name of a rule: ``usdahd.validate:IzCheck``."""
    return f"{PLUGIN_NAME}:{rule}"
