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


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_bar_told_not_to_draw_records_without_drawing():
    """Prims traced at once share one terminal line: the bar of a prim that waits for another
    keeps its count but draws nothing until it may (``update(..., draw=False)``)."""
    term = _Terminal()
    bar = progress.Progress("[2/3] /World/B", stream=term)
    bar.update(10, 100, draw=False)
    assert term.getvalue() == ""
    bar.update(20, 100)
    assert "[2/3] /World/B" in term.getvalue() and "20.0%" in term.getvalue()
