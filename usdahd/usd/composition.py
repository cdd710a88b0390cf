"""Composition problems of a stage, each once, with its cause and whether a baked prim is touched.

Production stages are rarely perfect: a variant that is not selected references a layer that
is empty or missing, a material references a ``.mtlx`` file the installed USD cannot read.
USD composes only selected variants, so such an arc changes nothing a bake reads; it must be
reported (selecting the variant would break the prim) but must not stop a bake, a validation or
a preview. :func:`problems` lists

- the stage's composition errors (``UsdStage.GetCompositionErrors``: arcs USD tried to compose
  and could not), with the prims whose composed data go through them: the baked prims at or
  below the error's prim (a reference on ``/World/Prop`` feeds every prim under it);
- the references and payloads authored inside *unselected* variants whose layer cannot be
  opened (missing, empty, not a USD file): USD never composes them, so only this walk sees them
  (``usdUtilsValidators:MissingReferenceValidator`` sees them too, but stops on a layer that does
  not parse).

A composition cycle is a :class:`Problem` with ``cycle`` set (the scene reader refuses the
stage: USD drops the arc that closes the cycle, so what is left is not what was authored).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, replace

from pxr import Ar, Sdf, Tf, Usd

from usdahd.usd import diagnostics

__all__ = ["Problem", "problems"]


def _one_line(text) -> str:
    """``text`` on one line, without USD's trailing full stop (messages add their own)."""
    return " ".join(str(text).split()).rstrip(".")


@dataclass(frozen=True)
class Problem:
    """One composition problem.

    prim : the composed prim path it is on; cause : USD's message (whole); asset : the asset
    path as authored ('' when USD's message is all there is); resolved : the file it names
    ('' when unknown); arc : "reference", "payload" or "composition"; variant : ``set=name`` of
    the unselected variant that authors the arc ('' for a composed arc); layer : the layer
    that authors it; baked : the prims given as baked whose composed data go through it;
    cycle : a composition cycle; also : the other prims whose arcs name the same broken
    file for the same reason (reported with this one).
    """

    prim: str
    cause: str
    asset: str = ""
    resolved: str = ""
    arc: str = "composition"
    variant: str = ""
    layer: str = ""
    baked: tuple[str, ...] = ()
    cycle: bool = False
    #: every prim with the same broken file (``prim`` is the first): one file, one problem
    also: tuple[str, ...] = ()

    @property
    def severity(self) -> str:
        """ "error" when a baked prim is composed through it, else "warning"."""
        return "error" if self.baked or self.cycle else "warning"

    @property
    def is_materialx(self) -> bool:
        """A ``.mtlx`` file (USD composes it only with its usdMtlx plugin)."""
        text = f"{self.asset} {self.cause}".lower()
        return ".mtlx@" in text or ".mtlx:" in text or self.asset.lower().endswith(".mtlx")

    @property
    def code(self) -> str:
        if self.variant:
            return "UnselectedVariantArc"
        if self.cycle:
            return "CompositionCycle"
        return "CompositionError" if self.baked else "CompositionErrorUnbaked"

    def message(self) -> str:
        """What is wrong, what it means for the bake, and the fix (one line, the cause whole);
        with ``also``: how many other prims have an arc to the same file, and the first few."""
        text = self._message()
        if self.also:
            shown = ", ".join(f"<{p}>" for p in self.also[:5])
            more = f" and {len(self.also) - 5} more" if len(self.also) > 5 else ""
            text += f" (the same file is also named by {shown}{more})"
        return text

    def _message(self) -> str:
        if self.variant:
            set_name = self.variant.split("=", 1)[0]
            where = f" in {self.layer}" if self.layer else ""
            return (
                f"the variant {self.variant} (not selected) {self.arc}s @{self.asset}@{where}, "
                f"which cannot be opened: {self.cause}. USD composes only the selected variant, "
                "so nothing baked uses it, but selecting it breaks the prim. Fix: repair or "
                f"remove that {self.arc} (variant set '{set_name}')"
            )
        if self.cycle:
            return (
                f"composition cycle: {self.cause}. Fix: remove the reference, payload or "
                "sublayer that points back to a layer already being composed"
            )
        if self.baked:
            shown = ", ".join(f"<{p}>" for p in self.baked[:5])
            more = f" and {len(self.baked) - 5} more" if len(self.baked) > 5 else ""
            return (
                f"composition error on the composition of baked prim(s) {shown}{more}: "
                f"{self.cause}. Their data may be incomplete. Fix: repair the arc (the file "
                "it names must exist and be a USD layer), then re-bake"
            )
        if self.is_materialx:
            return (
                f"MaterialX file could not be composed: {self.cause}. The installed USD has no "
                "MaterialX file format (usd-core from the package index lacks usdMtlx), so the "
                "material's network is not on the stage; no baked prim's geometry is affected "
                "(the bake reports the material it uses instead). Fix: convert the .mtlx to a "
                "UsdShade network, or use a USD build with MaterialX support"
            )
        return (
            f"composition error in a part of the stage no baked prim is composed from: "
            f"{self.cause}. That part is missing from the stage (it neither occludes nor "
            "bounces light in a bake). Fix: repair or remove the arc (the file it names must "
            "exist and be a USD layer)"
        )


def problems(stage, baked=()) -> list[Problem]:
    """Every composition problem of ``stage`` once (see the module doc), composed errors
    first, then unselected variants' arcs, each sorted by prim. baked : prim paths (str)
    whose composed data decide an error's severity."""
    baked = sorted({str(p) for p in baked})
    return _grouped(_composed_errors(stage, baked)) + _grouped(_unselected_variant_arcs(stage))


_ASSET = re.compile(r"@([^@]+)@")
#: USD's message parts that name the prim or layer introducing an arc (differ per prim).
_INTRODUCED = re.compile(r" for (reference|payload|sublayer) introduced by @[^@]*@<[^>]*>")


def _grouped(found: list[Problem]) -> list[Problem]:
    """One Problem per broken file and reason: a material library referenced from 19 prims is
    one finding naming the first prim and counting the others (``also``); errors on baked prims
    stay one per prim (each is a prim whose data may be incomplete)."""
    out, index = [], {}
    for p in found:
        if p.baked or p.cycle:
            out.append(p)
            continue
        asset = p.resolved or (_ASSET.search(p.cause).group(1) if _ASSET.search(p.cause) else "")
        if not asset:
            out.append(p)
            continue
        key = (bool(p.variant), asset, _INTRODUCED.sub("", p.cause))
        if key not in index:
            index[key] = len(out)
            out.append(p)
            continue
        first = out[index[key]]
        out[index[key]] = replace(first, also=(*first.also, p.prim))
    return out


def _composed_errors(stage, baked: list[str]) -> list[Problem]:
    try:
        errors = stage.GetCompositionErrors()
    except AttributeError:  # pragma: no cover - USD < 23.11
        return []
    out, seen = [], set()
    for err in errors:
        cause = _one_line(err)
        try:
            site = err.rootSite.path.StripAllVariantSelections().GetPrimPath()
        except Exception:  # noqa: BLE001 - an error kind without a usable site
            site = Sdf.Path.absoluteRootPath
        if (str(site), cause) in seen:
            continue
        seen.add((str(site), cause))
        touched = tuple(b for b in baked if Sdf.Path(b).HasPrefix(site))
        cycle = "Cycle" in type(err).__name__ or "Cycle" in str(getattr(err, "errorType", ""))
        out.append(Problem(str(site), cause, baked=touched, cycle=cycle))
    out.sort(key=lambda p: (p.prim, p.cause))
    return out


def _nodes(node):
    yield node
    for child in node.children:
        yield from _nodes(child)


def _arcs(spec, found: list) -> None:
    """(arc, asset path) of every reference and payload in ``spec`` and below (nested variant
    sets included)."""
    for arc, items in (("reference", spec.referenceList), ("payload", spec.payloadList)):
        for item in items.GetAddedOrExplicitItems():
            if item.assetPath:
                found.append((arc, item.assetPath))
    for child in spec.nameChildren:
        _arcs(child, found)
    for vset in spec.variantSets:
        for variant in vset.variants.values():
            _arcs(variant.primSpec, found)


def _all_prims(stage):
    """Every prim once: the stage's (inactive and unloaded ones too) and its instancing
    prototypes' (instance proxies would visit a prototype once per instance)."""
    yield from Usd.PrimRange.Stage(stage, Usd.PrimAllPrimsPredicate)
    for proto in stage.GetPrototypes():
        yield from Usd.PrimRange(proto, Usd.PrimAllPrimsPredicate)


def _unselected_variant_arcs(stage) -> list[Problem]:
    out, seen, opened = [], set(), {}
    for prim in _all_prims(stage):
        if not prim.HasVariantSets():
            continue
        sets = prim.GetVariantSets()
        selected = {name: sets.GetVariantSelection(name) for name in sets.GetNames()}
        index = prim.GetPrimIndex()
        if not index.IsValid():
            continue
        for node in _nodes(index.rootNode):
            for layer in node.layerStack.layers:
                spec = layer.GetPrimAtPath(node.path)
                if spec is None:
                    continue
                for set_name, vset in spec.variantSets.items():
                    for name, variant in vset.variants.items():
                        if name == selected.get(set_name):
                            continue
                        found = []
                        _arcs(variant.primSpec, found)
                        for arc, asset in found:
                            key = (str(prim.GetPath()), set_name, name, layer.identifier, asset)
                            if key in seen:
                                continue
                            seen.add(key)
                            resolved, cause = _open_problem(layer, asset, opened)
                            if cause is None:
                                continue
                            out.append(
                                Problem(
                                    str(prim.GetPath()),
                                    cause,
                                    asset=asset,
                                    resolved=resolved,
                                    arc=arc,
                                    variant=f"{set_name}={name}",
                                    layer=layer.realPath or layer.identifier,
                                )
                            )
    out.sort(key=lambda p: (p.prim, p.variant, p.asset))
    return out


def _open_problem(layer, asset: str, cache: dict) -> tuple[str, str | None]:
    """(the file ``asset`` names, why it cannot be opened as a layer or None)."""
    try:
        path = Sdf.ComputeAssetPathRelativeToLayer(layer, asset)
    except Exception:  # noqa: BLE001 - an asset path USD cannot anchor
        path = asset
    if path in cache:
        return cache[path]
    resolved = str(Ar.GetResolver().Resolve(path)) if path else ""
    if not resolved:
        result = (path, "the file does not exist")
    elif Sdf.Layer.Find(resolved) is not None:
        result = (resolved, None)
    else:
        cause = None
        with diagnostics.capture() as diags:
            try:
                opened = Sdf.Layer.FindOrOpen(resolved)
            except Tf.ErrorException as exc:
                opened, cause = None, "; ".join(diagnostics.exception_causes(exc))
        if opened is None and cause is None:
            cause = "; ".join(d.message for d in diags) or "USD cannot open it as a layer"
        if cause is not None and os.path.isfile(resolved) and os.path.getsize(resolved) == 0:
            cause = f"the file is empty (0 bytes): {cause}"
        result = (resolved, cause)
    cache[path] = result
    return result
