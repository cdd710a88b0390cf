"""``usdahd bench``: regenerate docs/benchmarks.md and its plots (runs benchmarks/run.py).

The benchmark scripts and the sample stages they bake live in the source checkout
(``benchmarks/``, ``samples/``), not in the usdahd package. They are their own development
package, ``usdahd-bench`` (benchmarks/pyproject.toml, import name ``benchmarks``), installed
editable from a clone: ``pip install -e benchmarks/``. This command imports that installed
package and nothing else from a checkout (never a path guessed from usdahd's own location or
the current directory); without it, it says which command installs it.
"""

from __future__ import annotations

import argparse
import importlib

from usdahd.commands.output import emit
from usdahd.errors import UsageError

#: benchmarks/run.py's sections, all run by default (its DEFAULT_SECTIONS; kept equal by a test).
SECTIONS = "bake,fit,encodings,skipping,soak,ktx2,reference"

#: The distribution and module of the benchmark harness (benchmarks/pyproject.toml).
HARNESS = "usdahd-bench"
RUNNER = "benchmarks.run"

MISSING = (
    "usdahd bench runs the benchmark harness usdahd-bench, which is not installed; it is a "
    "development package of the source checkout: from a git clone of usdahd run "
    "pip install -e benchmarks/ then usdahd bench (or usdahd-bench, or python benchmarks/run.py)"
)


def load_runner(module: str = RUNNER):
    """The installed harness's runner module (``benchmarks.run``); UsageError naming the install
    command when the harness is not installed."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        # only the harness itself missing is this message; a missing dependency *of* the
        # harness (matplotlib, ...) propagates with its own name
        if exc.name is None or not (module == exc.name or module.startswith(exc.name + ".")):
            raise
        raise UsageError(MISSING) from None


def add_parser(sub):
    p = sub.add_parser(
        "bench",
        help="regenerate docs/benchmarks.md and its plots (pip install -e benchmarks/ first)",
        description=(
            "Run the benchmarks (bake run time against error, fit speed and error per model and "
            "solver, encodings after quantization, skipping, soak, KTX2 containers, usdahd vs "
            "Blender Cycles) and write docs/benchmarks.md with PNG plots in docs/benchmarks/. "
            "Same as python benchmarks/run.py and usdahd-bench; needs the benchmark harness, a "
            "development package of the source checkout (pip install -e benchmarks/)."
        ),
    )
    p.add_argument("--quick", action="store_true", help="~2-3 minute run (fewer samples)")
    p.add_argument("--out", default=None, help="report path (default: docs/benchmarks.md)")
    p.add_argument(
        "--sections",
        default=SECTIONS,
        help=f"comma-separated subset of {SECTIONS} (reference: usdahd vs Blender Cycles; needs "
        "$USDAHD_BPY_PYTHON, see benchmarks/reference/README.md; reported as not run without it)",
    )
    p.add_argument(
        "--reference-stages",
        nargs="+",
        metavar="STAGE",
        help="the reference section's stages by file stem (default: every lit sample stage and "
        "the shared Cornell boxes)",
    )
    p.add_argument("--fresh", action="store_true", help="recompute cached reference bakes")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    runner = load_runner()
    ns = argparse.Namespace(
        quick=args.quick,
        out=args.out or str(runner.common.DOCS / "benchmarks.md"),
        sections=args.sections,
        reference_stages=args.reference_stages,
        fresh=args.fresh,
        quiet=bool(args.quiet or args.json),
    )
    runner.check_args(ns)  # usage errors first
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise UsageError("usdahd bench needs matplotlib: pip install -e benchmarks/") from None
    out = runner.run(ns)
    emit(args, {"report": str(out), "exit_code": 0}, lambda: print(out))
    return 0
