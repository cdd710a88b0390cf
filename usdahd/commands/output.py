"""How every command prints its result: one JSON document on stdout with ``--json``, else
human-readable lines; ``-q`` keeps the results on stdout (it hides progress and status on
stderr), ``-qq`` hides them too (errors only). Warnings go to stderr separately."""

from __future__ import annotations

import json
from collections.abc import Callable

__all__ = ["emit"]


def emit(args, report: dict, human: Callable[[], None]) -> None:
    """Print ``report`` as indented JSON when ``args.json``; else call ``human()`` (which prints
    the result lines a person reads) unless ``-qq``. ``args`` may lack either attribute."""
    if getattr(args, "json", False):
        print(json.dumps(report, indent=2))
    elif int(getattr(args, "quiet", 0) or 0) < 2:
        human()
