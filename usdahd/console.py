"""The ``usdahd`` console script's entry point: a Ctrl-C at any moment exits 130 with one line.

The script imports this module before anything else, so it imports nothing at module level
(``usdahd/__init__`` is light too): a Ctrl-C that lands while the command line, pxr, numba or
OpenImageIO are being imported is a KeyboardInterrupt inside :func:`main`'s ``try``, never a
traceback (issue 40). Once running, :func:`usdahd.cli.main` reports interrupts itself.
"""

__all__ = ["main"]


def main() -> int:
    try:
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
