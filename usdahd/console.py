"""The ``usdahd`` console script's entry point: a Ctrl-C at any moment exits 130 with one line.

The script imports this module before anything else, so it imports nothing at module level
(``usdahd/__init__`` is light too): a Ctrl-C that lands while the command line, pxr, numba or
OpenImageIO are being imported is a KeyboardInterrupt inside :func:`main`'s ``try``, never a
traceback (issue 40). Once running, :func:`usdahd.cli.main` reports interrupts itself.

A Ctrl-C that lands inside a C extension's import can come out as another exception: numpy
turns it into ``ImportError`` ("IMPORTANT: PLEASE READ THIS ..."). So the script's SIGINT
handler also records that an interrupt arrived (:func:`was_interrupted`), and the CLI reports
any error raised after that as the interrupt it is (exit 130), not as an internal error.
"""

__all__ = ["leave", "main", "was_interrupted"]

_INTERRUPTS = [0]


def _on_sigint(signum, frame):
    _INTERRUPTS[0] += 1
    raise KeyboardInterrupt


def was_interrupted(exc: BaseException | None = None) -> bool:
    """Whether a Ctrl-C reached the console script, or ``exc`` was caused by one (its cause or
    context chain holds a KeyboardInterrupt)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return _INTERRUPTS[0] > 0


def main() -> int:
    """Run the command line and end the process with its exit status (see :func:`leave`)."""
    try:
        import signal

        signal.signal(signal.SIGINT, _on_sigint)
        from usdahd.cli import main as cli_main

        code = cli_main()
    except KeyboardInterrupt:
        code = interrupted()
    return leave(code)


def leave(code: int) -> int:
    """End the process with ``code`` once the command is done, skipping the interpreter's
    teardown: the atexit handlers run and stdout / stderr are flushed, then ``os._exit``.
    The teardown frees what the OS frees anyway (C++ static destructors of pxr, LLVM, OIDN,
    TBB, and every module's objects) and took ~0.2 s of a 1.1 s ``usdahd bake`` of a 32^2
    sample (issue 43, docs/time-to-quality.md). Every file usdahd writes is closed (and
    atomically renamed) before the command returns. Returns ``code`` instead (the normal
    exit) when another Python thread is alive, when flushing fails (a closed pipe: Python
    reports it as usual) or with ``USDAHD_FULL_EXIT=1`` set."""
    import atexit
    import os
    import sys
    import threading

    if os.environ.get("USDAHD_FULL_EXIT") or threading.active_count() > 1:
        return code
    try:
        atexit._run_exitfuncs()  # clears them: the normal exit would not run them twice
        sys.stdout.flush()
        sys.stderr.flush()
    except BaseException:  # e.g. BrokenPipeError: the normal exit reports it
        return code
    os._exit(code if isinstance(code, int) else 1)


def interrupted() -> int:
    """One line on stderr (and the JSON error with --json), exit status 130; a second Ctrl-C
    while it prints is ignored."""
    import signal
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    command = next((a for a in sys.argv[1:] if not a.startswith("-")), "")
    name = f"usdahd {command}".strip()
    try:
        print(f"{name}: interrupted", file=sys.stderr, flush=True)
        if "--json" in sys.argv[1:]:
            import json

            print(json.dumps({"command": command, "exit_code": 130, "error": "interrupted"}))
    except (OSError, ValueError):
        pass
    return 130
