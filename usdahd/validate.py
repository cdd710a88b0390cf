"""Asset-CI checks of baked AhdLightmapAPI prims, shared by ``usdahd validate`` and UsdValidation.

Each rule is a plain function ``check_<rule>(prim) -> list[Finding]`` with a name and a
one-sentence description (:data:`RULES`). The same functions are registered with USD's
validation framework as plugin prim validators named ``usdahd.validate:<Rule>`` (declared in
``plugins/usdAhdValidators/plugInfo.json`` with the keyword ``UsdAhdValidators`` and the schema
type ``UsdAhdAhdLightmapAPI``), so any pipeline that runs ``UsdValidation.ValidationContext``
with our plugin path gets exactly the findings ``usdahd validate`` prints.

Why the plugin module is this module: a ``"Type": "python"`` Plug plugin is loaded with
``import <plugin name>``, so its module must be importable from ``sys.path``; with only
``PXR_PLUGINPATH_NAME`` set, the one importable place that ships with usdahd is the ``usdahd``
package itself. Importing this module registers the implementations (:func:`register`).

Rules (see docs/validate.md for what each checks and how to fix it):

``SchemaValues``   tokens, required properties, version, resolution, model settings.
``Textures``       files resolve, open, and match the declared resolution/format/colour space.
``TexelValues``    no NaN/Inf, I_z >= 0, unit upper-hemisphere directions, w_a/C_a/C_d ranges.
``IzCheck``        decoded I_z equals the irradiance in z of the baked SH sidecar.
``EncodingError``  hemispherical RMSE of the decoded model against the SH target (report).
``Staleness``      the stored content hash still matches the stage.
``UVSet``          the lightmap UV primvar exists, lies in [0, 1], does not overlap.

Every finding message ends with what to do. Tolerances live in :class:`Options` (module-level
:data:`OPTIONS`, changed by ``usdahd validate --tolerance`` and friends).
"""

from __future__ import annotations

import json
import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation  # noqa: E402,I001

from usdahd import models
from usdahd.numerics import encoding
from usdahd.numerics import sh as shm
from usdahd.usd import schema

# ------------------------------------------------------------------------------------ rules

#: Plug plugin name (= this module, see the module doc) and validator keyword.
PLUGIN_NAME = "usdahd.validate"
KEYWORD = "UsdAhdValidators"
#: Built-in validators that matter for a baked stage, run by ``usdahd validate`` too.
BUILTIN_VALIDATORS = (
    "usdUtilsValidators:MissingReferenceValidator",
    "usdValidation:AttributeTypeMismatch",
    "usdValidation:CompositionErrorTest",
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
        "channel count, data format and colour space the schema declares (UDIM sets complete).",
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
)
RULE_NAMES = tuple(r.name for r in RULES)

#: The one stage-level rule (a UsdValidation stage validator: no schema type, runs once per stage).
STAGE_RULE = Rule(
    "Lightmapped",
    "At least one prim of the stage has AhdLightmapAPI applied, so a CI job pointed at the "
    "source stage instead of its baked override layer fails.",
)


def validator_name(rule: str) -> str:
    """UsdValidation name of a rule: ``usdahd.validate:IzCheck``."""
    return f"{PLUGIN_NAME}:{rule}"


# ------------------------------------------------------------------------------- tolerances


@dataclass
class Options:
    """Every tolerance of the rules, with the reason for its default.

    iz_tolerance : relative I(z) tolerance (times the texel's brightest reference channel);
        None (default) derives it per texel from the codes' quantization
        (:func:`quantization_tolerance`).
    rmse_warning : relative hemispherical RMSE (per prim) of the decoded textures against the
        model's own unquantized fit above which EncodingError warns; 0.25 is 4x the largest
        quantization error measured on the samples (hlsh, whose 8-bit w_a spans up to +-16:
        0.061; float16 models ~3e-4) and well below a wrong decode (order 1). The model's own
        fit error is reported, not warned about: it is a choice of model, not a defect.
    rmse_normals : normals of the hemispherical RMSE (spherical Fibonacci, upper hemisphere).
    rmse_max_texels : texels sampled (evenly) for the RMSE, so big lightmaps stay fast.
    uv_epsilon : UVs may leave [0, 1] by this much (float32 rounding of authored 0 and 1).
    uv_overlap : fraction of covered texels whose centre lies in two triangles that still
        passes; shared edges can double-count a centre that lies exactly on them.
    density_spread : area-weighted 90th/10th percentile ratio of texel density that warns.
    """

    iz_tolerance: float | None = None
    rmse_warning: float = 0.25
    rmse_normals: int = 64
    rmse_max_texels: int = 20000
    uv_epsilon: float = 1e-5
    uv_overlap: float = 0.005
    density_spread: float = 4.0


OPTIONS = Options()
#: Model fit RMSE above which the EncodingError note suggests a closer-fitting model.
MODEL_RMSE_NOTE = 0.25

#: Relative rounding bound of a stored value by storage format (documentation and tests; IzCheck
#: derives its tolerance per texel, :func:`quantization_tolerance`): float16 rounds to nearest
#: with a relative error <= 2^-11 = 4.88e-4 (normal range), so 5e-4; float32 2^-24, so 1e-6.
FORMAT_RELATIVE_TOLERANCE = {"half": 5e-4, "float": 1e-6}
#: Absolute tolerance (times the decode scale) for values in float16's subnormal range, where
#: the spacing is 2^-24 (rounding error <= 2^-25).
HALF_ABSOLUTE_TOLERANCE = 2.0**-24
#: The smallest decoded d_z an 8-bit hemi-octahedral code may have (encoding.DZ_MIN = 1/127),
#: minus float32 rounding of the decode.
DZ_FLOOR = encoding.DZ_MIN * (1.0 - 1e-5)
#: Decoded directions must be unit length to this (float32 normalise).
UNIT_TOLERANCE = 1e-4
#: OpenImageIO format name -> schema storage format.
OIIO_FORMATS = {"half": "half", "float": "float", "uint8": "unorm8", "int8": "snorm8"}
FORMAT_DTYPES = {"half": np.float16, "float": np.float32, "unorm8": np.uint8, "snorm8": np.int8}
IRRADZ = ("ahd", "hhd", "hlsh")
#: Models whose colours must be non-negative (HLSH may have C_d < 0; linear bases ring).
NONNEGATIVE_COLOURS = ("ahd", "hhd", "ahd_classic", "hemisphere")


# --------------------------------------------------------------------------------- findings

SEVERITIES = ("error", "warning", "info")
_TYPES = {
    "error": UsdValidation.ValidationErrorType.Error,
    "warning": UsdValidation.ValidationErrorType.Warn,
    "info": UsdValidation.ValidationErrorType.Info,
}


@dataclass
class Finding:
    """One result of a rule on a prim.

    rule : a RULE_NAMES entry; severity : error, warning or info; prim : prim path;
    code : short machine name of the defect (the UsdValidation error name); message : what is
    wrong, ending with what to do; data : numbers behind the message (JSON-serialisable).
    """

    rule: str
    severity: str
    prim: str
    code: str
    message: str
    data: dict = field(default_factory=dict)

    def to_usd(self, stage) -> UsdValidation.ValidationError:
        site = UsdValidation.ValidationErrorSite(stage, Sdf.Path(self.prim))
        return UsdValidation.ValidationError(self.code, _TYPES[self.severity], [site], self.message)


class _Rule:
    """Collects findings of one rule on one prim."""

    def __init__(self, rule: str, prim):
        self.rule, self.prim, self.out = rule, str(prim.GetPath()), []

    def add(self, severity: str, code: str, message: str, fix: str = "", **data):
        text = message.rstrip(".") + "." + (f" Fix: {fix.rstrip('.')}." if fix else "")
        self.out.append(Finding(self.rule, severity, self.prim, code, text, _jsonable(data)))

    def error(self, code, message, fix="", **data):
        self.add("error", code, message, fix, **data)

    def warning(self, code, message, fix="", **data):
        self.add("warning", code, message, fix, **data)

    def info(self, code, message, fix="", **data):
        self.add("info", code, message, fix, **data)


def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            v = str(v)
        if isinstance(v, tuple | np.ndarray):
            v = np.asarray(v).tolist()
        out[k] = v
    return out


class _Skip(Exception):
    """Prerequisite data missing; another rule reports why (becomes an info finding)."""


# ------------------------------------------------------------------------------ image reading


@dataclass
class Image:
    """A texture read through OpenImageIO. data : (h, w, c) in the file's native dtype."""

    path: str
    data: np.ndarray
    format: str  # OIIO format name (half, float, uint8, int8, ...)
    channel_names: tuple[str, ...]
    color_space: str

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    def channels(self, names) -> np.ndarray:
        """(h, w, len(names)) channels looked up by name (EXR stores them sorted)."""
        idx = []
        for n in names:
            if n not in self.channel_names:
                raise KeyError(n)
            idx.append(self.channel_names.index(n))
        return self.data[..., idx]


_IMAGE_CACHE: OrderedDict = OrderedDict()
_IMAGE_CACHE_SIZE = 16
_LOCK = threading.Lock()


def read_image(path: str) -> Image:
    """Read a whole image in its native format (cached by path, size and mtime).

    Raises OSError with OpenImageIO's message when the file cannot be opened.
    """
    from usdahd.usd import assets

    key = assets.stamp(path)
    if key is None:
        if not assets.exists(path):
            raise FileNotFoundError(f"{path} does not exist")
    with _LOCK:
        if key is not None and key in _IMAGE_CACHE:
            _IMAGE_CACHE.move_to_end(key)
            return _IMAGE_CACHE[key]
    with assets.local_file(path) as local:  # a file, or an asset in a package (Ar)
        img = _read_local(local, path)
    if key is not None:
        with _LOCK:
            _IMAGE_CACHE[key] = img
            while len(_IMAGE_CACHE) > _IMAGE_CACHE_SIZE:
                _IMAGE_CACHE.popitem(last=False)
    return img


def _read_local(local: str, path: str) -> Image:
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # PNG alpha is data: never premultiply
    inp = oiio.ImageInput.open(local, config)
    if inp is None:
        raise OSError(oiio.geterror() or f"OpenImageIO cannot open {path}")
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, oiio.UNKNOWN)
        if data is None:
            raise OSError(inp.geterror() or f"OpenImageIO cannot read the pixels of {path}")
        data = np.asarray(data).reshape(spec.height, spec.width, spec.nchannels)
        img = Image(
            path=path,
            data=data,
            format=str(spec.format),
            channel_names=tuple(spec.channelnames),
            color_space=spec.get_string_attribute("oiio:ColorSpace", ""),
        )
    finally:
        inp.close()
    return img


# ---------------------------------------------------------------------------- bake loading


@dataclass
class Bake:
    """A prim's bake, decoded once for the texel rules.

    results : the schema record; mod : model module; layout : role -> TextureLayout;
    xy : (n, 2) int32 texel column/row of the texels considered (covered ones, or every texel
    without a sidecar); channels : role -> (n, c) stored values in the layout's dtype;
    params : decoded model parameters for those texels; sh : (n, 3, 9) float64 sidecar SH or
    None; valid : (n,) bool texels whose decoded values pass TexelValues.
    """

    results: schema.BakeResults
    mod: object
    layout: dict
    resolution: tuple[int, int]
    xy: np.ndarray
    channels: dict
    params: dict
    sh: np.ndarray | None
    factors: dict
    valid: np.ndarray


def decode_factors(results: schema.BakeResults) -> dict:
    """Factors for a model's ``decode``: every schema factor (authored value or fallback)."""
    return {name: results.factor(name) for name in schema.FACTORS}


_BAKE_CACHE: OrderedDict = OrderedDict()


def _bake_key(prim, results) -> tuple:
    stamps = []
    from usdahd.usd import assets

    for role, path in sorted(results.textures.items()):
        stamps.append((role, path, assets.stamp(path)))
    rec = (results.model, results.ratio, results.resolution, tuple(sorted(results.factors.items())))
    return (str(prim.GetPath()), rec, tuple(stamps))


def load_bake(prim) -> Bake:
    """Read and decode a prim's textures; raises _Skip when another rule reports the cause."""
    try:
        results = schema.read_results(prim, validate=False)
    except Exception as exc:
        raise _Skip(f"bake record unreadable ({exc}); see SchemaValues") from None
    if results is None:
        raise _Skip("the prim is not baked; see SchemaValues")
    if schema.result_problems(results):
        raise _Skip("invalid bake record; see SchemaValues")
    key = _bake_key(prim, results)
    with _LOCK:
        if key in _BAKE_CACHE:
            _BAKE_CACHE.move_to_end(key)
            return _BAKE_CACHE[key]
    bake = _load_bake(results)
    with _LOCK:
        _BAKE_CACHE[key] = bake
        while len(_BAKE_CACHE) > 4:
            _BAKE_CACHE.popitem(last=False)
    return bake


def _load_bake(results) -> Bake:
    try:
        mod = models.get(results.model)
        layout = {t.role: t for t in mod.layout(results.ratio)}
    except Exception as exc:
        raise _Skip(f"model settings unusable ({exc}); see SchemaValues") from None
    w, h = results.resolution
    images = {}
    for role, lay in layout.items():
        path = results.textures.get(role)
        if path is None or "<UDIM>" in results.asset_paths.get(role, ""):
            raise _Skip(f"texture {role!r} missing or a UDIM set; see Textures")
        try:
            img = read_image(path)
        except OSError:
            raise _Skip(f"texture {role!r} unreadable; see Textures") from None
        if (img.width, img.height) != (w, h) or set(img.channel_names) != set(lay.channels):
            raise _Skip(f"texture {role!r} has the wrong shape or channels; see Textures")
        images[role] = img
    sh = cov = None
    sc = results.textures.get(schema.SIDECAR_ROLE)
    if sc is not None:
        try:
            img = read_image(sc)
            if (img.width, img.height) == (w, h):
                data = img.channels(schema.SH_SIDECAR_CHANNELS).astype(np.float64)
                sh = data[..., :27].reshape(h, w, 3, 9)
                cov = data[..., 27] > 0.5
        except (OSError, KeyError):
            sh = cov = None  # Textures reports it
    if cov is None:
        ys, xs = np.mgrid[0:h, 0:w]
        xy = np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.int32)
    else:
        ys, xs = np.nonzero(cov)
        xy = np.stack([xs, ys], axis=-1).astype(np.int32)
    # Channels by name, in the layout's order (EXR stores them sorted, so never by position).
    channels = {
        role: images[role]
        .channels(lay.channels)[xy[:, 1], xy[:, 0]]
        .astype(FORMAT_DTYPES[lay.format])
        for role, lay in layout.items()
    }
    factors = decode_factors(results)
    try:
        with np.errstate(all="ignore"):
            params = mod.decode(channels, ratio=results.ratio, factors=factors)
    except Exception as exc:
        raise _Skip(f"the textures do not decode ({exc}); see Textures") from None
    params = {k: np.asarray(v) for k, v in params.items()}
    valid = np.ones(len(xy), bool)
    for k, v in params.items():
        if k != "invalid" and v.dtype.kind == "f":
            valid &= np.isfinite(v.reshape(len(xy), -1)).all(axis=1)
    if "direction" in params:
        valid &= params["direction"][:, 2] >= DZ_FLOOR
    if sh is not None:
        sh = sh[xy[:, 1], xy[:, 0]]
    return Bake(results, mod, layout, (w, h), xy, channels, params, sh, factors, valid)


# ----------------------------------------------------------------------- rule 1: SchemaValues


def _prim_definition():
    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(schema.API_NAME)


def check_schema_values(prim) -> list[Finding]:
    """Rule SchemaValues (see RULES)."""
    r = _Rule("SchemaValues", prim)
    defn = _prim_definition()
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
            if inputs.solver not in mod.SOLVERS:
                r.error(
                    "SolverNotInModel",
                    f"ahdLightmap:solver = {inputs.solver!r} is not a solver of model "
                    f"{inputs.model!r} ({', '.join(mod.SOLVERS)})",
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
    if results.ratio not in mod.RATIOS:
        r.error(
            "RatioNotInModel",
            f"baked ratio {results.ratio!r} is not a ratio type of model {results.model!r} "
            f"({', '.join(mod.RATIOS)})",
            "re-bake the prim",
        )
        return r.out
    if results.solver and results.solver not in mod.SOLVERS:
        r.error(
            "SolverNotInModel",
            f"baked solver {results.solver!r} is not a solver of model {results.model!r}",
            "re-bake the prim",
        )
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


# --------------------------------------------------------------------------- rule 2: Textures


def _udim_tiles(prim, asset: str, attr) -> list[tuple[int, str]]:
    layer = None
    for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
        if spec.HasDefaultValue():
            layer = spec.layer
            break
    tiles = UsdShade.UdimUtils.ResolveUdimTilePaths(asset, layer) if layer else []
    return [(int(t[1]), str(t[0])) for t in tiles]


def _uv_tiles(prim, uv_name: str) -> set[int]:
    uv = _read_uvs(prim, uv_name)
    if uv is None:
        return set()
    u = np.floor(uv[..., 0].mean(axis=1)).astype(int)
    v = np.floor(uv[..., 1].mean(axis=1)).astype(int)
    return {1001 + a + 10 * b for a, b in zip(u, v) if 0 <= a < 10 and b >= 0}


def check_textures(prim) -> list[Finding]:
    """Rule Textures (see RULES)."""
    from usdahd.usd import assets

    r = _Rule("Textures", prim)
    try:
        results = schema.read_results(prim, validate=False)
    except Exception:
        return r.out  # SchemaValues reports it
    if results is None or results.format_version not in schema.KNOWN_FORMAT_VERSIONS:
        return r.out  # SchemaValues reports the version (RebakeNeeded / UnknownVersion)
    try:
        layout = {t.role: t for t in models.get(results.model).layout(results.ratio)}
    except Exception:
        layout = {}
    w, h = results.resolution
    for role in results.textures:
        prop = schema.file_property_name(role)
        attr = prim.GetAttribute(prop)
        asset = results.asset_paths.get(role, "")
        want_cs = schema.COLOR_SPACES.get(role)
        cs = attr.GetColorSpace() if attr.HasColorSpace() else ""
        if want_cs and cs != want_cs:
            r.error(
                "ColorSpace",
                f"{prop} has colorSpace {cs or '(none)'!r}, the schema declares {want_cs!r}",
                f"author colorSpace = {want_cs!r} on {prop} (or re-bake)",
                property=prop,
            )
        if "<UDIM>" in asset:
            tiles = _udim_tiles(prim, asset, attr)
            have = {t for t, _ in tiles}
            want = _uv_tiles(prim, results.uv_primvar)
            missing = sorted(want - have)
            if not tiles or missing:
                r.error(
                    "UdimIncomplete",
                    f"{prop} @{asset}@ is a UDIM set missing tile(s) "
                    f"{', '.join(map(str, missing)) or '(all)'} that the UVs use",
                    "write the missing tiles or re-bake",
                    property=prop,
                    missing=missing,
                )
            files = [(f"tile {t}", p) for t, p in tiles]
        else:
            resolved = attr.Get().resolvedPath if attr.Get() else ""
            if not assets.exists(resolved):  # Ar: files and assets inside usdz packages
                r.error(
                    "MissingFile",
                    f"{prop} @{asset}@ does not resolve to a file",
                    "re-bake the prim, or restore the lightmaps/ folder next to the layer",
                    property=prop,
                    asset=asset,
                )
                continue
            files = [("", resolved)]
            digest = results.digests.get(role)
            if not digest:
                r.warning(
                    "NoDigest",
                    f"{schema.digest_property_name(role)} is not authored, so a replaced "
                    f"{os.path.basename(resolved)} would go unnoticed",
                    "re-bake the prim (usdahd bake records a digest per texture)",
                    property=prop,
                )
            else:
                actual = schema.file_digest(resolved)  # a file or an asset in a package
                if actual != digest:
                    r.error(
                        "TextureReplaced",
                        f"{prop} ({os.path.basename(resolved)}) is not the file the bake wrote: "
                        f"its digest is {actual[:19]}..., {schema.digest_property_name(role)} "
                        f"records {digest[:19]}...",
                        "re-bake the prim; edit lightmaps only through usdahd bake",
                        property=prop,
                        expected=digest,
                        actual=actual,
                    )
        for label, path in files:
            base = os.path.basename(path.rstrip("]"))  # a package path ends in ...[dir/a.exr]
            where = f"{prop}{' ' + label if label else ''} ({base})"
            try:
                img = read_image(path)
            except OSError as exc:
                r.error(
                    "Unreadable",
                    f"{where} does not open with OpenImageIO: {str(exc).strip()[:200]}",
                    "re-bake the prim",
                    property=prop,
                )
                continue
            if (img.width, img.height) != (w, h):
                r.error(
                    "Resolution",
                    f"{where} is {img.width}x{img.height} but ahdLightmap:baked:resolution "
                    f"is {w}x{h}",
                    "re-bake the prim (every texture of a bake has the same resolution)",
                    property=prop,
                )
            if role == schema.SIDECAR_ROLE:
                missing_ch = [c for c in schema.SH_SIDECAR_CHANNELS if c not in img.channel_names]
                if missing_ch:
                    r.error(
                        "Channels",
                        f"{where} lacks channel(s) {', '.join(missing_ch[:6])}"
                        f"{'...' if len(missing_ch) > 6 else ''} of the SH sidecar layout",
                        "re-bake the prim",
                        property=prop,
                    )
                if img.format != "float":
                    r.error(
                        "DataFormat",
                        f"{where} stores {img.format}; the SH sidecar is float32",
                        "re-bake the prim",
                        property=prop,
                    )
                continue
            lay = layout.get(role)
            if lay is None:
                continue
            if sorted(img.channel_names) != sorted(lay.channels):
                r.error(
                    "Channels",
                    f"{where} has channel(s) {' '.join(img.channel_names)}; model "
                    f"{results.model!r} with ratio {results.ratio!r} stores "
                    f"{' '.join(lay.channels)}",
                    "re-bake the prim",
                    property=prop,
                )
            fmt = OIIO_FORMATS.get(img.format, img.format)
            if fmt != lay.format:
                r.error(
                    "DataFormat",
                    f"{where} stores {img.format} but the {role} texture is {lay.format}",
                    "re-bake the prim",
                    property=prop,
                )
            file_cs = img.color_space
            want_ext = lay.extension
            if assets.extension(path) != want_ext:
                r.error(
                    "FileType",
                    f"{where} is not a {want_ext} file; the {role} texture is {lay.format} "
                    f"({want_ext}: what engines and usdz packages accept)",
                    "re-bake the prim",
                    property=prop,
                )
            # PNG says "not sRGB" only with a gAMA chunk of 1.0 (OpenImageIO then reports it
            # linear); without one every reader takes the bytes as sRGB and converts them.
            if assets.extension(path) == ".png":
                if "srgb" in (file_cs or "srgb").lower() and "srgb" not in lay.color_space:
                    r.warning(
                        "FileColorSpace",
                        f"{where} carries no gAMA 1.0 chunk, so image tools and engine "
                        f"importers read it as sRGB although it holds {lay.color_space} data",
                        "re-bake the prim (usdahd writes the gAMA chunk)",
                        property=prop,
                    )
            elif file_cs:
                lin = lay.color_space == "lin_rec709_scene"
                srgb_claim = "srgb" in file_cs.lower()
                if srgb_claim or (not lin and "rec709" in file_cs.lower() and "lin" in file_cs):
                    r.warning(
                        "FileColorSpace",
                        f"{where} declares colour space {file_cs!r} but holds "
                        f"{lay.color_space} data; tools that honour the file tag will convert it",
                        "re-bake the prim (usdahd writes the right tag)",
                        property=prop,
                    )
    return r.out


# ------------------------------------------------------------------------ rule 3: TexelValues


def _texel(bake: Bake, i: int) -> tuple[int, int]:
    return int(bake.xy[i, 0]), int(bake.xy[i, 1])


def check_texel_values(prim) -> list[Finding]:
    """Rule TexelValues (see RULES)."""
    r = _Rule("TexelValues", prim)
    try:
        bake = load_bake(prim)
    except _Skip as why:
        r.info("Skipped", f"TexelValues did not run: {why}")
        return r.out
    # Raw stored floats first: NaN/Inf anywhere in the texture, padding included.
    for role, lay in bake.layout.items():
        if lay.format not in ("half", "float"):
            continue
        img = read_image(bake.results.textures[role])
        bad = ~np.isfinite(img.data.astype(np.float32)).all(axis=2)
        if bad.any():
            ys, xs = np.nonzero(bad)
            r.error(
                "NonFinite",
                f"{schema.file_property_name(role)} holds {int(bad.sum())} texel(s) with NaN or "
                f"Inf, first at texel ({xs[0]}, {ys[0]})",
                "re-bake the prim; engines propagate NaN through filtering and bloom",
                count=int(bad.sum()),
                texel=(int(xs[0]), int(ys[0])),
            )
    p, model = bake.params, bake.results.model

    def report(code, mask, what, fix="re-bake the prim", **data):
        if mask.any():
            i = int(np.argmax(mask))
            x, y = _texel(bake, i)
            r.error(
                code,
                f"{int(mask.sum())} texel(s) {what}, first at texel ({x}, {y})",
                fix,
                count=int(mask.sum()),
                texel=(x, y),
                **data,
            )

    with np.errstate(all="ignore"):
        if "iz" in p:
            iz = p["iz"]
            report("NegativeIz", (iz < 0).any(axis=1) & np.isfinite(iz).all(axis=1), "have I_z < 0")
        if "direction" in p:
            d = p["direction"]
            fin = np.isfinite(d).all(axis=1)
            report(
                "DirectionNotUnit",
                fin & (np.abs(np.linalg.norm(d, axis=1) - 1.0) > UNIT_TOLERANCE),
                "decode to a direction that is not unit length",
            )
            report(
                "DirectionBelowFloor",
                fin & (d[:, 2] < DZ_FLOOR),
                "decode to a direction with d_z below 1/127 (the documented floor; "
                "C_d = I_z (1 - w_a) / d_z blows up)",
                "re-bake the prim; the encoder clamps codes to +-126",
            )
        if "ambient_ratio" in p:
            wa = p["ambient_ratio"]
            fin = np.isfinite(wa).all(axis=1)
            if model == "hlsh":
                from usdahd.models._irradz import HLSH_RATIO_SCALE_MAX

                lo, hi = -HLSH_RATIO_SCALE_MAX, HLSH_RATIO_SCALE_MAX
            else:
                lo, hi = 0.0, 1.0
            report(
                "RatioRange",
                fin & ((wa < lo) | (wa > hi)).any(axis=1),
                f"have w_a outside [{lo:g}, {hi:g}] (the range of model {model})",
            )
        if model in NONNEGATIVE_COLOURS:
            if model in IRRADZ:
                from usdahd.models._irradz import colors

                ca, cd, _ = colors(p)
                cols = {"C_a": ca, "C_d": cd}
            else:
                cols = {k: v for k, v in p.items() if k in ("ambient", "directional")}
            for name, c in cols.items():
                c = np.asarray(c)
                report(
                    "NegativeColour",
                    np.isfinite(c).all(axis=1) & (c < 0).any(axis=1),
                    f"have {name} < 0 (model {model} requires colours >= 0)",
                )
    return r.out


# ---------------------------------------------------------------------------- rule 4: IzCheck


#: Slack on the derived tolerance: the first-order bound ignores products of two code errors
#: (the 8-bit sh_l1 L1 = ratio x L0, at most 1/127 of the bound) and float32 evaluation.
TOLERANCE_SLACK = 0.02


def _step(codes: np.ndarray, up: bool) -> np.ndarray:
    """Each stored code moved by one code step: the next float16, or the 8-bit code +-1."""
    if codes.dtype == np.float16:
        toward = np.float16(np.inf if up else -np.inf)
        out = np.nextafter(codes, toward)
        return np.where(np.isfinite(out), out, codes).astype(np.float16)
    c = codes.astype(np.int16) + (1 if up else -1)
    return np.clip(c, 0, 255).astype(codes.dtype)


def _at_z(bake: Bake, channels: dict) -> np.ndarray:
    """Decoded I(n = z) (n, 3) float64 of stored channels (as an engine computes it)."""
    params = bake.mod.decode(channels, ratio=bake.results.ratio, factors=bake.factors)
    z = np.zeros((len(bake.xy), 3))
    z[:, 2] = 1.0
    return bake.mod.evaluate(params, z).astype(np.float64)


def quantization_tolerance(bake: Bake, got: np.ndarray | None = None) -> np.ndarray:
    """Per texel and colour, how far the decoded I(z) may lie from the unquantized fit: (n, 3).

    Derived from the storage, not guessed: every stored code c_j is the rounding of the exact
    value to the nearest code (half a code step away at most), so to first order
    ``|I(z) - I_exact(z)| <= sum_j 0.5 |I(z; c_j + 1 step) - I(z)|`` (the larger of the two
    one-sided differences). One step is the next float16 (an ULP, 2^-11 relative at most, times
    the decode scale) or one 8-bit code; every channel of every texture enters, so a model
    whose I(z) involves several coefficients or an 8-bit direction gets the sum of their
    quantization errors at z. Plus TOLERANCE_SLACK of that. docs/validate.md, IzCheck.
    """
    base = _at_z(bake, bake.channels) if got is None else got
    tol = np.zeros_like(base)
    for role, codes in bake.channels.items():
        lay = bake.layout[role]
        for j, code in enumerate(lay.codes):
            if code == "reserved":
                continue
            worst = np.zeros_like(base)
            for up in (True, False):
                moved = dict(bake.channels)
                c = codes.copy()
                c[:, j] = _step(codes[:, j], up)
                moved[role] = c
                with np.errstate(all="ignore"):
                    diff = np.abs(_at_z(bake, moved) - base)
                worst = np.maximum(worst, np.where(np.isfinite(diff), diff, 0.0))
            tol += 0.5 * worst
    return tol * (1.0 + TOLERANCE_SLACK)


def check_iz(prim) -> list[Finding]:
    """Rule IzCheck (see RULES)."""
    r = _Rule("IzCheck", prim)
    try:
        bake = load_bake(prim)
    except _Skip as why:
        r.info("Skipped", f"IzCheck did not run: {why}")
        return r.out
    if bake.sh is None:
        r.info("Skipped", "IzCheck did not run: no readable SH sidecar (see SchemaValues)")
        return r.out
    res = bake.results
    z = np.array([0.0, 0.0, 1.0])
    with np.errstate(all="ignore"):
        got = _at_z(bake, bake.channels)
        if res.model in IRRADZ:
            ref = np.maximum(shm.iz(bake.sh), 0.0)  # the fit stores max(I_z, 0) (SH ringing)
            what = "I_z"
        else:
            fitted = models.fit(bake.sh, res.model, ratio=res.ratio, solver=res.solver or None)
            params = models.representable(fitted, bake.mod)
            zz = np.broadcast_to(z, bake.sh.shape[:-2] + (3,))
            ref = bake.mod.evaluate(params, zz).astype(np.float64)
            what = f"{res.model} irradiance at n = z"
        allowed = quantization_tolerance(bake, got)
    if OPTIONS.iz_tolerance is not None:  # --tolerance: a plain relative tolerance instead
        allowed = np.broadcast_to(
            float(OPTIONS.iz_tolerance) * np.abs(ref).max(axis=1, keepdims=True), ref.shape
        )
    # Texels TexelValues rejects (non-finite values, d_z below the floor) are its findings.
    ok = bake.valid & np.isfinite(got).all(axis=1) & np.isfinite(ref).all(axis=1)
    n_skip = int((~ok).sum())
    if not ok.any():
        r.info("Skipped", "IzCheck did not run: no texel decodes to finite values (TexelValues)")
        return r.out
    err = np.where(ok[:, None], np.abs(got - ref), 0.0)
    # Relative figures against the texel's brightest channel (a black channel next to a bright
    # one is judged relative to the bright one).
    denom = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1e-30)
    relerr = err / denom
    lit = ok & (denom[:, 0] > 1e-6 * denom[ok].max())  # texels bright enough for a ratio
    reltol = np.where(lit[:, None], allowed / denom, 0.0)
    fail = ok & (err > allowed).any(axis=1)
    ratio = np.where(
        allowed > 0, err / np.where(allowed > 0, allowed, 1.0), np.where(err > 0, np.inf, 0.0)
    )
    worst = int(np.argmax(ratio.max(axis=1))) if fail.any() else int(np.argmax(relerr.max(axis=1)))
    x, y = _texel(bake, worst)
    stats = dict(
        texels=int(ok.sum()),
        failing=int(fail.sum()),
        max_relative=float(relerr.max()),
        mean_relative=float(relerr[ok].mean()),
        worst_texel=(x, y),
        tolerance=float(reltol[lit].max()) if lit.any() else 0.0,
        tolerance_median=float(np.median(reltol[lit].max(axis=1))) if lit.any() else 0.0,
        worst_error_over_tolerance=float(ratio[ok].max()),
        skipped_nonfinite=n_skip,
    )
    summary = (
        f"{what} vs the SH sidecar over {stats['texels']} covered texels: max relative error "
        f"{stats['max_relative']:.3g}, mean {stats['mean_relative']:.3g}, worst at texel "
        f"({x}, {y}); tolerance from the quantization up to {stats['tolerance']:.3g} relative "
        f"(median {stats['tolerance_median']:.3g}), worst error "
        f"{stats['worst_error_over_tolerance']:.3g} of it"
    )
    if fail.any():
        r.error(
            "IzMismatch",
            f"{stats['failing']} texel(s) exceed the tolerance: {summary}",
            "re-bake the prim; a texture was edited, corrupted or written with another "
            "quantization than the schema declares",
            **stats,
        )
    else:
        r.info("IzOk", summary, **stats)
    return r.out


# ---------------------------------------------------------------------- rule 5: EncodingError


def _relative_rmse(got: np.ndarray, ref: np.ndarray, scale: np.ndarray):
    """(per texel (n,), whole prim) RMSE of got - ref (n, d, 3) relative to ``scale`` (n,)."""
    sq = ((got - ref) ** 2).mean(axis=(1, 2))
    per_texel = np.sqrt(sq) / np.where(scale > 0, scale, np.inf)
    return per_texel, float(np.sqrt(sq.mean()) / max(float(scale.mean()), 1e-30))


def check_encoding_error(prim) -> list[Finding]:
    """Rule EncodingError (see RULES and docs/validate.md).

    Three hemispherical RMSEs over OPTIONS.rmse_normals upper-hemisphere normals (spherical
    Fibonacci), each relative to the mean |SH irradiance| over those normals and texels:
    ``relative_rmse`` decoded textures vs the SH irradiance (what a renderer gets), ``model_rmse``
    the unquantized refit vs the SH irradiance (the model's own approximation error, a note:
    a model choice, not a defect), ``quantization_rmse`` decoded vs the unquantized refit (what
    the textures add). Warns when the quantization part exceeds OPTIONS.rmse_warning.
    """
    r = _Rule("EncodingError", prim)
    try:
        bake = load_bake(prim)
    except _Skip as why:
        r.info("Skipped", f"EncodingError did not run: {why}")
        return r.out
    if bake.sh is None:
        r.info("Skipped", "EncodingError did not run: no readable SH sidecar")
        return r.out
    idx = np.nonzero(bake.valid & np.isfinite(bake.sh).all(axis=(1, 2)))[0]
    if idx.size == 0:
        r.info("Skipped", "EncodingError did not run: no valid covered texel")
        return r.out
    if idx.size > OPTIONS.rmse_max_texels:
        idx = idx[np.linspace(0, idx.size - 1, OPTIONS.rmse_max_texels).astype(np.int64)]
    dirs = shm.fibonacci_sphere(OPTIONS.rmse_normals, hemisphere=True)
    sh = bake.sh[idx]
    params = {k: v[idx] for k, v in bake.params.items()}
    res = bake.results
    with np.errstate(all="ignore"):
        target = shm.irradiance(sh[:, None], dirs[None])  # (n, d, 3)
        normals = np.broadcast_to(dirs, (idx.size,) + dirs.shape)
        got = bake.mod.evaluate(params, normals).astype(np.float64)
        fitted = models.fit(sh, res.model, ratio=res.ratio, solver=res.solver or None)
        exact = bake.mod.evaluate(models.representable(fitted, bake.mod), normals)
        exact = exact.astype(np.float64)
    scale = np.abs(target).mean(axis=(1, 2))
    per_texel, total = _relative_rmse(got, target, scale)
    _, model_total = _relative_rmse(exact, target, scale)
    q_texel, q_total = _relative_rmse(got, exact, scale)
    worst = int(np.argmax(per_texel))
    x, y = int(bake.xy[idx[worst], 0]), int(bake.xy[idx[worst], 1])
    qw = int(np.argmax(np.where(np.isfinite(q_texel), q_texel, 0.0)))
    stats = dict(
        texels=int(idx.size),
        relative_rmse=total,
        model_rmse=model_total,
        quantization_rmse=q_total,
        texel_relative_rmse_mean=float(per_texel.mean()),
        texel_relative_rmse_max=float(per_texel.max()),
        texel_quantization_rmse_max=float(q_texel.max()),
        worst_texel=(x, y),
        threshold=OPTIONS.rmse_warning,
    )
    msg = (
        f"{res.model} ({res.ratio}) decoded vs SH irradiance over "
        f"{OPTIONS.rmse_normals} hemisphere normals and {idx.size} texels: relative RMSE "
        f"{total:.3g} (model fit {model_total:.3g}, quantization {q_total:.3g}); per texel mean "
        f"{stats['texel_relative_rmse_mean']:.3g}, max {stats['texel_relative_rmse_max']:.3g} "
        f"at texel ({x}, {y})"
    )
    if not math.isfinite(q_total) or q_total > OPTIONS.rmse_warning:
        qx, qy = int(bake.xy[idx[qw], 0]), int(bake.xy[idx[qw], 1])
        r.warning(
            "HighEncodingError",
            f"{msg}; the textures add {q_total:.3g} to the model's own fit (worst texel "
            f"({qx}, {qy})), above the {OPTIONS.rmse_warning:g} threshold",
            "check the textures decode as docs/schema.md says (channel order, biases, scale "
            "factors), or re-bake the prim",
            **stats,
        )
    else:
        hint = (
            "; the model fits this lighting loosely, hhd or sh_l2 fit closer"
            if model_total > MODEL_RMSE_NOTE
            else ""
        )
        r.info("EncodingError", msg + hint, **stats)
    return r.out


# -------------------------------------------------------------------------- rule 6: Staleness


class _SceneCache:
    """Scene hash parts per (stage layers, uv name).

    The key is every used layer's identifier with its file's size and mtime, so a stage whose
    layers changed on disk is re-read; stages with unsaved (dirty) or anonymous layers are not
    cached at all (an in-memory edit must never see an older scene).
    """

    def __init__(self):
        self._data: OrderedDict = OrderedDict()

    @staticmethod
    def key(stage, uv_name: str, time=None):
        parts = []
        for layer in stage.GetUsedLayers():
            if layer.anonymous and layer != stage.GetSessionLayer():
                return None
            if layer.dirty and not layer.anonymous:
                return None
            if layer.anonymous:
                if not layer.empty:
                    return None
                continue
            from usdahd.usd import assets

            stamp = assets.stamp(layer.realPath)  # a layer inside a usdz: its package's
            if stamp is None:
                return None
            parts.append((layer.identifier, *stamp))
        return (tuple(sorted(parts)), uv_name, repr(time))

    def get(self, stage, uv_name: str, time=None):
        """Hash parts of the stage read at ``time`` (the bake's: a number or "default")."""
        from usdahd.usd.reader import load_scene

        key = self.key(stage, uv_name, time)
        if key is not None:
            with _LOCK:
                if key in self._data:
                    self._data.move_to_end(key)
                    return self._data[key]
        from usdahd.pipeline import scene_hash_parts

        parts = scene_hash_parts(load_scene(stage, uv_name=uv_name, time=time))
        if key is not None:
            with _LOCK:
                self._data[key] = parts
                while len(self._data) > 8:
                    self._data.popitem(last=False)
        return parts

    def auto_time(self, stage):
        """The time a bake would pick now (usd.time.resolve_time): a number or "default"."""
        from usdahd.usd.time import resolve_time

        key = self.key(stage, "", "auto-time")
        if key is not None:
            with _LOCK:
                if key in self._data:
                    return self._data[key]
        t, _ = resolve_time(stage, None)
        now = "default" if t.IsDefault() else float(t.GetValue())
        if key is not None:
            with _LOCK:
                self._data[key] = now
        return now

    def clear(self):
        with _LOCK:
            self._data.clear()


_SCENES = _SceneCache()

#: Schema input -> key of the bake settings record (usdahd.pipeline.resolve_settings).
_SETTING_KEYS = {
    "model": "model",
    "ratio": "ratio",
    "solver": "solver",
    "uv_primvar": "uv",
    "samples": "samples",
    "bounces": "bounces",
    "resolution": "resolution",
    "texel_density": "texel_density",
}


def settings_drift(prim, settings: dict) -> list[str]:
    """Authored bake inputs that differ from the settings the bake used (valid inputs only)."""
    inputs = schema.read_inputs(prim, validate=False)
    if schema.input_problems(inputs):
        return []  # SchemaValues reports invalid inputs; do not guess
    out = []
    authored = {
        f: prim.GetAttribute(schema.property_name(k)).HasAuthoredValue()
        for f, k in schema.INPUT_KEYS.items()
    }
    for f, key in _SETTING_KEYS.items():
        if not authored.get(f) or key not in settings:
            continue
        v, old = getattr(inputs, f), settings[key]
        if f == "resolution":
            if v == 0:
                continue
            same = list(old or []) == [v, v] or old == v
        elif f == "texel_density":
            if authored.get("resolution") and inputs.resolution:
                continue
            same = old is not None and math.isclose(float(old), float(v), rel_tol=1e-6)
        elif f == "ratio":
            try:
                if v not in models.get(inputs.model).RATIOS:
                    continue  # ignored by the bake for models without that ratio type
            except Exception:
                continue
            same = v == old
        elif f == "solver" and v == "":
            continue
        else:
            same = v == old
        if not same:
            out.append(f"{schema.property_name(schema.INPUT_KEYS[f])} ({old!r} -> {v!r})")
    return out


def check_staleness(prim) -> list[Finding]:
    """Rule Staleness (see RULES)."""
    r = _Rule("Staleness", prim)
    try:
        results = schema.read_results(prim, validate=False)
    except Exception:
        return r.out
    if results is None:
        return r.out
    if not results.content_hash:
        r.warning(
            "NoHash",
            "the bake has no content hash, so staleness cannot be checked",
            "re-bake the prim",
        )
        return r.out
    from usdahd import pipeline

    uv_name = str(results.settings.get("uv") or results.uv_primvar or "st")
    from usdahd.errors import StageError

    # Read the stage at the time the bake read it (older bakes: the default time).
    time = results.settings.get("time", "default")
    try:
        parts = _SCENES.get(prim.GetStage(), uv_name, time)
    except StageError as exc:
        r.error(
            "SceneUnreadable",
            f"the stage cannot be read as a scene, so staleness cannot be checked: {exc}",
            "fix the stage (the baker reports the same error)",
        )
        return r.out
    path = str(prim.GetPath())
    if path not in parts:
        r.error(
            "NotInScene",
            "the prim is no longer a visible mesh the baker would bake",
            "re-bake the stage or remove the stale results",
        )
        return r.out
    current, named = pipeline.content_hash(parts, path, results.settings)
    drift = settings_drift(prim, results.settings)
    if results.settings.get("time_auto"):
        # A time chosen from the stage: a re-bake would read the stage's time now.
        now = _SCENES.auto_time(prim.GetStage())
        if now != time:
            drift.append(f"bake time ({time!r} -> {now!r}: the stage's startTimeCode or animation)")
    if current == results.content_hash and not drift:
        return r.out
    changed = pipeline.changed_parts(results.part_hashes, named) if results.part_hashes else []
    if drift:
        changed = sorted(set(changed) - {"settings"})
    what = ", ".join(changed) if changed else ""
    if drift:
        what = (what + "; " if what else "") + "settings: " + ", ".join(drift)
    if current != results.content_hash and not changed and not drift:
        what = "unknown (no part hashes stored)"
    stale_normals = _normals_drift(prim, results) if "geometry" in changed else None
    if stale_normals:
        what += f" ({stale_normals})"
    if changed == ["generator"] and not drift:
        r.warning(
            "OtherGenerator",
            f"the bake was written by {results.generator or 'another usdahd'}; the scene is "
            "unchanged but the baker version differs",
            "re-bake the prim to pick up baker fixes",
        )
        return r.out
    r.error(
        "Stale",
        f"the bake is stale: changed since the bake: {what}",
        "re-bake the stage (usdahd bake)",
        changed=changed,
        settings=drift,
    )
    return r.out


def _normals_drift(prim, results) -> str | None:
    """When the bake computed and authored the prim's normals (``baked:normals`` not
    "authored"): a sentence if the rule (usdahd.usd.normals, the baker's own function) gives
    other normals on the current points, i.e. the mesh changed under the authored normals."""
    from usdahd.usd import normals as N

    if results.normals not in (N.RULE_CREASE, N.RULE_SMOOTH):
        return None
    mesh = UsdGeom.Mesh(prim)
    time = results.settings.get("time", "default")
    t = Usd.TimeCode.Default() if time == "default" else Usd.TimeCode(float(time))
    pts, counts, idx = (
        mesh.GetPointsAttr().Get(t),
        mesh.GetFaceVertexCountsAttr().Get(t),
        mesh.GetFaceVertexIndicesAttr().Get(t),
    )
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
    authored = pv.ComputeFlattened(t) if pv and pv.HasValue() else mesh.GetNormalsAttr().Get(t)
    if pts is None or counts is None or idx is None or authored is None:
        return None
    idx = np.asarray(idx, np.int64)
    if len(idx) == 0 or idx.min() < 0 or idx.max() >= len(pts) or len(authored) != len(idx):
        return "the normals the bake authored no longer fit the mesh's topology"
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    want = N.compute_normals(np.asarray(pts, np.float64), counts, idx, results.normals, left)
    got = np.asarray(authored, np.float32).reshape(-1, 3)
    if np.abs(got - want).max() > 1e-5:
        return (
            f"the {results.normals} normals the bake authored no longer match the mesh: "
            "re-baking recomputes them"
        )
    return None


# ------------------------------------------------------------------------------ rule 7: UVSet


def _read_uvs(prim, name: str) -> np.ndarray | None:
    """Per-triangle-corner UVs (t, 3, 2) float64 by fan triangulation, or None if absent."""
    mesh = UsdGeom.Mesh(prim)
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    vals = pv.ComputeFlattened()
    if vals is None:
        return None
    vals = np.asarray(vals, dtype=np.float64).reshape(-1, 2)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    interp = pv.GetInterpolation()
    if interp == UsdGeom.Tokens.faceVarying:
        per_corner = vals
    elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        per_corner = vals[fvi]
    elif interp == UsdGeom.Tokens.uniform:
        per_corner = np.repeat(vals, counts, axis=0)
    else:
        per_corner = np.broadcast_to(vals[:1], (len(fvi), 2))
    tri = _fan(counts)
    return per_corner[tri]


def _fan(counts: np.ndarray) -> np.ndarray:
    """(t, 3) face-vertex slots of the fan triangulation of polygons with ``counts``."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_tri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), n_tri)
    k = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
    s = starts[face]
    return np.stack([s, s + k + 1, s + k + 2], axis=-1)


def texel_coverage(uv: np.ndarray, resolution: tuple[int, int]) -> np.ndarray:
    """How many triangles cover each texel centre: (h, w) int32 (row 0 = top, v = 1).

    uv : (t, 3, 2) float. A centre on an edge counts for one side only (top-left rule), so
    triangles sharing an edge do not double-count it.
    """
    w, h = resolution
    px = np.empty(uv.shape, np.float64)
    px[..., 0] = uv[..., 0] * w
    px[..., 1] = (1.0 - uv[..., 1]) * h
    return _coverage_kernel(np.ascontiguousarray(px), int(w), int(h))


def _coverage_kernel_py(px, w, h):
    count = np.zeros((h, w), np.int32)
    for t in range(px.shape[0]):
        ax, ay = px[t, 0]
        bx, by = px[t, 1]
        cx, cy = px[t, 2]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0 or not math.isfinite(area):
            continue
        if area < 0.0:  # make every triangle counter-clockwise in pixel space
            bx, by, cx, cy = cx, cy, bx, by
        x0 = max(int(math.floor(min(ax, bx, cx) - 0.5)), 0)
        x1 = min(int(math.ceil(max(ax, bx, cx) - 0.5)), w - 1)
        y0 = max(int(math.floor(min(ay, by, cy) - 0.5)), 0)
        y1 = min(int(math.ceil(max(ay, by, cy) - 0.5)), h - 1)
        e = ((ax, ay, bx, by), (bx, by, cx, cy), (cx, cy, ax, ay))
        for y in range(y0, y1 + 1):
            qy = y + 0.5
            for x in range(x0, x1 + 1):
                qx = x + 0.5
                inside = True
                for k in range(3):
                    sx, sy, ex, ey = e[k]
                    f = (ex - sx) * (qy - sy) - (ey - sy) * (qx - sx)
                    if f < 0.0:
                        inside = False
                        break
                    if f == 0.0:  # top-left rule: keep edges going up or exactly left
                        dy, dx = ey - sy, ex - sx
                        if not (dy < 0.0 or (dy == 0.0 and dx < 0.0)):
                            inside = False
                            break
                if inside:
                    count[y, x] += 1
    return count


try:
    from numba import njit

    _coverage_kernel = njit(cache=True, fastmath=False)(_coverage_kernel_py)
except ImportError:  # pragma: no cover
    _coverage_kernel = _coverage_kernel_py


def check_uv_set(prim) -> list[Finding]:
    """Rule UVSet (see RULES)."""
    r = _Rule("UVSet", prim)
    try:
        results = schema.read_results(prim, validate=False)
    except Exception:
        return r.out
    if results is None or not results.uv_primvar:
        return r.out
    name = results.uv_primvar
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        r.error(
            "MissingUVSet",
            f"primvars:{name} (ahdLightmap:baked:uvPrimvar) does not exist or has no value",
            "re-bake the prim (the bake authors the UV set it unwrapped) or restore the primvar",
        )
        return r.out
    if pv.GetTypeName().type != Sdf.ValueTypeNames.TexCoord2fArray.type:
        r.error(
            "UVSetType",
            f"primvars:{name} is {pv.GetTypeName()}, not a float2/texCoord2f array",
            "author the lightmap UVs as texCoord2f[]",
        )
        return r.out
    uv = _read_uvs(prim, name)
    if uv is None or uv.size == 0:
        r.error("MissingUVSet", f"primvars:{name} has no values", "re-bake the prim")
        return r.out
    if not np.isfinite(uv).all():
        r.error("NonFiniteUV", f"primvars:{name} holds NaN or Inf", "re-unwrap and re-bake")
        return r.out
    udim = "<UDIM>" in "".join(results.asset_paths.values())
    eps = OPTIONS.uv_epsilon
    if not udim:
        out = (uv < -eps) | (uv > 1.0 + eps)
        if out.any():
            r.error(
                "UVOutOfRange",
                f"{int(out.any(axis=2).any(axis=1).sum())} triangle(s) of primvars:{name} "
                f"leave [0, 1] (range u {uv[..., 0].min():.4g}..{uv[..., 0].max():.4g}, "
                f"v {uv[..., 1].min():.4g}..{uv[..., 1].max():.4g}); a lightmap does not tile",
                "re-unwrap the lightmap UV set into [0, 1] and re-bake",
            )
            return r.out
        cov = texel_coverage(uv, results.resolution)
        covered = int((cov > 0).sum())
        over = int((cov > 1).sum())
        if covered and over > OPTIONS.uv_overlap * covered:
            ys, xs = np.nonzero(cov > 1)
            r.error(
                "UVOverlap",
                f"{over} of {covered} covered texels ({100.0 * over / covered:.2g}%) lie in "
                f"more than one triangle of primvars:{name}, first at texel ({xs[0]}, {ys[0]}); "
                f"overlapping charts share (and fight over) lightmap texels",
                "re-unwrap without overlaps (usdahd bake unwraps when the UV set is missing)",
                overlapping=over,
                covered=covered,
                texel=(int(xs[0]), int(ys[0])),
            )
    # Texel density: texels per unit of world area per triangle.
    mesh = UsdGeom.Mesh(prim)
    pts = np.asarray(mesh.GetPointsAttr().Get() or [], dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    fvi = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    if len(pts) and len(fvi):
        m = np.asarray(
            UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        ).T
        wp = pts @ m[:3, :3].T + m[:3, 3]
        tri = wp[fvi[_fan(counts)]]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        w, h = results.resolution
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * w * h
        total = float(area.sum())
        if total > 0:
            zero = (uv_area <= 1e-12) & (area > 0)
            if area[zero].sum() > 0.01 * total:
                r.warning(
                    "DegenerateUV",
                    f"{int(zero.sum())} triangle(s) ({100 * area[zero].sum() / total:.2g}% of "
                    f"the surface) have zero area in primvars:{name} and get no lightmap texels",
                    "re-unwrap the lightmap UV set",
                )
            ok = (uv_area > 1e-12) & (area > 0)
            if ok.sum() >= 2:
                dens = np.sqrt(uv_area[ok] / area[ok])
                order = np.argsort(dens)
                cw = np.cumsum(area[ok][order]) / area[ok].sum()
                p10 = dens[order][np.searchsorted(cw, 0.1)]
                p90 = dens[order][min(np.searchsorted(cw, 0.9), len(cw) - 1)]
                spread = float(p90 / p10) if p10 > 0 else math.inf
                if spread > OPTIONS.density_spread:
                    r.warning(
                        "TexelDensity",
                        f"texel density varies {spread:.3g}x across the mesh (area-weighted "
                        f"10th..90th percentile {p10:.3g}..{p90:.3g} texels per unit)",
                        "re-unwrap with uniform texel density",
                        spread=spread,
                    )
    return r.out


# ------------------------------------------------------------------------------ registration

CHECKS = {
    "SchemaValues": check_schema_values,
    "Textures": check_textures,
    "TexelValues": check_texel_values,
    "IzCheck": check_iz,
    "EncodingError": check_encoding_error,
    "Staleness": check_staleness,
    "UVSet": check_uv_set,
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


def check_prim(prim, rules=RULE_NAMES) -> list[Finding]:
    """Every finding of ``rules`` on one prim (the plain-function path, no UsdValidation)."""
    out = []
    for rule in rules:
        out += run_rule(rule, prim)
    return out


#: (rule, prim, code, message) -> data of findings returned through UsdValidation, which can
#: only carry a message; ``usdahd validate --json`` adds the numbers back from here.
FINDING_DATA: dict = {}


def _task(rule: str):
    def task(prim, time_range=None):
        try:
            stage = prim.GetStage()
            found = run_rule(rule, prim)
            with _LOCK:
                for f in found:
                    FINDING_DATA[(f.rule, f.prim, f.code, f.message)] = f.data
                while len(FINDING_DATA) > 10000:
                    FINDING_DATA.pop(next(iter(FINDING_DATA)))
            return [f.to_usd(stage) for f in found]
        except Exception as exc:  # noqa: BLE001 - never let an exception abort Validate()
            site = UsdValidation.ValidationErrorSite(prim.GetStage(), prim.GetPath())
            return [
                UsdValidation.ValidationError(
                    "InternalError",
                    UsdValidation.ValidationErrorType.Error,
                    [site],
                    f"rule {rule} could not run: {exc}",
                )
            ]

    task.__name__ = f"usdahd_{rule}"
    return task


def register() -> list[str]:
    """Register every rule's implementation with UsdValidation (idempotent).

    Only rules whose metadata the plugInfo declared are registered (USD refuses the others);
    returns the names registered by this call.
    """
    reg = UsdValidation.ValidationRegistry()
    done = []
    for rule in RULE_NAMES:
        name = validator_name(rule)
        if reg.HasValidator(name) or reg.GetValidatorMetadata(name) is None:
            continue
        reg.RegisterPluginPrimValidator(name, _task(rule))
        done.append(name)
    name = validator_name(STAGE_RULE.name)
    if not reg.HasValidator(name) and reg.GetValidatorMetadata(name) is not None:
        reg.RegisterPluginStageValidator(name, _stage_task)
        done.append(name)
    return done


def check_lightmapped(stage) -> list[Finding]:
    """Rule Lightmapped on a whole stage: one ``NoAhdLightmapAPI`` error on ``/`` when no prim
    has the API (nothing else would be validated, and a CI job must not stay green)."""
    if any(True for _ in schema.prims_with_api(stage)):
        return []
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


def _stage_task(stage, time_range=None):
    try:
        return [f.to_usd(stage) for f in check_lightmapped(stage)]
    except Exception as exc:  # noqa: BLE001 - never let an exception abort Validate()
        site = UsdValidation.ValidationErrorSite(stage, Sdf.Path.absoluteRootPath)
        return [
            UsdValidation.ValidationError(
                "InternalError",
                UsdValidation.ValidationErrorType.Error,
                [site],
                f"rule {STAGE_RULE.name} could not run: {exc}",
            )
        ]


def finding_from_usd(error) -> Finding:
    """A Finding from a UsdValidation.ValidationError (ours or a built-in validator's)."""
    validator = error.GetValidator()
    vname = validator.GetMetadata().name if validator else ""
    rule = vname.split(":", 1)[1] if vname.startswith(PLUGIN_NAME + ":") else vname
    sev = {
        UsdValidation.ValidationErrorType.Error: "error",
        UsdValidation.ValidationErrorType.Warn: "warning",
    }.get(error.GetType(), "info")
    prim = ""
    for site in error.GetSites():
        p = site.GetPrim()
        if p:
            prim = str(p.GetPath())
            break
        prop = site.GetProperty()
        if prop:
            prim = str(prop.GetPrimPath())
            break
        layer = site.GetLayer()
        if layer:
            prim = f"@{layer.identifier}@"
    code, msg = str(error.GetName()), error.GetMessage()
    return Finding(rule, sev, prim, code, msg, dict(FINDING_DATA.get((rule, prim, code, msg), {})))


def findings_json(findings: list[Finding]) -> list[dict]:
    return [
        {
            "rule": f.rule,
            "severity": f.severity,
            "prim": f.prim,
            "code": f.code,
            "message": f.message,
            "data": f.data,
        }
        for f in findings
    ]


def dumps(findings: list[Finding]) -> str:
    return json.dumps(findings_json(findings), indent=2, sort_keys=True)


# Plug imports this module to load the plugin: register the implementations now.
register()

# Opt-in rules declared in the same plugInfo under their own keyword (not UsdAhdValidators).
from usdahd import validate_retrace as _retrace  # noqa: E402

_retrace.register()
