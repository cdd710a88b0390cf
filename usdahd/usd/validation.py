"""The UsdValidation side of the validator: registering rule functions as USD validators,
converting findings to and from ``UsdValidation.ValidationError``, building the
``ValidationContext`` that ``usdahd validate`` runs, and capturing USD's C++ diagnostics.

The rules themselves are pxr-free functions in :mod:`usdahd.validate`; they reach this module
through callables (a rule is ``check(prim) -> list[finding]``), so ``usd/`` never imports the
validator. A *finding* here is any object with ``severity`` ("error", "warning" or "info"),
``prim`` (a prim path string), ``code`` and ``message`` (:class:`usdahd.validate.Finding`).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile

from pxr import Sdf, Usd, UsdValidation

from usdahd.errors import StageError, UsageError

__all__ = [
    "captured_stderr_fd",
    "context",
    "error_record",
    "is_usd_diagnostic",
    "prim_task",
    "register_validator",
    "run_context",
    "stage_task",
    "to_error",
    "validator_doc",
]

_TYPES = {
    "error": UsdValidation.ValidationErrorType.Error,
    "warning": UsdValidation.ValidationErrorType.Warn,
    "info": UsdValidation.ValidationErrorType.Info,
}

# ---------------------------------------------------------------------- findings <-> errors


def to_error(finding, stage) -> UsdValidation.ValidationError:
    """The ValidationError of a finding, sited at its prim on ``stage``."""
    site = UsdValidation.ValidationErrorSite(stage, Sdf.Path(finding.prim))
    return UsdValidation.ValidationError(
        finding.code, _TYPES[finding.severity], [site], finding.message
    )


def _internal_error(stage, path, rule: str, exc: Exception) -> UsdValidation.ValidationError:
    site = UsdValidation.ValidationErrorSite(stage, path)
    return UsdValidation.ValidationError(
        "InternalError",
        UsdValidation.ValidationErrorType.Error,
        [site],
        f"rule {rule} could not run: {exc}",
    )


def error_record(error) -> tuple[str, str, str, str, str]:
    """(validator name, severity, prim, code, message) of a ValidationError (ours or a built-in
    validator's). prim : the first site's prim path, a property's prim path, or
    ``@layer identifier@`` for a layer site; "" without a site."""
    validator = error.GetValidator()
    vname = validator.GetMetadata().name if validator else ""
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
    return vname, sev, prim, str(error.GetName()), error.GetMessage()


# ------------------------------------------------------------------------------ registration


def prim_task(rule: str, check):
    """A UsdValidation prim task running ``check(prim) -> list[finding]``.

    Findings become ValidationErrors on the prim's stage; an exception (an exception escaping
    a Python validator would abort the whole UsdValidation run) becomes one ``InternalError``.
    """

    def task(prim, time_range=None):
        try:
            stage = prim.GetStage()
            return [to_error(f, stage) for f in check(prim)]
        except Exception as exc:  # noqa: BLE001 - never let an exception abort Validate()
            return [_internal_error(prim.GetStage(), prim.GetPath(), rule, exc)]

    task.__name__ = f"usdahd_{rule}"
    return task


def stage_task(rule: str, check):
    """A UsdValidation stage task running ``check(stage) -> list[finding]`` (an exception
    becomes one ``InternalError`` on ``/``)."""

    def task(stage, time_range=None):
        try:
            return [to_error(f, stage) for f in check(stage)]
        except Exception as exc:  # noqa: BLE001 - never let an exception abort Validate()
            return [_internal_error(stage, Sdf.Path.absoluteRootPath, rule, exc)]

    task.__name__ = f"usdahd_{rule}"
    return task


def register_validator(name: str, task, stage: bool = False) -> bool:
    """Register ``task`` as the plugin validator ``name`` (a prim validator, or a stage
    validator with ``stage``). Idempotent, and only when a plugInfo declared ``name`` (USD
    refuses the others); returns whether this call registered it."""
    reg = UsdValidation.ValidationRegistry()
    if reg.HasValidator(name) or reg.GetValidatorMetadata(name) is None:
        return False
    if stage:
        reg.RegisterPluginStageValidator(name, task)
    else:
        reg.RegisterPluginPrimValidator(name, task)
    return True


# ---------------------------------------------------------------------------------- running


def context(keyword: str, required: list[str], builtins, extra: str | None = None):
    """The ValidationContext of every validator of ``keyword`` plus the ``builtins`` that are
    registered (plus the validator ``extra``, e.g. the opt-in Retrace).

    Raises StageError when a name of ``required`` is not among the keyword's validators (the
    registry was built before usdahd registered its plugins) or ``extra`` is not registered.
    """
    reg = UsdValidation.ValidationRegistry()
    metas = list(reg.GetValidatorMetadataForKeyword(keyword))
    ours = {m.name for m in metas}
    missing = [n for n in required if n not in ours]
    if missing:
        raise StageError(
            f"the usdahd validators are not registered ({', '.join(missing)}): USD's validation "
            "registry was created before usdahd registered its plugins; import usdahd.usd first or "
            "set PXR_PLUGINPATH_NAME to the output of 'usdahd plugin-path'"
        )
    for name in builtins:
        m = reg.GetValidatorMetadata(name)
        if m is not None:
            metas.append(m)
    if extra is not None:
        m = reg.GetValidatorMetadata(extra)
        if m is None or not reg.HasValidator(extra):
            raise StageError(
                f"the usdahd validator {extra} is not registered: its plugInfo "
                "(plugins/usdAhdValidators) is older than this usdahd; reinstall usdahd"
            )
        metas.append(m)
    return UsdValidation.ValidationContext(metadata=metas, includeAllAncestors=False)


def run_context(ctx, stage, prims: list[str] | None = None) -> list:
    """ValidationErrors of ``ctx`` on the whole stage, or on the prims at ``prims`` and their
    descendants (UsageError ``--prim P: no such prim`` for a path that is not on the stage)."""
    if not prims:
        return list(ctx.Validate(stage))
    selected = []
    for p in prims:
        try:
            prim = stage.GetPrimAtPath(Sdf.Path(p))
        except Exception:
            prim = None
        if not prim:
            raise UsageError(f"--prim {p}: no such prim on the stage")
        selected += list(Usd.PrimRange(prim))
    return list(ctx.Validate(selected))


# ------------------------------------------------------------------------------ diagnostics


@contextlib.contextmanager
def captured_stderr_fd():
    """Capture what C++ code (USD's TfDiagnostic warnings) writes to file descriptor 2.

    Yields a list that holds the captured, non-empty lines after the block, so USD's own
    messages ("Ill-formed SdfPath", "Failed to resolve reference") do not interleave with the
    findings; ``usdahd validate`` reports them separately.
    """
    lines: list[str] = []
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded use): nothing to capture
        yield lines
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", errors="replace")
            lines += [ln.strip() for ln in text.splitlines() if ln.strip()]


def is_usd_diagnostic(line: str) -> bool:
    """A line of USD's TfDiagnostic output (``Warning: in F at line N of x.cpp -- ...``)."""
    return line.startswith(("Warning: in ", "Error: in ", "Coding Error: in ", "Runtime Error"))


def usd_diagnostic(line: str) -> str:
    """``Warning: in F at line N of /path/x.cpp -- message`` -> ``message``."""
    return line.split(" -- ", 1)[1] if " -- " in line else line


def validator_doc(name: str) -> str:
    """The ``doc`` string of a registered validator (USD's built-ins have one), or ''."""
    try:
        meta = UsdValidation.ValidationRegistry().GetValidatorMetadata(name)
    except Exception:
        return ""
    return str(getattr(meta, "doc", "") or "") if meta is not None else ""
