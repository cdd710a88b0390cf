"""``usdahd bake --workers N`` / ``--scheduler ADDRESS``: trace the tiles on a Dask cluster.

The client (this process) plans the bake, rasterises every mesh's texels and cuts them into
tiles (:mod:`usdahd.bake.tiles`); the scene description is scattered once to every worker,
which builds its Embree scene once (cached per process by the scatter's key) and traces the
tiles it is given. The client gathers the SH in texel order and runs the finishing steps
(fill, denoise, stitch, fit, encode, write, author) itself, exactly as a local bake does, so
the outputs are byte-identical to a plain bake with the same ``--seed`` (docs/scaling.md).

A tile that raises is retried (:data:`RETRIES`); a worker that dies has its tiles rescheduled
by Dask. A tile that keeps failing fails its prim (exit 1) with a message naming the tile and
the prim; the other prims still bake. ``dask[distributed]`` is optional
(``pip install 'usdahd[distributed]'``): :func:`require` turns its absence into a usage error
before anything is read or traced. This is the only module that imports Dask.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time

from usdahd.errors import UsageError

__all__ = ["require", "trace_jobs"]

#: Extra attempts of a failing tile (Dask ``retries``).
RETRIES = 2
#: Seconds to wait for ``--scheduler`` to answer.
CONNECT_TIMEOUT = 10
INSTALL = "pip install 'usdahd[distributed]'"


def require(workers: int | None, scheduler: str | None) -> None:
    """UsageError unless the options and Dask allow a distributed bake (no-op for a plain one)."""
    if workers is None and scheduler is None:
        return
    if workers is not None and scheduler is not None:
        raise UsageError(
            "--workers starts a local cluster and --scheduler uses an existing one: give one "
            "of them"
        )
    if workers is not None and workers < 1:
        raise UsageError(
            f"--workers must be >= 1 (local Dask worker processes), got {workers}; omit it "
            "for a single-process bake"
        )
    if scheduler is not None and not scheduler.strip():
        raise UsageError("--scheduler needs a scheduler address such as tcp://HOST:8786")
    try:
        import distributed  # noqa: F401
    except ImportError:
        flag = "--workers" if workers is not None else "--scheduler"
        raise UsageError(
            f"{flag} needs Dask's distributed scheduler, which is not installed: {INSTALL} "
            f"(or bake without {flag})"
        ) from None


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None):
    """(dask Client, tracer threads per tile or None for all of a worker's cores)."""
    import distributed

    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, ValueError, TypeError) as exc:  # TimeoutError is an OSError
            raise UsageError(
                f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({exc}); start "
                "one with `dask scheduler` and workers with `dask worker ADDRESS --nthreads 1`, "
                "and pass the address it prints (tcp://HOST:8786)"
            ) from None
        try:
            yield client, None
        finally:
            client.close()
        return
    cluster = distributed.LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.ERROR,
    )
    client = distributed.Client(cluster, set_as_default=False)
    try:
        yield client, max(1, (os.cpu_count() or 1) // workers)
    finally:
        client.close()
        cluster.close()


def trace_jobs(scene, work, opts, record) -> None:
    """Trace jobs in tiles on the cluster of ``opts`` (``opts.workers`` / ``opts.scheduler``).

    work : (job, its index in scene.meshes, its seed) for jobs with rasterised, non-empty
    texels; record(job, t0) fills a traced job's report (shared with the local path of
    :func:`usdahd.pipeline.stages._trace_jobs`). Sets job.texels/sh/stats, or marks the job
    failed.
    """
    jobs = [w[0] for w in work]
    import distributed

    from usdahd.bake import tiles
    from usdahd.bake.integrate import chunk_texels, uses_native
    from usdahd.bake.kernels import embree
    from usdahd.progress import Progress

    backend = "native" if embree.available() else "embreex"
    native = uses_native(scene, backend)
    per_job = []
    for job, mesh, seed in work:
        s = job.settings
        chunk = chunk_texels(int(s["samples"]), bool(s["adaptive"]), native)
        ranges = tiles.split(len(job.texels), chunk, tiles.TILE_TEXELS)
        per_job.append(
            [
                tiles.Tile(
                    prim=job.path,
                    mesh=mesh,
                    index=i,
                    count=len(ranges),
                    first=a,
                    texels=tiles.slice_texels(job.texels, a, b),
                    samples=int(s["samples"]),
                    bounces=int(s["bounces"]),
                    seed=seed,
                    adaptive=bool(s["adaptive"]),
                )
                for i, (a, b) in enumerate(ranges)
            ]
        )
    total = sum(len(t) for t in per_job)
    t0 = time.perf_counter()
    with _client(opts.workers, opts.scheduler) as (client, threads):
        if not client.nthreads():
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except (TimeoutError, OSError):
                raise UsageError(
                    f"--scheduler {opts.scheduler}: no Dask worker is connected to it; start "
                    f"some with `dask worker {opts.scheduler} --nthreads 1` and re-run"
                ) from None
        n_workers = len(client.nthreads())
        where = opts.scheduler or "a local cluster"
        _say(opts, f"tiles: {total} on {n_workers} Dask worker(s) of {where}")
        [scene_ref] = client.scatter([scene], broadcast=True, hash=False)
        futures, owner = [], {}
        for k, job_tiles in enumerate(per_job):
            for tile in job_tiles:
                fut = client.submit(
                    tiles.trace_tile, scene_ref.key, scene_ref, tile, backend, threads,
                    retries=RETRIES, pure=False,
                )  # fmt: skip
                futures.append(fut)
                owner[fut.key] = (k, tile)
        results = [[] for _ in jobs]
        errors: dict[int, str] = {}
        bar = Progress(f"tiles on {n_workers} worker(s)", unit="tiles", quiet=opts.quiet)
        done = 0
        for fut in distributed.as_completed(futures, loop=client.loop):
            k, tile = owner[fut.key]
            try:
                results[k].append(fut.result())
            except Exception as exc:  # the tile's own error, or KilledWorker
                errors.setdefault(
                    k,
                    f"{tile.describe()} failed {RETRIES + 1} times on the cluster: "
                    f"{type(exc).__name__}: {exc}",
                )
            fut.release()
            done += 1
            bar.update(done, total)
        bar.close()
    elapsed = time.perf_counter() - t0
    for k, job in enumerate(jobs):
        if k in errors:
            job.report.update(status="failed", error=errors[k])
            continue
        job.texels, job.sh, job.stats = tiles.gather(job.texels, results[k])
        record(job, t0)
        job.report["tiles"] = len(per_job[k])
    _say(opts, f"tiles: {total} traced in {elapsed:.2f}s ({total / max(elapsed, 1e-9):.2f}/s)")


def _say(opts, msg: str) -> None:
    import sys

    if not opts.quiet:
        print(msg, file=sys.stderr)
