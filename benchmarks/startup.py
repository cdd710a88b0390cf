"""First-bake start-up (issue 16): time to the first traced texel and numba compile time with a
fresh numba cache, as on the first ``usdahd bake`` after ``pip install``.

    python -m benchmarks.startup                      # 3 cold runs of samples/cornell_box.usda
    python -m benchmarks.startup --runs 5 --stop      # stop each run at the first progress
    python -m benchmarks.startup --json out.json
    python -m benchmarks.startup --runs 4 --stop --jobs 1 2   # alternate: without / with the
                                                              # second compiling process
    python -m benchmarks.startup --write-signatures    # rewrite the prefetch manifest

Each run is a new process with its own empty ``NUMBA_CACHE_DIR`` and a fresh copy of the stage,
baking with ``usdahd bake -q``. The child records (from numba's ``numba:compile`` events) the
compile seconds of every dispatcher (outermost compiles and each one's own share without the
callees it compiled), the specialisations each compiled (``dispatcher.signatures``), and the
moment the first call of the bake kernel (``native_pass``) returned: the first texels are traced
then; ``first progress`` is the first update of the bake's progress bar (after the kernel that
solves those texels' SH, ``native_result``, compiled too): what a user sees. Times are from the
child's launch (interpreter start and imports included). After the
cold runs one more run reuses the last cache: it must compile nothing (``warm compiles``).
Reports the median of each figure and the load average (``/proc/loadavg``) before and after:
on this 2-core machine other work running alongside inflates every figure.

``--jobs 1 2`` alternates the runs between ``USDAHD_COMPILE_JOBS=1`` (the bake compiles every
kernel itself) and 2 (the default: a second process compiles the kernels of
``usdahd.bake.kernels.prefetch.GROUPS`` meanwhile); ``cpu`` is then the bake process's CPU
seconds and ``cpu2`` the second process's (from ``/proc``, at the moment the run ended), and
``waited`` the seconds the bake waited for the second process's kernels.
``--write-signatures`` bakes ``usdahd warmup``'s stage once in a new, empty cache with one
process and writes the signatures of those kernels to ``usdahd/bake/kernels/signatures.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_STAGE = REPO / "samples" / "cornell_box.usda"


def _child(stage: str, out: str, stop: bool, write: bool = False) -> None:
    """Bake ``stage`` in this process, record compile events and the first texel into ``out``."""
    import threading

    from numba.core import event as ev

    launch = float(os.environ["STARTUP_LAUNCH"])
    local = threading.local()
    comp: dict = {}
    lock = threading.Lock()

    class _Listener(ev.Listener):
        def on_start(self, e):
            stack = getattr(local, "stack", None)
            if stack is None:
                stack = local.stack = []
            stack.append([time.perf_counter(), 0.0])

        def on_end(self, e):
            t0, inner = local.stack.pop()
            dt = time.perf_counter() - t0
            if local.stack:
                local.stack[-1][1] += dt
            f = e.data["dispatcher"].py_func
            name = f"{f.__module__}.{f.__qualname__}"
            with lock:
                r = comp.setdefault(name, {"outer": 0.0, "own": 0.0, "compiles": 0})
                r["own"] += dt - inner
                r["compiles"] += 1
                if not local.stack:
                    r["outer"] += dt

    ev.register("numba:compile", _Listener())

    import numba

    import usdahd.bake.integrate as integrate

    first: dict = {}
    kernel = integrate.native_pass

    def dump(rc: int) -> None:
        from usdahd.bake.kernels.prefetch import Prefetch, cpu_seconds

        pf = Prefetch.last
        second = None
        if pf is not None:
            cpu2 = cpu_seconds(pf.proc.pid) if pf.proc.poll() is None else None
            if cpu2 is None and pf.report:
                cpu2 = pf.report["cpu_seconds"]
            second = {"cpu": cpu2, "waited": pf.waited, "kernels": pf.names, "done": pf.done}
        sigs = {}
        for mod in list(sys.modules.values()):
            if not getattr(mod, "__name__", "").startswith("usdahd"):
                continue
            for v in list(vars(mod).values()):
                if isinstance(v, numba.core.dispatcher.Dispatcher) and v.signatures:
                    sigs[f"{v.py_func.__module__}.{v.py_func.__qualname__}"] = len(v.signatures)
        res = {
            "exit_code": rc,
            "first_texel": first.get("texel"),
            "first_progress": first.get("progress"),
            "total": time.time() - launch,
            "cpu": time.process_time(),
            "compile_total": sum(r["outer"] for r in comp.values()),
            "compiles": sum(r["compiles"] for r in comp.values()),
            "compile": comp,
            "signatures": sigs,
            "second": second,
        }
        Path(out).write_text(json.dumps(res, indent=1))

    def traced(*args):
        r = kernel(*args)
        first.setdefault("texel", time.time() - launch)
        return r

    from usdahd import progress

    update = progress.Progress.update

    def shown(self, done, total=None):
        if done and "progress" not in first:  # the bar's first line: texels traced and solved
            first["progress"] = time.time() - launch
            if stop:
                dump(0)
                os._exit(0)
        return update(self, done, total)

    integrate.native_pass = traced
    progress.Progress.update = shown
    from usdahd.cli import main

    if write:
        from usdahd.bake.kernels import prefetch

        rc = main(["bake", "-q", stage, "--resolution", "8", "--samples", "8"])
        print(prefetch.write_manifest(), file=sys.stderr)
        dump(rc)
        return
    dump(main(["bake", "-q", stage]))


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "?"


def _run(stage: Path, cache: Path, stop: bool, jobs: int = 2, write: bool = False) -> dict:
    with tempfile.TemporaryDirectory(prefix="usdahd-startup-") as tmp:
        shutil.copy(stage, Path(tmp) / stage.name)
        out = Path(tmp) / "result.json"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), STARTUP_LAUNCH=repr(time.time()))
        env["USDAHD_COMPILE_JOBS"] = str(jobs)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
        load0 = _loadavg()
        cmd = [sys.executable, "-m", "benchmarks.startup", "--child", str(Path(tmp) / stage.name)]
        cmd += ["--out", str(out)] + (["--stop"] if stop else []) + (["--write"] if write else [])
        subprocess.run(cmd, env=env, cwd=REPO, check=True)
        res = json.loads(out.read_text())
        res["load"] = (load0, _loadavg())
        res["jobs"] = jobs
        return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="cold runs (fresh cache each)")
    ap.add_argument("--stage", default=str(DEFAULT_STAGE))
    ap.add_argument("--stop", action="store_true", help="end each run at the first progress")
    ap.add_argument("--json", help="write all runs here")
    ap.add_argument(
        "--jobs",
        type=int,
        nargs="+",
        choices=(1, 2),
        default=[2],
        help="USDAHD_COMPILE_JOBS of the runs, in turn (1 2: alternate, 1 first)",
    )
    ap.add_argument(
        "--write-signatures",
        action="store_true",
        help="rewrite usdahd/bake/kernels/signatures.json from one cold bake, then stop",
    )
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--write", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        _child(a.child, a.out, a.stop, a.write)
        return 0
    if a.write_signatures:
        from usdahd.commands.warmup import STAGE

        with tempfile.TemporaryDirectory(prefix="usdahd-startup-") as tmp:
            stage = Path(tmp) / "warmup.usda"
            stage.write_text(STAGE)
            _run(stage, Path(tmp) / "cache", False, jobs=1, write=True)
        return 0
    stage = Path(a.stage).resolve()
    runs = []
    with tempfile.TemporaryDirectory(prefix="usdahd-startup-cache-") as caches:
        for i in range(a.runs):
            cache = Path(caches) / f"run{i}"
            runs.append(_run(stage, cache, a.stop, jobs=a.jobs[i % len(a.jobs)]))
            r = runs[-1]
            sec = r.get("second") or {}
            cpu2 = sec.get("cpu")
            print(
                f"run {i + 1} (jobs {r['jobs']}): first texel {r['first_texel']:.1f}s, first "
                f"progress {r['first_progress']:.1f}s, compile "
                f"{r['compile_total']:.1f}s ({r['compiles']} compiles), total {r['total']:.1f}s, "
                f"cpu {r['cpu']:.1f}s"
                + (f", cpu2 {cpu2:.1f}s, waited {sec['waited']:.1f}s" if cpu2 is not None else "")
                + f", load {r['load'][0]} -> {r['load'][1]}",
                file=sys.stderr,
                flush=True,
            )
        warm = _run(stage, cache, a.stop, jobs=a.jobs[-1])
    keys = ("first_texel", "first_progress", "compile_total")
    med = {k: statistics.median(r[k] for r in runs) for k in keys}
    med.update(total=statistics.median(r["total"] for r in runs))
    for j in sorted(set(a.jobs)):
        mine = [r for r in runs if r["jobs"] == j]
        if mine and len(set(a.jobs)) > 1:
            fp = statistics.median(r["first_progress"] for r in mine)
            cpu = statistics.median(r["cpu"] for r in mine)
            cpu2 = [r["second"]["cpu"] for r in mine if r.get("second") and r["second"]["cpu"]]
            print(
                f"  jobs {j}: first progress {fp:6.1f} s, cpu {cpu:.1f} s"
                + (f" + {statistics.median(cpu2):.1f} s" if cpu2 else "")
                + f" (median of {len(mine)})"
            )
    top: dict = {}
    for r in runs:
        for name, c in r["compile"].items():
            top.setdefault(name, []).append(c["own"])
    print(f"{stage.name}: {a.runs} cold runs (median)")
    print(f"  first texel     {med['first_texel']:6.1f} s    (first bake-kernel call returned)")
    print(f"  first progress  {med['first_progress']:6.1f} s    (first line of the progress bar)")
    print(f"  compile total   {med['compile_total']:6.1f} s")
    print(f"  bake total      {med['total']:6.1f} s" + ("  (stopped at first progress)" * a.stop))
    print(f"  warm compiles   {warm['compiles']:6d}    (second run, same cache: must be 0)")
    print(f"  warm first prog.{warm['first_progress']:6.1f} s")
    print("  load average    " + ", ".join(f"{r['load'][0]} -> {r['load'][1]}" for r in runs))
    print("  compile seconds per dispatcher (own share, median; top 8):")
    for name, secs in sorted(top.items(), key=lambda kv: -statistics.median(kv[1]))[:8]:
        nsig = runs[-1]["signatures"].get(name, "?")
        print(f"    {statistics.median(secs):6.2f}  {name}  [{nsig} specialisation(s)]")
    multi = {k: v for k, v in runs[-1]["signatures"].items() if v > 1}
    print(f"  dispatchers with several specialisations: {multi or 'none'}")
    if a.json:
        Path(a.json).write_text(json.dumps({"runs": runs, "warm": warm}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
