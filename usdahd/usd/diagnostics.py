"""USD's own diagnostics (TfWarning, TfError, TfStatus), captured instead of printed raw.

USD reports through its diagnostic manager, whose default delegate prints each message to the
process's stderr as ``Warning: in _ReportErrors at line 3326 of .../stage.cpp -- In </P>: ...``:
beside usdahd's own line for the same problem, sometimes twice, and with the C++ location in
front of the cause. :func:`capture` traps them (``Tf.DiagnosticTrap``, usd-core >= 25.8) so a
command can report each once in usdahd's format (:func:`report`): ``warning: USD: <message>``,
never cut before its cause.

The trap is per thread: it takes what the calling thread posts (everything a stage open,
composition, the scene reader and UsdValidation's serial validators post here). A secondary
thread's diagnostics still reach USD's printer; :func:`from_stderr_lines` turns such captured
lines into the same form.

Errors posted inside a Python-wrapped USD call are raised by pxr as ``Tf.ErrorException``; the
trap does not change that. :func:`exception_causes` extracts their messages.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

from pxr import Tf

__all__ = [
    "Diagnostic",
    "capture",
    "exception_causes",
    "from_stderr_lines",
    "is_usd_error",
    "report",
]

#: The functions whose warnings restate a stage's composition errors: usdahd reports those
#: itself from ``UsdStage.GetCompositionErrors()`` (usdahd.usd.composition), with their cause.
COMPOSITION_SOURCES = ("_ReportErrors", "_ReportPcpErrors")
#: USD's own prefixes of a printed diagnostic line.
PRINTED_PREFIXES = ("Warning: in ", "Error: in ", "Coding Error: in ", "Runtime Error: in ")


@dataclass(frozen=True)
class Diagnostic:
    """One USD diagnostic. kind : "warning", "error" or "status"; message : USD's commentary
    (whole, one line); source : the C++ function that posted it (short name)."""

    kind: str
    message: str
    source: str = ""

    @property
    def restates_composition(self) -> bool:
        """Whether it repeats a composition error usdahd reports itself."""
        return self.source.rsplit("::", 1)[-1] in COMPOSITION_SOURCES

    def line(self) -> str:
        """usdahd's one line for it: ``USD: <message>`` (warnings and statuses) or
        ``USD error: <message>``."""
        return f"USD{' error' if self.kind == 'error' else ''}: {self.message}"


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _short(function: str) -> str:
    return str(function or "").rsplit("::", 1)[-1]


class Captured(list):
    """The diagnostics of a :func:`capture` block (a list of Diagnostic, unique, in order)."""

    def add(self, diag: Diagnostic) -> None:
        if diag.message and all((d.kind, d.message) != (diag.kind, diag.message) for d in self):
            self.append(diag)

    def drop(self, messages) -> None:
        """Forget the diagnostics whose message contains one of ``messages`` (the caller
        reported them in its own words); also in the enclosing capture they were forwarded
        to."""
        messages = [m for m in messages if m]
        keep = [d for d in self if not any(m in d.message for m in messages)]
        self[:] = keep
        for outer in _stack():
            outer[:] = [d for d in outer if not any(m in d.message for m in messages)]

    def unreported(self) -> list[Diagnostic]:
        """The ones usdahd has not reported in its own words (all but composition restates)."""
        return [d for d in self if not d.restates_composition]


_ACTIVE = threading.local()


def _stack() -> list:
    if not hasattr(_ACTIVE, "stack"):
        _ACTIVE.stack = []
    return _ACTIVE.stack


@contextlib.contextmanager
def capture(forward: bool = False):
    """Trap what USD posts on this thread during the block; yields a :class:`Captured` list,
    filled when the block ends (also when it raises).

    forward : when this block sits inside another :func:`capture` (e.g. a stage opened during
    a command that captures), hand the diagnostics on to it at the end as well, so the outer
    block reports them (the inner caller only looks at them, e.g. to drop what it reported in
    its own words with :meth:`Captured.drop`)."""
    out = Captured()
    trap_type = getattr(Tf, "DiagnosticTrap", None)
    if trap_type is None:  # pragma: no cover - usd-core < 25.8: USD prints them itself
        yield out
        return
    stack = _stack()
    stack.append(out)
    with trap_type() as trap:
        try:
            yield out
        finally:
            stack.pop()
            for kind, items in (
                ("error", trap.GetErrors()),
                ("warning", trap.GetWarnings()),
                ("status", trap.GetStatuses()),
            ):
                for d in items:
                    out.add(Diagnostic(kind, _one_line(d.commentary), _short(d.sourceFunction)))
            trap.Clear()  # handled here: nothing reaches USD's printer
            if forward and stack:
                for d in out:
                    stack[-1].add(d)


def is_usd_error(exc: BaseException) -> bool:
    """Whether ``exc`` is pxr's ``Tf.ErrorException`` (errors USD posted during a call)."""
    return isinstance(exc, Tf.ErrorException)


def exception_causes(exc: BaseException) -> list[str]:
    """The messages of a ``Tf.ErrorException`` (one per posted error, unique, in order); for
    another exception its text."""
    causes = []
    for arg in getattr(exc, "args", ()):
        text = _one_line(getattr(arg, "commentary", "") or "")
        if text and text not in causes:
            causes.append(text)
    if not causes:
        text = str(exc).strip()
        for ln in text.splitlines():
            ln = ln.strip()
            # "Error in 'F' at line N in file X : 'message'" -> message
            if ln.startswith("Error in ") and " : " in ln:
                ln = ln.split(" : ", 1)[1].strip().strip("'")
            if ln and ln not in causes:
                causes.append(ln)
    return causes or [type(exc).__name__]


def from_stderr_lines(lines) -> list[Diagnostic]:
    """Diagnostics from lines USD printed (``Warning: in F at line N of x.cpp -- message``),
    unique; other lines are ignored."""
    out = Captured()
    for ln in lines:
        ln = ln.strip()
        secondary = ln.replace(" (secondary thread)", "")
        if not secondary.startswith(PRINTED_PREFIXES):
            continue
        kind = "warning" if secondary.startswith("Warning") else "error"
        head, _, msg = secondary.partition(" -- ")
        func = head.split(" in ", 1)[1].split(" at line ", 1)[0] if " in " in head else ""
        out.add(Diagnostic(kind, _one_line(msg or secondary), _short(func)))
    return list(out)


def report(diags, warn) -> int:
    """Pass each diagnostic usdahd has not reported itself to ``warn`` once, as
    :meth:`Diagnostic.line`; returns how many."""
    seen, n = set(), 0
    for d in diags:
        if d.restates_composition or d.line() in seen:
            continue
        seen.add(d.line())
        warn(d.line())
        n += 1
    return n
