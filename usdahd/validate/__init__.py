"""Asset-CI checks of baked AhdLightmapAPI prims, shared by ``usdahd validate`` and UsdValidation.

Each rule is a plain function ``check_<rule>(prim) -> list[Finding]`` with a name and a
one-sentence description (:data:`RULES`). The same functions are registered with USD's
validation framework as plugin prim validators named ``usdahd.validate:<Rule>`` (declared in
``plugins/usdAhdValidators/plugInfo.json`` with the keyword ``UsdAhdValidators`` and the schema
type ``UsdAhdAhdLightmapAPI``), so any pipeline that runs ``UsdValidation.ValidationContext``
with our plugin path gets exactly the findings ``usdahd validate`` prints.

Why the plugin module is this package: a ``"Type": "python"`` Plug plugin is loaded with
``import <plugin name>``, so its module must be importable from ``sys.path``; with only
``PXR_PLUGINPATH_NAME`` set, the one importable place that ships with usdahd is the ``usdahd``
package itself. Importing this package registers the implementations (:func:`register`).

Layout (one module per rule domain): ``registry`` (rule names and docs), ``options``
(tolerances), ``findings`` (Finding, JSON), ``loading`` (textures and the decoded bake),
``schema_values``, ``textures``, ``texel_values``, ``irradiance`` (IzCheck, EncodingError),
``staleness``, ``uvset``, ``atlas``, ``plugin`` (registration, :func:`run_rule`), ``run`` (what
``usdahd validate`` runs on a stage file); the opt-in Retrace rule is
:mod:`usdahd.validate.retrace`. No module here imports pxr: the rules read prims through
:mod:`usdahd.usd` (:mod:`usdahd.usd.inspect` for the small reads), and the UsdValidation glue
(tasks, error conversion, the ValidationContext) is :mod:`usdahd.usd.validation`.

Rules (see docs/validate.md for what each checks and how to fix it):

``SchemaValues``   tokens, required properties, version, resolution, model settings.
``Textures``       files resolve, open, and match the declared resolution/format/colour space.
``TexelValues``    no NaN/Inf, I_z >= 0, unit upper-hemisphere directions, w_a/C_a/C_d ranges.
``IzCheck``        decoded I_z equals the irradiance in z of the baked SH sidecar.
``EncodingError``  hemispherical RMSE of the decoded model against the SH target (report).
``Staleness``      the stored content hash still matches the stage.
``UVSet``          the lightmap UV primvar exists, lies in [0, 1], does not overlap.
``Atlas``          atlas records: whole-texel, 4-aligned rectangles inside their page,
                   disjoint and padded, one set of page files per page (``atlas``).
``Lightmapped``    (per stage) at least one prim has AhdLightmapAPI.
``Composition``    (per stage) composition problems once each: warnings unless a baked prim
                   is composed through them (``composition``).

Every finding message ends with what to do. Tolerances live in :class:`Options` (module-level
:data:`OPTIONS`, changed by ``usdahd validate --tolerance`` and friends).
"""

from __future__ import annotations

# The names other modules, tests and tools use, re-exported from their homes.
from usdahd import models  # noqa: F401  (V.models in tests)
from usdahd.numerics import sh as shm  # noqa: F401
from usdahd.usd import schema  # noqa: F401
from usdahd.validate.atlas import check_atlas  # noqa: F401
from usdahd.validate.composition import check_composition  # noqa: F401
from usdahd.validate.findings import (  # noqa: F401
    FINDING_DATA,
    Finding,
    RuleFindings,
    SkipRule,
    dumps,
    finding_from_usd,
    findings_json,
    jsonable,
)
from usdahd.validate.irradiance import (  # noqa: F401
    TOLERANCE_SLACK,
    check_encoding_error,
    check_iz,
    code_step,
    decoded_iz,
    quantization_tolerance,
)
from usdahd.validate.loading import (  # noqa: F401
    LOCK,
    Bake,
    Image,
    clear_caches,
    decode_factors,
    load_bake,
    read_image,
)
from usdahd.validate.options import (  # noqa: F401
    DZ_FLOOR,
    FORMAT_DTYPES,
    FORMAT_RELATIVE_TOLERANCE,
    HALF_ABSOLUTE_TOLERANCE,
    IRRADZ,
    MODEL_RMSE_NOTE,
    NONNEGATIVE_COLOURS,
    OIIO_FORMATS,
    OPTIONS,
    UNIT_TOLERANCE,
    Options,
)
from usdahd.validate.plugin import (  # noqa: F401
    CHECKS,
    check_lightmapped,
    register,
    run_rule,
)
from usdahd.validate.registry import (  # noqa: F401
    BUILTIN_VALIDATORS,
    COMPOSITION_RULE,
    KEYWORD,
    PLUGIN_NAME,
    RULE_NAMES,
    RULES,
    STAGE_RULE,
    STAGE_RULES,
    Rule,
    validator_name,
)
from usdahd.validate.schema_values import check_schema_values  # noqa: F401
from usdahd.validate.staleness import (  # noqa: F401
    check_staleness,
    settings_drift,
)
from usdahd.validate.texel_values import (  # noqa: F401
    check_texel_values,
)
from usdahd.validate.textures import (  # noqa: F401
    check_textures,
)
from usdahd.validate.uvset import (  # noqa: F401
    check_uv_set,
    overlap_statistic,
)

__all__ = [
    "BUILTIN_VALIDATORS",
    "FINDING_DATA",
    "Finding",
    "KEYWORD",
    "LOCK",
    "OPTIONS",
    "PLUGIN_NAME",
    "RULES",
    "RULE_NAMES",
    "STAGE_RULES",
    "SkipRule",
    "jsonable",
    "load_bake",
]

# Plug imports this package to load the plugin: register the implementations now.
register()

# Opt-in rules declared in the same plugInfo under their own keyword (not UsdAhdValidators).
from usdahd.validate import retrace as _retrace  # noqa: E402

_retrace.register()
