"""``python -m benchmarks.reference {compare,bake,summary,calibrate,seeds} ...`` (see README.md)."""

from __future__ import annotations

import sys


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        print("  compare STAGE --resolution N [--usdahd-args ...]: usdahd vs Cycles (see --help)")
        print("  bake STAGE --resolution N --spp S: Cycles I_z per mesh into an .npz")
        print("  summary A.json B.json ...: one line per stage from compare --json outputs")
        print("  calibrate [--spp S]: the analytic cases")
        print("  seeds STAGE --prim P --resolution N: one mesh's bias over many seeds and spp")
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd == "calibrate":
        from benchmarks.reference import calibrate

        return calibrate.main(rest)
    if cmd == "seeds":
        from benchmarks.reference import seeds

        return seeds.main(rest)
    if cmd in ("compare", "bake", "summary"):
        from benchmarks.reference import compare

        return compare.main([cmd, *rest])
    known = "compare, bake, summary, calibrate, seeds"
    print(f"error: unknown command {cmd!r} ({known})", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
