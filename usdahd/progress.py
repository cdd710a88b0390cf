"""Progress on stderr: a bar with rate and ETA, and the numba compile notice.

- :class:`Progress`: ``update(done, total)`` redraws at most ~5 times per second on a terminal;
  on a non-terminal stderr (CI logs) it prints a plain line at most every 10 s, and ``close``
  always prints the final 100 % line there so logs show every mesh finishing.
- :class:`CompileNotice`: while numba compiles kernels (the first run after installing), prints
  ``compiling kernels (first run only)…`` with the elapsed time, and the total when done
  (pointing to ``usdahd warmup``, which compiles them ahead of a first bake). Time
  spent compiling is excluded from every :class:`Progress` rate and ETA.
"""

from __future__ import annotations

import sys
import threading
import time

__all__ = ["CompileNotice", "Progress", "clear_line"]

#: Said after a compile: the command that compiles every bake kernel ahead of a first bake.
WARMUP_HINT = "after installing or upgrading usdahd, `usdahd warmup` compiles them ahead"
#: Seconds numba spent compiling in this process (outermost compile events only).
_compile = {"seconds": 0.0, "depth": 0, "since": None}
_lock = threading.Lock()
#: The stream a progress line is drawn on without a newline yet (None: the line is clean).
_open_line: dict = {"stream": None, "width": 0}


def compile_seconds() -> float:
    """Seconds spent compiling numba kernels so far, including a compile still running."""
    with _lock:
        extra = time.perf_counter() - _compile["since"] if _compile["since"] is not None else 0.0
        return _compile["seconds"] + extra


def clear_line() -> None:
    """End a progress line still drawn on a terminal, so the next message starts clean."""
    stream, width = _open_line["stream"], _open_line["width"]
    if stream is not None:
        try:
            stream.write("\r" + " " * width + "\r")
            stream.flush()
        except (OSError, ValueError):
            pass
    _open_line["stream"] = None


def _draw(stream, tty: bool, line: str) -> None:
    if tty:
        width = max(len(line), _open_line["width"] if _open_line["stream"] is stream else 0)
        stream.write("\r" + line.ljust(width))  # pad over a longer previous line
        _open_line.update(stream=stream, width=width)
    else:
        stream.write(line + "\n")
    stream.flush()


class Progress:
    """Progress of a long job in "units" (rays, texels), printed to stderr."""

    def __init__(self, label: str, *, unit: str = "rays", quiet: bool = False, stream=None):
        self.label = label
        self.unit = unit
        self.quiet = bool(quiet)
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self._compile0 = compile_seconds()
        self._last = 0.0
        self._drawn = False
        self._done = 0.0
        self._total = None

    def _elapsed(self, now: float) -> float:
        """Wall time since start minus time numba spent compiling meanwhile."""
        return max(now - self.start - (compile_seconds() - self._compile0), 1e-9)

    def _line(self, done: float, total: float | None, now: float) -> str:
        rate = done / self._elapsed(now)
        parts = [f"{self.label}"]
        if total:
            frac = min(max(done / total, 0.0), 1.0)
            width = 24
            fill = int(frac * width)
            parts.append(f"[{'#' * fill}{'.' * (width - fill)}] {100 * frac:5.1f}%")
            if rate > 0 and frac < 1:
                parts.append(f"ETA {format_seconds((total - done) / rate)}")
        parts.append(f"{_si(rate)} {self.unit}/s")
        return "  ".join(parts)[:160]

    def update(self, done: float, total: float | None = None, *, draw: bool = True) -> None:
        """Record ``done`` of ``total`` units; redraw unless ``draw`` is False (a bar waiting
        for another on the same terminal line: only one prim's bar draws at a time)."""
        self._done, self._total = done, total
        if self.quiet or not draw:
            return
        now = time.perf_counter()
        interval = 0.2 if self.tty else 10.0
        if now - self._last < interval:
            return
        self._last = now
        _draw(self.stream, self.tty, self._line(done, total, now))
        self._drawn = True
        self._drawn_done = done

    def close(self) -> None:
        """Finish: a terminal line is erased; a log gets the final 100 % line."""
        if self.quiet:
            return
        if self.tty:
            if self._drawn:
                clear_line()
            return
        if (self._drawn or self._done) and getattr(self, "_drawn_done", None) != self._done:
            done = self._total or self._done
            line = self._line(done, done, time.perf_counter())
            line += f"  done in {format_seconds(self._elapsed(time.perf_counter()))}"
            _draw(self.stream, False, line)


class CompileNotice:
    """Context manager: report numba compiling kernels (first run after install) on stderr.

    Listens to numba's ``numba:compile`` events (fired only for real compiles, not for loads
    from numba's on-disk cache). The first compile prints ``compiling kernels (first run
    only)…``; on a terminal a thread keeps the elapsed time on that line; at the end of each
    run of compiles (or on exit) it prints the total. Nothing is printed when every kernel
    comes from the cache.
    """

    def __init__(self, *, quiet: bool = False, stream=None, tick: float = 1.0):
        self.quiet = bool(quiet)
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.tick = tick
        self.announced = False
        self._t0 = None
        self._stop = threading.Event()
        self._thread = None
        self._listener = None
        self._compiling = False

    # numba.core.event.Listener interface (built lazily so importing this module needs no numba)
    def _on_start(self, event) -> None:
        with _lock:
            _compile["depth"] += 1
            if _compile["depth"] == 1:
                _compile["since"] = time.perf_counter()
        if _compile["depth"] == 1 and not self._compiling:
            self._compiling = True
            if self._t0 is None:
                self._t0 = time.perf_counter()
                self._announce()

    def _on_end(self, event) -> None:
        with _lock:
            _compile["depth"] = max(0, _compile["depth"] - 1)
            if _compile["depth"] == 0 and _compile["since"] is not None:
                _compile["seconds"] += time.perf_counter() - _compile["since"]
                _compile["since"] = None

    def _announce(self) -> None:
        self.announced = True
        if self.quiet:
            return
        clear_line()
        if self.tty:
            _draw(self.stream, True, "compiling kernels (first run only)… 0s")
            self._thread = threading.Thread(target=self._ticker, daemon=True)
            self._thread.start()
        else:
            self.stream.write("compiling kernels (first run only; later runs use the cache)…\n")
            self.stream.flush()

    def _ticker(self) -> None:
        while not self._stop.wait(self.tick):
            if _compile["since"] is None:
                continue  # between compiles: tracing may be drawing its own bar
            _draw(
                self.stream,
                True,
                f"compiling kernels (first run only)… {self.seconds():.0f}s",
            )

    def seconds(self) -> float:
        return compile_seconds() - self._c0

    def __enter__(self):
        self._c0 = compile_seconds()
        try:
            from numba.core import event as ev
        except ImportError:  # pragma: no cover - numba is a dependency
            return self
        outer = self

        class _Listener(ev.Listener):
            def on_start(self, event):
                outer._on_start(event)

            def on_end(self, event):
                outer._on_end(event)

        self._listener = _Listener()
        ev.register("numba:compile", self._listener)
        return self

    def finish(self) -> None:
        """Print the compile total once (call when the compiling part of the work is over)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * self.tick)
        if self.announced and not self.quiet:
            clear_line()
            self.stream.write(
                f"compiled kernels in {format_seconds(self.seconds())} (cached for later runs; "
                f"{WARMUP_HINT})\n"
            )
            self.stream.flush()

    def __exit__(self, *exc):
        if self._listener is not None:
            from numba.core import event as ev

            ev.unregister("numba:compile", self._listener)
            self._listener = None
        self.finish()
        return False


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
