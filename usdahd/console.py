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

__all__ = ["main", "was_interrupted"]

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
    try:
        import signal

        signal.signal(signal.SIGINT, _on_sigint)
        from usdahd.cli import main as cli_main

        return cli_main()
    except KeyboardInterrupt:
        return interrupted()


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
