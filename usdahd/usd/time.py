"""The bake time: which time code every attribute of a stage is read at.

:func:`parse_time` checks a ``--time`` value (pxr-free rules, no stage needed);
:func:`resolve_time` picks the time for a stage: the stage's startTimeCode when anything the
bake reads is animated (:func:`animated_attributes`), else ``Usd.TimeCode.Default()``, with a
warning naming the animated attributes and one per attribute whose default value and time
samples disagree. docs/usd-semantics.md#time describes the rule; the scene reader
(:mod:`usdahd.usd.reader`) reads every attribute at that time, and an attribute that only has
time samples at the default time at its first sample (with a warning).
"""

from __future__ import annotations

import math

from pxr import Usd

__all__ = ["animated_attributes", "parse_time", "resolve_time", "start_time_code", "time_label"]


def time_label(t) -> str:
    """``"the default time"`` or ``"time 12"`` for a ``Usd.TimeCode`` (in messages)."""
    return "the default time" if t.IsDefault() else f"time {t.GetValue():g}"


#: Prim types whose time samples never change a bake (the scene reader does not read them).
UNREAD_TYPES = ("Camera", "RenderSettings", "RenderProduct", "RenderVar", "RenderPass")


def animated_attributes(stage) -> list:
    """Attributes with time samples on the prims the scene reader reads (geometry, xforms,
    visibility, lights, materials and shaders, subsets; cameras and render settings excluded),
    prototypes of scenegraph instances included once. returns [Usd.Attribute]."""
    out = []
    roots = [stage.GetPseudoRoot(), *stage.GetPrototypes()]
    for root in roots:
        for prim in Usd.PrimRange(root):
            if prim.GetTypeName() in UNREAD_TYPES:
                continue
            for attr in prim.GetAttributes():
                if attr.GetNumTimeSamples() > 0:
                    out.append(attr)
    return out


def parse_time(value):
    """A ``--time`` value: None, ``"default"`` or a finite number (str or float) -> None,
    "default" or float. Raises ValueError with the accepted forms."""
    if value is None or value == "default":
        return value
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"--time {value!r}: expected a time code (a number such as 1 or 101.5) or 'default'"
        ) from None
    if not math.isfinite(t):
        raise ValueError(f"--time {value!r}: the time code must be finite")
    return t


def start_time_code(stage):
    """startTimeCode of the strongest layer of the root layer stack that authors one, or None.

    USD reads it from the root (or session) layer only; a bake's override layer sublayers the
    source without a timeline of its own, so its sublayers count too (the validator opens the
    override layer and must find the time the bake used)."""
    if stage.HasAuthoredMetadata("startTimeCode"):
        return float(stage.GetStartTimeCode())
    for layer in stage.GetLayerStack(includeSessionLayers=True):
        if layer.HasStartTimeCode():
            return float(layer.startTimeCode)
    return None


def resolve_time(stage, time=None, warn=None):
    """The time the bake reads the stage at, and whether it was chosen automatically.

    time : None (automatic), "default" or a number (see :func:`parse_time`).
    Automatic: the stage's startTimeCode when any attribute the bake reads has time samples
    (the first of their samples if startTimeCode is not authored), else the default time. A
    warning names the animated attributes, and one per attribute whose default value and
    time samples disagree at the chosen time (a default plus samples: USD renderers show the
    sample at a numeric time, the default only at the default time).
    returns (Usd.TimeCode, auto: bool).
    """
    warn = warn or (lambda m: None)
    time = parse_time(time)
    anim = animated_attributes(stage)
    auto = time is None
    if time == "default":
        t = Usd.TimeCode.Default()
    elif time is not None:
        t = Usd.TimeCode(time)
    elif not anim:
        t = Usd.TimeCode.Default()
    elif start_time_code(stage) is not None:
        t = Usd.TimeCode(start_time_code(stage))
    else:
        first = min(a.GetTimeSamples()[0] for a in anim)
        t = Usd.TimeCode(first)
        warn(
            f"the stage has time samples but no startTimeCode: baked at the first sample, time "
            f"{first:g} (author startTimeCode or pass --time)"
        )
    when = time_label(t)
    if anim:
        names = [str(a.GetPath()) for a in anim[:4]]
        more = f" and {len(anim) - 4} more" if len(anim) > 4 else ""
        start = start_time_code(stage) is not None and not t.IsDefault()
        why = " (the stage's startTimeCode)" if auto and start else ""
        hint = ""
        if t.IsDefault():
            hint = (
                ": animated attributes use their default value, or their schema fallback if "
                "they have none"
            )
        warn(
            f"{len(anim)} attributes have time samples ({', '.join(names)}{more}): baked at "
            f"{when}{why}{hint}; pass --time to bake another time"
        )
    for a in anim:
        # a default authored next to the samples (in any layer of the stack)
        if not any(spec.HasDefaultValue() for spec in a.GetPropertyStack(t)):
            continue
        d = a.Get(Usd.TimeCode.Default())
        v = a.Get(Usd.TimeCode(a.GetTimeSamples()[0]) if t.IsDefault() else t)
        try:
            same = bool(d == v)
        except Exception:  # pragma: no cover - exotic value types
            same = False
        if not same:
            used = "the default" if t.IsDefault() else "the time sample"
            warn(
                f"{a.GetPath()}: its default value and its time samples disagree; {used} is "
                f"used (baked at {when}); remove the one you do not mean"
            )
    return t, auto
