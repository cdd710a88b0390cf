"""Lighting scenarios: one stage, several lighting set-ups, one override layer per scenario.

A *scenario* is a variant of a variant set on the stage (``day``/``night`` of a ``lighting``
set, lights on/off, ...). ``usdahd bake STAGE --scenario night`` selects that variant (in the
session layer; the source is never modified), bakes, and writes ``STAGE.night.lightmaps.usda``.
That override layer authors the same variant selection itself, so whoever opens it (an engine
importer, usdview, ``usdahd validate``) composes the lights the lightmaps were baked with, and
records the scenario in its ``customLayerData`` (:data:`LAYER_KEY`) so a tool can list the
scenarios of a folder without composing anything. Texture names are unique per output layer,
so the scenarios of one stage share a ``lightmaps/`` folder without overwriting each other.
docs/schema.md ("Lighting scenarios") is the interchange description.

A scenario is named on the command line as ``NAME`` (the variant; it must be unambiguous on the
stage), ``SET=NAME`` or ``/Prim{SET=NAME}`` (SdfPath variant-selection syntax, which is also
how :meth:`Scenario.spec` writes it into ``baked:settings``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from pxr import Sdf, Usd

from usdahd.errors import UsageError

__all__ = ["author", "default_output", "name_of", "resolve", "select"]

#: customLayerData key of an override layer baked for a scenario: {prim, variantSet, variant}.
LAYER_KEY = "ahdLightmapScenario"

#: A scenario name becomes part of a file name: keep it to portable characters.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
_FULL = re.compile(r"^(?P<prim>/[^{}]*)\{(?P<set>[^={}]+)=(?P<variant>[^={}]*)\}$")


@dataclass(frozen=True)
class Scenario:
    """A variant selection that defines a lighting scenario.

    prim : path of the prim holding the variant set; variant_set, variant : the selection.
    """

    prim: str
    variant_set: str
    variant: str

    @property
    def name(self) -> str:
        """The scenario's name (the variant), used in the default output file name."""
        return self.variant

    def spec(self) -> str:
        """``/Prim{set=variant}``: the unambiguous form (``baked:settings``, messages)."""
        return f"{self.prim}{{{self.variant_set}={self.variant}}}"

    def as_dict(self) -> dict:
        return {"prim": self.prim, "variantSet": self.variant_set, "variant": self.variant}


def _choices(stage: Usd.Stage) -> list[Scenario]:
    """Every (prim, variant set, variant) of the stage, in traversal order."""
    out = []
    for prim in Usd.PrimRange.Stage(stage, Usd.PrimAllPrimsPredicate):
        vsets = prim.GetVariantSets()
        for set_name in vsets.GetNames():
            for variant in vsets.GetVariantSet(set_name).GetVariantNames():
                out.append(Scenario(str(prim.GetPath()), set_name, variant))
    return out


def _listing(choices: list[Scenario], limit: int = 12) -> str:
    if not choices:
        return "the stage has no variant sets"
    shown = ", ".join(c.spec() for c in choices[:limit])
    more = f" and {len(choices) - limit} more" if len(choices) > limit else ""
    return f"the stage's variants: {shown}{more}"


def resolve(stage: Usd.Stage, text: str) -> Scenario:
    """The scenario ``text`` names on ``stage`` (``NAME``, ``SET=NAME`` or ``/Prim{SET=NAME}``).

    Raises UsageError naming the flag, what the stage offers and the fix when the variant does
    not exist, is ambiguous, or is not a portable file-name part.
    """
    text = (text or "").strip()
    flag = f"--scenario {text!r}"
    m = _FULL.match(text)
    if m:
        prim_path, set_name, variant = m["prim"], m["set"].strip(), m["variant"].strip()
    elif "=" in text:
        prim_path = None
        set_name, _, variant = (s.strip() for s in text.partition("="))
    else:
        prim_path, set_name, variant = None, None, text
    _check_name(text, variant)
    choices = _choices(stage)
    found = [
        c
        for c in choices
        if c.variant == variant
        and (set_name is None or c.variant_set == set_name)
        and (prim_path is None or c.prim == prim_path)
    ]
    if not found:
        raise UsageError(
            f"{flag}: no variant {variant!r}"
            + (f" in a variant set {set_name!r}" if set_name else "")
            + (f" on {prim_path}" if prim_path else "")
            + f"; {_listing(choices)}. Fix: name one of them"
        )
    if len(found) > 1:
        raise UsageError(
            f"{flag} is ambiguous: {', '.join(c.spec() for c in found)}. Fix: give the full "
            f"form, e.g. --scenario '{found[0].spec()}'"
        )
    return found[0]


def select(stage: Usd.Stage, scenario: Scenario) -> None:
    """Select the scenario's variant in the stage's session layer (the source is untouched)."""
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        prim = stage.GetPrimAtPath(scenario.prim)
        prim.GetVariantSets().GetVariantSet(scenario.variant_set).SetVariantSelection(
            scenario.variant
        )


def author(layer: Sdf.Layer, scenario: Scenario) -> None:
    """Author the scenario into an override layer: the variant selection (so the layer composes
    the lighting it was baked with) and :data:`LAYER_KEY` in its customLayerData."""
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(scenario.prim))
    if spec.specifier != Sdf.SpecifierDef:
        spec.specifier = Sdf.SpecifierOver
    spec.variantSelections[scenario.variant_set] = scenario.variant
    data = dict(layer.customLayerData)
    data[LAYER_KEY] = scenario.as_dict()
    layer.customLayerData = data


def of_layer(layer: Sdf.Layer) -> Scenario | None:
    """The scenario an override layer was baked for (None for a plain bake)."""
    d = dict(layer.customLayerData).get(LAYER_KEY)
    if not d:
        return None
    return Scenario(str(d["prim"]), str(d["variantSet"]), str(d["variant"]))


def name_of(text: str) -> str:
    """The scenario name (variant) a ``--scenario`` text gives, before any stage is open (the
    output path is checked before the stage is read); :func:`resolve` checks it on the stage."""
    given = text
    text = (text or "").strip()
    if text.endswith("}") and "{" in text:
        text = text[text.rindex("{") + 1 : -1]
    name = text.rpartition("=")[2].strip()
    _check_name(given, name)
    return name


def _check_name(text: str, name: str) -> None:
    if not name or not _NAME.match(name):
        raise UsageError(
            f"--scenario {text!r}: a scenario is a variant name of letters, digits, '_', '.', "
            "'-' (it becomes part of the output file name); give NAME, SET=NAME or "
            "/Prim{SET=NAME}"
        )


def default_output(stage_path: Path, name: str | None) -> Path:
    """``STAGE.lightmaps.usda``, or ``STAGE.NAME.lightmaps.usda`` for scenario ``name``."""
    stage_path = Path(stage_path)
    middle = f".{name}" if name else ""
    return stage_path.with_name(f"{stage_path.stem}{middle}.lightmaps.usda")


def list_layers(folder: Path) -> dict[str, Path]:
    """Scenario name -> override layer, for the ``*.lightmaps.usd*`` layers of ``folder`` that
    record one (what an importer or tool uses to offer the scenarios of a stage)."""
    out = {}
    for path in sorted(Path(folder).glob("*.lightmaps.usd*")):
        try:
            layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
        except Exception:  # noqa: BLE001 - not a readable layer: not a scenario
            continue
        sc = of_layer(layer) if layer is not None else None
        if sc is not None:
            out[sc.name] = path
    return out
