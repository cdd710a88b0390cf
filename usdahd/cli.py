"""The ``usdahd`` command line: one subcommand per module in ``usdahd/commands/``.

Results go to stdout, progress and status to stderr. Exit status: 0 ok, 1 findings or a
failed prim, 2 usage or input error (argparse's own errors also exit 2), 130 interrupted.

Every subcommand takes the options of one parent parser (:func:`common_parser`): ``--json``
(stdout is always one JSON object, errors included) and ``-q/--quiet`` (no progress or status;
warnings still reach stderr; ``-qq`` prints errors only). Every error a user can cause ends in
:func:`main` as one line ``usdahd CMD: error: ...`` naming the file, prim or flag and the fix,
never a traceback (set ``USDAHD_DEBUG=1`` to see one for an internal error).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import json
import os
import sys

from usdahd.errors import UsdAhdError
from usdahd.version import __version__

__all__ = ["main"]

#: subcommand name -> module in usdahd.commands defining ``add_parser(subparsers)`` and
#: ``run(args) -> int``.
COMMANDS = {
    "bake": "usdahd.commands.bake",
    "validate": "usdahd.commands.validate",
    "fit": "usdahd.commands.fit",
    "bench": "usdahd.commands.bench",
    "plugin-path": "usdahd.commands.plugin_path",
    "preview": "usdahd.commands.preview",
    "warmup": "usdahd.commands.warmup",
    "export": "usdahd.commands.export",
}


#: Commands that load numba kernels in every run (:func:`_numba_without_scipy_blas` first).
NUMBA_COMMANDS = ("bake", "warmup")
#: Commands whose threads allocate: the process's malloc arenas capped first
#: (:func:`usdahd.budget.cap_malloc_arenas`: peak memory).
ARENA_COMMANDS = ("bake", "validate", "preview", "warmup")


def _numba_without_scipy_blas() -> None:
    """Import numba's array-math registry without importing SciPy's BLAS.

    numba's ``numba.np.arraymath`` checks at import whether ``scipy.linalg.cython_blas``
    imports (``_HAVE_BLAS``), and so imports all of ``scipy.linalg`` when SciPy is installed:
    0.13 s of CPU in every ``usdahd bake`` process (docs/time-to-quality.md, issue 43), for a
    flag that only picks BLAS or a plain loop for ``np.vdot``-style inner products, which no
    usdahd kernel uses (they call no BLAS: numerics/cholesky.py is hand-written). The module
    is imported here with that one import blocked for the duration, then unblocked: SciPy and
    numba's own ``np.dot``/``np.linalg`` support (which imports SciPy's BLAS when it compiles)
    work as before. A no-op when numba's registry or SciPy's BLAS is already imported."""
    blas = "scipy.linalg.cython_blas"
    if "numba.np.arraymath" in sys.modules or blas in sys.modules:
        return
    sys.modules[blas] = None  # an import of it raises ImportError without importing scipy
    try:
        import numba.np.arraymath  # noqa: F401
    except ImportError:
        pass  # numba missing: the command says so where it needs it
    finally:
        if sys.modules.get(blas, 0) is None:
            del sys.modules[blas]


def _available():
    for name, path in COMMANDS.items():
        try:
            yield name, importlib.import_module(path)
        except ModuleNotFoundError as exc:
            if exc.name != path:
                raise


def common_parser() -> argparse.ArgumentParser:
    """The options every subcommand takes (an argparse parent parser)."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("output")
    g.add_argument(
        "--json",
        action="store_true",
        help="print one machine-readable JSON object on stdout (also on errors)",
    )
    g.add_argument(
        "-q",
        "--quiet",
        action="count",
        default=0,
        help="no progress or status on stderr (warnings still shown); -qq: errors only",
    )
    return p


class _Subparsers:
    """Wraps argparse's subparsers so every ``add_parser`` gets the common parent parser."""

    def __init__(self, sub):
        self._sub = sub

    def add_parser(self, name, **kw):
        kw["parents"] = [*kw.get("parents", []), common_parser()]
        return self._sub.add_parser(name, **kw)

    def __getattr__(self, name):
        return getattr(self._sub, name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="usdahd",
        description=(
            "Bake directional lightmaps (IrradZ AHD/HHD/HLSH, SH, ambient cube) from an OpenUSD "
            "stage, describe them with the AhdLightmapAPI schema, and validate them in asset CI."
        ),
    )
    parser.add_argument("--version", action="version", version=f"usdahd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wrapped = _Subparsers(sub)
    for _name, mod in _available():
        mod.add_parser(wrapped)
    return parser


def describe_error(exc: BaseException) -> tuple[str, int]:
    """(one-line message, exit code) for an exception a user can cause.

    UsdAhdError carries its own; OS errors name the file and the fix; pxr's Tf.ErrorException
    gives USD's messages, whole, without the C++ location in front of them. Anything else is
    an internal error (exit 2, "please report").
    """
    if isinstance(exc, UsdAhdError):
        return str(exc), exc.exit_code
    if isinstance(exc, MemoryError):
        return (
            "out of memory; lower --resolution or --texel-density, or bake fewer prims (--prim)",
            2,
        )
    if isinstance(exc, OSError):
        where = exc.filename or ""
        what = exc.strerror or str(exc)
        fix = {
            errno.EACCES: "check the permissions or choose another output with -o",
            errno.EPERM: "check the permissions or choose another output with -o",
            errno.EROFS: "the file system is read-only: choose another output with -o",
            errno.ENOSPC: "the disk is full: free some space and re-run (the previous bake "
            "is intact)",
            errno.EISDIR: "give a file, not a directory",
            errno.ENOTDIR: "a path component is not a directory",
            errno.ENOENT: "check the path",
        }.get(exc.errno, "check the path and re-run")
        return (f"{where}: {what}; {fix}" if where else f"{what}; {fix}"), 2
    if type(exc).__module__.startswith("pxr") or type(exc).__name__ == "ErrorException":
        from usdahd.usd.diagnostics import exception_causes  # USD's messages, whole, no C++ site

        return f"USD: {'; '.join(exception_causes(exc))}", 2
    return (
        f"internal error {type(exc).__name__}: {str(exc)[:300]} (please report a bug; "
        "set USDAHD_DEBUG=1 for the traceback)",
        2,
    )


def _error(command: str, message: str, code: int, as_json: bool) -> int:
    from usdahd import progress

    progress.clear_line()
    print(f"usdahd {command}: error: {message}", file=sys.stderr)
    if as_json:
        print(json.dumps({"command": command, "exit_code": code, "error": message}, indent=2))
    return code


def _run_captured(args, command: str) -> int:
    """Run the command with USD's own diagnostics trapped (usdahd.usd.diagnostics): none is
    printed raw; each one usdahd did not report in its own words is printed once when the
    command ends, ``usdahd CMD: warning: USD: <message>`` on stderr (not with -qq)."""
    if command not in ("bake", "validate", "preview", "export"):  # the commands reading stages
        return int(args.func(args) or 0)
    from usdahd.usd import diagnostics

    diags = []
    try:
        with diagnostics.capture() as diags:
            return int(args.func(args) or 0)
    finally:
        if int(getattr(args, "quiet", 0) or 0) < 2:
            from usdahd import progress

            progress.clear_line()
            diagnostics.report(
                diags, lambda line: print(f"usdahd {command}: warning: {line}", file=sys.stderr)
            )


def _interrupted(command: str, as_json: bool) -> int:
    from usdahd import progress

    progress.clear_line()
    print(f"usdahd {command}: interrupted", file=sys.stderr)
    if as_json:
        print(json.dumps({"command": command, "exit_code": 130, "error": "interrupted"}))
    return 130


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    as_json = "--json" in argv
    command = next((a for a in argv if a in COMMANDS), "")
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:
            if exc.code not in (0, None) and as_json:
                msg = f"invalid arguments (see usdahd {command} --help)".replace("  ", " ")
                print(json.dumps({"command": command, "exit_code": 2, "error": msg}, indent=2))
            raise
        command = args.command
        as_json = bool(getattr(args, "json", False))
        if command in ARENA_COMMANDS:
            from usdahd import budget

            budget.cap_malloc_arenas()
        if command in NUMBA_COMMANDS:
            _numba_without_scipy_blas()
        return _run_captured(args, command)
    except KeyboardInterrupt:
        return _interrupted(command, as_json)
    except SystemExit:
        raise
    except Exception as exc:
        from usdahd.console import was_interrupted

        if was_interrupted(exc):  # a Ctrl-C inside an import comes out as ImportError (numpy)
            return _interrupted(command, as_json)
        if os.environ.get("USDAHD_DEBUG") and not isinstance(exc, UsdAhdError):
            raise
        message, code = describe_error(exc)
        return _error(command, message, code, as_json)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
