"""Rule ``Composition`` (per stage): composition problems, each once, as warnings unless a baked
prim is composed through them (issues 37 and 41).

A production stage carries arcs that have nothing to do with its lightmaps: a variant that is
not selected references an empty or missing layer, a material references a ``.mtlx`` file the
installed USD cannot read. USD composes only what is selected, so a validator that fails the
stage for them (or stops: ``usdUtilsValidators:MissingReferenceValidator`` raises on a layer
that does not parse) fails a CI job for a defect outside what it checks. Here
(:func:`usdahd.usd.composition.problems`):

- ``UnselectedVariantArc`` (warning): a reference or payload inside an unselected variant whose
  layer cannot be opened; the message gives the variant, the asset, USD's cause and the fix;
- ``CompositionErrorUnbaked`` (warning): an arc USD could not compose on a prim that neither is
  nor holds a baked prim (that part of the stage is missing; no baked prim's data is);
- ``CompositionError`` (error): an arc USD could not compose on a baked prim or one of its
  ancestors: the baked prim's composed data may be incomplete;
- ``CompositionCycle`` (error).

It replaces ``usdValidation:CompositionErrorTest`` in ``usdahd validate`` (which reports every
composition error as an error, with no notion of what is baked).
"""

from __future__ import annotations

from usdahd.usd import composition, schema
from usdahd.validate.findings import Finding
from usdahd.validate.registry import COMPOSITION_RULE

__all__ = ["check_composition"]


def check_composition(stage) -> list[Finding]:
    """The Composition findings of ``stage`` (see the module doc), sorted by prim."""
    baked = [str(p.GetPath()) for p in schema.prims_with_api(stage)]
    out = []
    for prob in composition.problems(stage, baked):
        data = {"cause": prob.cause}
        if prob.asset:
            data["asset"] = prob.asset
        if prob.resolved:
            data["resolved"] = prob.resolved
        if prob.variant:
            data["variant"] = prob.variant
        if prob.baked:
            data["baked_prims"] = list(prob.baked)
        if prob.also:
            data["also"] = list(prob.also)
        out.append(
            Finding(
                COMPOSITION_RULE.name,
                prob.severity,
                prob.prim,
                prob.code,
                prob.message().rstrip(".") + ".",
                data,
            )
        )
    return out
