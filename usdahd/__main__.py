import sys

try:
    from usdahd.cli import main
except KeyboardInterrupt:  # Ctrl-C while importing (pxr, numba): no traceback
    print("usdahd: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
