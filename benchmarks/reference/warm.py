"""``usdahd bake`` timed as a call inside a running process, the way Cycles' bake is timed.

The reference harness times Cycles' ``bpy.ops.object.bake`` call in a running Blender
(Blender's start-up, which loads its kernels, is excluded). A ``usdahd bake`` command also
pays, in every process, the import of numba/pxr/OpenImageIO and the loading of the cached
numba kernels (about 0.5-0.9 s, most of the time of a bake of a small stage). A DCC plug-in
or a pipeline service that bakes stage after stage pays that once. :class:`WarmBaker` runs
``usdahd.cli.main`` for each request in one long-lived child process, so after a first
(untimed) bake the report's ``seconds`` measure the bake itself: the same quantity as
Cycles' bake call. The command's output is the same as the CLI's (same code, same seed).

Protocol: one JSON object per line on the child's stdin (``{"argv": [...]}``), one per line on
its stdout (``{"code": exit code, "stdout": captured stdout, "wall": seconds}``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


class WarmBaker:
    """One long-lived Python process running ``usdahd`` commands in-process."""

    def __init__(self):
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "from benchmarks.reference.warm import serve; serve()"],
            cwd=REPO,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def run(self, argv: list[str]) -> dict:
        """Run ``usdahd <argv>``; returns {"code", "stdout", "wall"}."""
        self.proc.stdin.write(json.dumps({"argv": argv}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the warm usdahd process died (exit {self.proc.wait()})")
        return json.loads(line)

    def bake(self, stage: Path, layer: Path, resolution: int | None, extra: list[str]) -> dict:
        """``usdahd bake`` like :func:`benchmarks.reference.compare.bake_usdahd`: returns
        {"report", "seconds" (wall time of the call), "layer"}."""
        argv = ["bake", str(stage), "-o", str(layer), "--json", "--quiet"]
        if resolution:
            argv += ["--resolution", str(resolution)]
        r = self.run(argv + list(extra))
        if r["code"] not in (0, 1) or not layer.is_file():
            raise RuntimeError(f"warm usdahd bake of {stage} failed (exit {r['code']})")
        return {"report": json.loads(r["stdout"] or "{}"), "seconds": r["wall"], "layer": layer}

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def serve() -> None:
    """Child side: read requests until EOF; each runs ``usdahd.cli.main`` with stdout and
    stderr captured (progress goes nowhere)."""
    import contextlib
    import io

    from usdahd import cli

    proto = sys.stdout
    for line in sys.stdin:
        argv = json.loads(line)["argv"]
        out, err = io.StringIO(), io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(argv)
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 2
        wall = time.perf_counter() - t0
        proto.write(json.dumps({"code": code, "stdout": out.getvalue(), "wall": wall}) + "\n")
        proto.flush()
