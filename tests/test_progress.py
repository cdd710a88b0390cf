"""usdahd.progress.CompileNotice: the summary after a compile names ``usdahd warmup`` (issue 16),
and a run that compiles nothing prints nothing (no hint either)."""

from __future__ import annotations

import io

import numba
import numpy as np

from usdahd import progress


def test_compile_summary_points_to_warmup():
    stream = io.StringIO()
    with progress.CompileNotice(stream=stream) as notice:

        @numba.njit(cache=False)
        def fresh(x):  # never cached: always compiles
            return np.sqrt(x) + 1.0

        fresh(4.0)
    assert notice.announced
    last = stream.getvalue().strip().splitlines()[-1]
    assert last.startswith("compiled kernels in ")
    assert "(cached for later runs; " in last and "`usdahd warmup` compiles them ahead" in last


def test_no_hint_without_a_compile():
    stream = io.StringIO()
    with progress.CompileNotice(stream=stream):
        np.sqrt(4.0)
    assert stream.getvalue() == ""
