"""Opening a stage, and the stage-level metadata every reader depends on.

:func:`open_stage` is the one place a ``Usd.Stage`` is opened from a file (bake, validate,
preview, the scene reader): the same checks and the same one-line :class:`StageError` for a
missing, unreadable or non-UTF-8 file. :func:`meters_per_unit`, :func:`up_axis` and
:func:`composition_warnings` read what the scene reader (:mod:`usdahd.usd.reader`) needs from
the stage as a whole.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from usdahd.errors import StageError

__all__ = [
    "as_stage",
    "composition_warnings",
    "is_prim_path",
    "meters_per_unit",
    "meters_per_unit_authored",
    "open_stage",
    "prim_at",
    "up_axis",
    "fmt_values",
    "one_line",
    "utf8_problem",
]


def one_line(text, limit: int = 300) -> str:
    """``text`` on one line (whitespace runs collapsed), cut to ``limit`` characters."""
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def fmt_values(v) -> str:
    """A number or vector in messages: ``0.5`` or ``(1, 0, 0)``."""
    a = np.ravel(np.asarray(v, np.float64))
    return f"{a[0]:g}" if a.size == 1 else "(" + ", ".join(f"{x:g}" for x in a) + ")"


def utf8_problem(path) -> str:
    """Where a text layer stops being UTF-8 (USD text layers must be UTF-8)."""
    path = Path(path)
    data = path.read_bytes()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        return (
            f"{path}: not valid UTF-8 at line {line} (byte 0x{data[exc.start]:02x}); USD text "
            "layers must be UTF-8: re-save the file as UTF-8 (e.g. iconv -f latin1 -t utf-8)"
        )
    return f"{path}: not a readable USD stage (it names a layer or value that is not UTF-8)"


def open_stage(path, *, reload: bool = True):
    """Open the stage at ``path`` (str or PathLike). Returns a ``Usd.Stage``.

    reload : re-read the root layer from disk when this process opened it before (the layer
        registry keeps layers alive; a second in-process bake or validate must see files
        changed since: tests, long-lived pipeline tools). False keeps the registry's copy,
        with any unsaved edits made in this process.
    Raises StageError naming the file: no such file, not valid UTF-8 (the line and byte), or
    not a readable USD stage (USD's first line of error).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise StageError(f"{path}: no such file")
    if reload:
        cached = Sdf.Layer.Find(path)
        if cached is not None:
            cached.Reload(force=True)
    from usdahd.usd import diagnostics

    # USD's own messages (the composition errors it prints as "Warning: in _ReportErrors ...")
    # are trapped: composition problems are reported once by composition_warnings / the
    # Composition rule, the rest by the command that captures around this (usdahd.cli).
    try:
        with diagnostics.capture(forward=True):
            stage = Usd.Stage.Open(path)
    except UnicodeDecodeError:  # USD's message quotes the undecodable bytes
        raise StageError(utf8_problem(path)) from None
    except Exception as exc:  # pxr raises Tf.ErrorException with the errors it posted
        cause = "; ".join(diagnostics.exception_causes(exc))
        raise StageError(f"{path}: not a readable USD stage ({cause})") from None
    if stage is None:
        raise StageError(f"{path}: not a readable USD stage")
    return stage


def as_stage(stage):
    """A ``Usd.Stage`` or a path to one -> (stage, source: the file name used in messages).

    A path is opened with :func:`open_stage` (``reload=False``: the layer as this process
    holds it)."""
    if isinstance(stage, Usd.Stage):
        return stage, str(stage.GetRootLayer().identifier)
    path = os.fspath(stage)
    return open_stage(path, reload=False), path


def meters_per_unit(stage, source) -> float:
    """The stage's metersPerUnit. Raises StageError when it is not positive and finite."""
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (math.isfinite(mpu) and mpu > 0):
        raise StageError(
            f"{source}: stage metadata metersPerUnit = {mpu:g} must be a positive finite "
            "number (1 = metres, 0.01 = centimetres); fix it in the root layer"
        )
    return mpu


def prim_at(stage, path: str):
    """The prim at ``path`` (a ``Usd.Prim``), or None when the stage has none there."""
    prim = stage.GetPrimAtPath(path)
    return prim if prim else None


def meters_per_unit_authored(stage) -> bool:
    """Whether the stage authors metersPerUnit (else USD's fallback, 0.01, applies)."""
    return bool(UsdGeom.StageHasAuthoredMetersPerUnit(stage))


def is_prim_path(text: str) -> bool:
    """Whether ``text`` is an absolute prim path (like ``/World/Floor``)."""
    return Sdf.Path.IsValidPathString(text) and Sdf.Path(text).IsAbsolutePath()


def up_axis(stage, warn) -> str:
    """The stage's upAxis, "Y" or "Z"; anything else warns and is taken as "Y"."""
    axis = str(UsdGeom.GetStageUpAxis(stage))
    if axis not in ("Y", "Z"):
        warn(
            f"stage metadata upAxis = {axis!r} is not 'Y' or 'Z'; assuming 'Y' "
            "(fix the upAxis metadata in the root layer)"
        )
        axis = "Y"
    return axis


def composition_warnings(stage, source, warn) -> None:
    """Composition problems (:func:`usdahd.usd.composition.problems`), each once with its
    cause: a cycle raises StageError, the rest warn (the bake still runs: an arc USD could not
    compose is missing from the scene; an unselected variant's broken arc is not composed at
    all)."""
    from usdahd.usd import composition

    meshes = [
        str(p.GetPath())
        for p in Usd.PrimRange.Stage(stage)  # instance proxies are occluders, never baked
        if p.IsA(UsdGeom.Mesh)
    ]
    for prob in composition.problems(stage, meshes):
        if prob.cycle:
            raise StageError(
                f"{source}: composition cycle ({prob.cause}); remove the reference, payload or "
                "sublayer that points back to a layer already being composed"
            )
        if prob.variant:
            warn(f"{source}: <{prob.prim}>: {prob.message()}")
            continue
        if prob.is_materialx and not prob.baked:
            if _reads_materialx():
                continue  # the material reader names the file once where a binding uses it
            warn(f"{source}: <{prob.prim}>: {prob.message()}")
            continue
        n = len(prob.baked)
        touched = (
            f"{n} mesh(es) under it ({', '.join(prob.baked[:3])}{', ...' if n > 3 else ''}) "
            "are read without it"
            if n
            else "no mesh is composed from it"
        )
        also = (
            f" (also on {len(prob.also)} more prim(s): <{prob.also[0]}>, ...)" if prob.also else ""
        )
        warn(
            f"{source}: composition error, that part of the scene is missing ({touched}): "
            f"<{prob.prim}>: {prob.cause}{also}. Fix: repair or remove the arc (the file it "
            "names must exist and be a USD layer)"
        )


def _reads_materialx() -> bool:
    """Whether usdahd's MaterialX reader (usdahd.usd.materialx, issue 37) is installed: it
    reads materials from ``.mtlx`` files USD cannot compose and reports each such file itself,
    so the bake does not report the composition error a second time."""
    import importlib.util

    return importlib.util.find_spec("usdahd.usd.materialx") is not None
