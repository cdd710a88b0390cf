"""Public alias: ``usdahd.sh`` is :mod:`usdahd.numerics.sh` (the same module object).

The SH basis, constants and quadrature rules live in ``usdahd/numerics/sh.py``; this alias keeps
``import usdahd.sh`` / ``from usdahd import sh`` working for users and scripts (README, docs).
Code inside the package imports :mod:`usdahd.numerics.sh` directly.
"""

import sys

from usdahd.numerics import sh as _sh

# Replace this module by the real one, so usdahd.sh.X is usdahd.numerics.sh.X for every name
# (private ones included) and monkeypatching either affects both.
sys.modules[__name__] = _sh
