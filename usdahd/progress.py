"""A small progress bar on stderr with rate and ETA; silent when quiet or not a terminal."""

from __future__ import annotations

import sys
import time


class Progress:
    """Progress of a long job in "units" (rays, texels), printed to stderr.

    ``update(done, total)`` redraws at most ~5 times per second. On a non-terminal stderr
    (CI logs) it prints a plain line at most every 10 s so logs stay short.
    """

    def __init__(self, label: str, *, unit: str = "rays", quiet: bool = False, stream=None):
        self.label = label
        self.unit = unit
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self._last = 0.0
        self._drawn = False

    def update(self, done: float, total: float | None = None) -> None:
        if self.quiet:
            return
        now = time.perf_counter()
        interval = 0.2 if self.tty else 10.0
        if now - self._last < interval:
            return
        self._last = now
        elapsed = max(now - self.start, 1e-9)
        rate = done / elapsed
        parts = [f"{self.label}"]
        if total:
            frac = min(max(done / total, 0.0), 1.0)
            width = 24
            fill = int(frac * width)
            parts.append(f"[{'#' * fill}{'.' * (width - fill)}] {100 * frac:5.1f}%")
            if rate > 0 and frac < 1:
                parts.append(f"ETA {format_seconds((total - done) / rate)}")
        parts.append(f"{_si(rate)} {self.unit}/s")
        line = "  ".join(parts)
        if self.tty:
            self.stream.write("\r" + line[:120].ljust(80))
            self._drawn = True
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self._drawn and not self.quiet:
            self.stream.write("\r" + " " * 80 + "\r")
            self.stream.flush()


def format_seconds(s: float) -> str:
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.1f}s"
    m, s = divmod(int(s), 60)
    if m < 60:
        return f"{m}m{s:02d}s"
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m"


def _si(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.0f}"
