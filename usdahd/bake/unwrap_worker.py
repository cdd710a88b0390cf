"""The worker processes that run xatlas for :mod:`usdahd.bake.unwrap`.

xatlas 0.0.11 can segfault (some meshes) or deadlock (its thread pool, every thread on a
futex), so unwraps run in long-lived child processes: a crash fails one prim, a stall is
seen from the child's CPU time (Linux /proc) and retried once. The deadlock is xatlas's
``Destroy`` (found with gdb), so atlases are made by :func:`new_atlas` and destroyed only
seconds after their use, and a worker leaves without destroying its last ones. The requests
are pickled arguments of :func:`usdahd.bake.unwrap.pack_part`, framed by an 8-byte
big-endian length.
"""

from __future__ import annotations

from usdahd.errors import BakeError, UsageError

__all__ = [
    "ATLAS_RETIRE_S",
    "CHILD_CODE",
    "STALL_POLL_S",
    "STALL_S",
    "Worker",
    "child_main",
    "cpu_seconds",
    "forget",
    "new_atlas",
    "slot_worker",
    "stop_worker",
]

#: A worker that uses no CPU time for this long (seconds) while it unwraps a mesh is wedged:
#: xatlas 0.0.11's thread pool can deadlock, every thread of the process waiting on a futex
#: (seen three times in a day of plans of the classroom and Sponza on a loaded 2-core machine,
#: on meshes that unwrap in a second). It is stopped and the mesh retried once in a fresh
#: worker (xatlas is deterministic: the same layout), instead of waiting UNWRAP_TIMEOUT_S.
#: Linux only (/proc); elsewhere the timeout alone applies. 10 s: a live xatlas run uses CPU
#: every clock tick it is scheduled (even a nice-19 process against busy cores gets ~1.5 %,
#: i.e. ticks every second), and a deadlock costs this long before the retry.
STALL_S = 10.0
#: How often (seconds) a waiting parent looks at its worker's CPU time.
STALL_POLL_S = 2.0


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (all its threads), None when unknown."""
    import os

    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


#: Seconds an xatlas ``Atlas`` is kept alive after its last use (:func:`new_atlas`).
#: xatlas 0.0.11's ``Destroy`` wakes its thread pool's workers without holding their mutex and
#: then joins them: a worker preempted between testing its wake-up flag and going to sleep
#: misses the wake-up, and the join waits forever (gdb on a wedged unwrap worker: the main
#: thread in ``TaskScheduler::~TaskScheduler`` -> ``std::thread::join``, the pool's worker in
#: ``condition_variable::wait``; two classroom plans in a row with two workers at load ~7).
#: Seconds after its last task a worker is asleep for sure, and then the wake-up reaches it.
ATLAS_RETIRE_S = 2.0
_ATLASES: list[list] = []  # [atlas, time its use ended or None while in use]


def new_atlas():
    """A new ``xatlas.Atlas``, kept referenced until :data:`ATLAS_RETIRE_S` after the next
    atlas is made (unwraps run one at a time per process, so a new atlas means the earlier
    ones are done); the last ones of a process are never destroyed: the worker process leaves
    with ``os._exit`` (:func:`child_main`), and an in-process unwrap
    waits them out at exit (:func:`_retire_all`)."""
    import atexit
    import time

    import xatlas

    now = time.monotonic()
    if not _ATLASES:
        atexit.register(_retire_all)
    for entry in _ATLASES:
        if entry[1] is None:
            entry[1] = now
    _ATLASES[:] = [e for e in _ATLASES if now - e[1] < ATLAS_RETIRE_S]
    atlas = xatlas.Atlas()
    _ATLASES.append([atlas, None])
    return atlas


def _retire_all() -> None:
    """At interpreter exit: destroy the atlases still kept once the youngest is
    :data:`ATLAS_RETIRE_S` old (at most that long a wait)."""
    import time

    if not _ATLASES:
        return
    now = time.monotonic()
    last = max(now if e[1] is None else e[1] for e in _ATLASES)
    time.sleep(max(0.0, last + ATLAS_RETIRE_S - now))
    _ATLASES.clear()


def child_main() -> None:
    """Worker-process entry point: for each request on stdin (an 8-byte big-endian length,
    then the pickled arguments of :func:`usdahd.bake.unwrap.pack_part`), run it and answer
    on stdout in the same framing with ("ok", result), ("usage" | "bake" | "error",
    message); stop at EOF."""
    import os
    import pickle
    import sys

    from usdahd.bake.unwrap import pack_part  # the child imports it; no import cycle

    inp, out = sys.stdin.buffer, sys.stdout.buffer
    while True:
        head = inp.read(8)
        if len(head) < 8:
            # leave without destroying the last xatlas atlases (ATLAS_RETIRE_S: the
            # destructor can deadlock); everything answered is flushed already
            sys.stderr.flush()
            os._exit(0)
        args = pickle.loads(inp.read(int.from_bytes(head, "big")))
        try:
            msg = ("ok", pack_part(*args))
        except UsageError as exc:
            msg = ("usage", str(exc))
        except BakeError as exc:  # already names the prim
            msg = ("bake", str(exc))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as a BakeError
            msg = ("error", f"{type(exc).__name__}: {exc}")
        data = pickle.dumps(msg)
        out.write(len(data).to_bytes(8, "big") + data)
        out.flush()


#: What the worker process runs (a module attribute so a test can make it crash).
CHILD_CODE = "from usdahd.bake.unwrap_worker import child_main; child_main()"


class Worker:
    """One long-lived child Python process that runs :func:`_pack` for mesh after mesh, so an
    unwrap costs xatlas's time, not an interpreter start-up each (classroom, 74 meshes
    without UVs: ~0.12 s each). xatlas 0.0.11 segfaults on some meshes (e.g. a subdivided
    icosphere of 82k triangles): that kills the worker, fails that one prim, and the next
    mesh starts a new worker. A plain subprocess (not multiprocessing) so the caller's
    __main__ is not re-run."""

    def __init__(self):
        import os
        import subprocess
        import sys
        import tempfile

        import usdahd

        root = os.path.dirname(os.path.dirname(os.path.abspath(usdahd.__file__)))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        # stderr to a file, not a pipe: a child that writes warnings mesh after mesh must not
        # block on a full pipe nobody reads until it dies
        self.err = tempfile.TemporaryFile()
        self.stalled = False
        self.proc = subprocess.Popen(
            [sys.executable, "-c", CHILD_CODE],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.err,
            env=env,
        )

    def alive(self) -> bool:
        return self.proc.poll() is None

    def request(self, data: bytes, timeout: float):
        """Send one pickled request; returns the unpickled reply, or None when the worker
        died; raises TimeoutError after ``timeout`` seconds (the worker is then stopped)."""
        import time

        if not self.send(data):
            return None
        return self.receive(time.monotonic() + timeout)

    def send(self, data: bytes) -> bool:
        """Send one pickled request; False when the worker is dead."""
        try:
            self.proc.stdin.write(len(data).to_bytes(8, "big") + data)
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            return False
        return True

    def receive(self, end: float):
        """The unpickled reply to the request sent, or None when the worker died; raises
        TimeoutError at ``end`` (time.monotonic(); the worker is then stopped)."""
        import pickle

        head = self._read(8, end)
        if head is None:
            return None
        body = self._read(int.from_bytes(head, "big"), end)
        return None if body is None else pickle.loads(body)

    def _read(self, n: int, end: float):
        import os
        import selectors
        import time

        fd = self.proc.stdout.fileno()
        buf = b""
        cpu, since = None, time.monotonic()
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while len(buf) < n:
                now = time.monotonic()
                left = end - now
                if left <= 0:
                    self.stop()
                    raise TimeoutError
                if not sel.select(min(left, STALL_POLL_S)):
                    used = cpu_seconds(self.proc.pid)
                    if used is None or used != cpu:
                        cpu, since = used, now
                    elif now - since >= STALL_S:
                        self.stalled = True
                        self.stop()
                        return None
                    continue
                chunk = os.read(fd, n - len(buf))
                if not chunk:
                    return None
                buf += chunk
        return buf

    def failure(self) -> str:
        """The dead worker's last stderr line or its exit code (or that it stalled)."""
        if self.stalled:
            return f"its threads stopped working: no CPU time for {STALL_S:g} s"
        try:
            self.proc.wait(timeout=5)
            self.err.seek(0)
            err = self.err.read().decode(errors="replace").strip().splitlines()
        except Exception:  # noqa: BLE001 - best effort: the message only
            err = []
        return err[-1] if err else f"exit code {self.proc.returncode}"

    def stop(self) -> None:
        if self.alive():
            self.proc.kill()
        try:
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - nothing more to do for a stuck child
            pass
        for f in (self.proc.stdin, self.proc.stdout, self.err):
            try:
                f.close()
            except OSError:
                pass


_worker: Worker | None = None  # the first worker; the others are in _helpers
_helpers: list[Worker | None] = []
_registered = False


def stop_worker() -> None:
    """Stop every worker process (the next unwrap starts new ones)."""
    global _worker
    for w in [_worker, *_helpers]:
        if w is not None:
            w.stop()
    _worker = None
    _helpers.clear()


def slot_worker(i: int, fresh: bool = False) -> Worker:
    """Worker ``i`` (0 is ``_worker``), started when missing, dead or ``fresh``."""
    import atexit

    global _worker, _registered
    if not _registered:
        atexit.register(stop_worker)
        _registered = True
    while len(_helpers) < i:
        _helpers.append(None)
    w = _worker if i == 0 else _helpers[i - 1]
    if w is None or fresh or not w.alive():
        if w is not None:
            w.stop()
        w = Worker()
        if i == 0:
            _worker = w
        else:
            _helpers[i - 1] = w
    return w


def forget(i: int) -> None:
    global _worker
    if i == 0:
        _worker = None
    elif i - 1 < len(_helpers):
        _helpers[i - 1] = None
