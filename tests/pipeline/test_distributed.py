"""The bake on a Dask cluster (issue 15): tiles of texels traced anywhere, gathered in texel order,
give the outputs of a plain bake byte for byte; ``--workers`` / ``--scheduler`` and their errors.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import usdahd
from tests.scenes import copy_sample
from usdahd import cli
from usdahd.bake import integrate, tiles

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[2]
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
STAGE = "cornell_box.usda"
SMALL = ["--resolution", "16", "--samples", "16", "--seed", "7"]


def _main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return code, cap.out, cap.err


def _outputs(folder: Path) -> dict[str, bytes]:
    """Every file a bake wrote under folder (layer and lightmaps/, not the lock file, which
    names the process), by relative name."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
        and (p.parent.name == "lightmaps" or ".lightmaps." in p.name)
        and p.suffix != ".lock"
    }


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A plain single-process bake of the Cornell box (the reference)."""
    folder = tmp_path_factory.mktemp("plain")
    stage = copy_sample(folder, STAGE)
    assert cli.main(["bake", str(stage), *SMALL, "-q"]) == 0
    return _outputs(folder)


def test_split_starts_every_tile_on_a_chunk_boundary():
    for n, chunk, target in [(10, 3, 4), (1000, 64, 200), (5, 64, 1 << 16), (128, 64, 64)]:
        ranges = tiles.split(n, chunk, target)
        assert ranges[0][0] == 0 and ranges[-1][1] == n
        assert all(a % chunk == 0 for a, _ in ranges)
        assert all(b == c for (_, b), (c, _) in zip(ranges, ranges[1:]))
        assert all(b - a <= max(chunk, round(target / chunk) * chunk) for a, b in ranges)


def test_tiles_reproduce_the_whole_mesh_bit_for_bit(monkeypatch, samples_dir):
    """Many tiles per mesh (small chunks), traced out of order and gathered: the SH, the
    invalid flags and the contact-pushed positions equal the whole-mesh bake's; the Embree
    scene is built once for all the tiles of one scene key."""
    from usdahd.bake.contacts import push_off_contacts
    from usdahd.bake.texels import rasterize
    from usdahd.bake.trace import Tracer
    from usdahd.usd.reader import load_scene

    monkeypatch.setattr(integrate, "NATIVE_CHUNK_RAYS", 64 * 8)  # 64 texels at 8 samples
    monkeypatch.setattr(integrate, "CHUNK_RAYS", 64 * 8)
    scene = load_scene(str(samples_dir / STAGE))
    tracer = Tracer(scene)
    k = next(i for i, m in enumerate(scene.meshes) if m.path.endswith("TallBox"))
    texels = rasterize(scene.meshes[k], (24, 24))
    assert integrate.chunk_texels(8, False, tracer.backend == "native") == 64
    pushed, contact_invalid = push_off_contacts(texels, scene.meshes[k], tracer)
    sh, stats = integrate.bake_texels(scene, tracer, pushed, samples=8, seed=11, mesh=k)
    ranges = tiles.split(len(texels), 64, 128)
    assert len(ranges) >= 3
    before = tiles.builds["count"]
    results = []
    for i, (a, b) in reversed(list(enumerate(ranges))):
        tile = tiles.Tile(STAGE, k, i, len(ranges), a, tiles.slice_texels(texels, a, b), 8,
                          integrate.DEFAULT_BOUNCES, 11, False)  # fmt: skip
        results.append(tiles.trace_tile("scene-key", scene, tile, tracer.backend, threads=2))
    assert tiles.builds["count"] == before + 1
    got_texels, got_sh, got_stats = tiles.gather(texels, results)
    assert got_sh.tobytes() == sh.tobytes()
    np.testing.assert_array_equal(got_stats["invalid"], stats["invalid"] | contact_invalid)
    np.testing.assert_array_equal(got_texels.position, pushed.position)
    assert got_stats["rays"] == stats["rays"]
    with pytest.raises(ValueError, match="cover"):
        tiles.gather(texels, results[1:])


def test_two_workers_give_the_plain_bake_byte_for_byte(tmp_path, capsys, plain):
    stage = copy_sample(tmp_path, STAGE)
    code, _, err = _main(capsys, "bake", stage, *SMALL, "--workers", "2")
    assert code == 0, err
    assert "tiles: 7 on 2 Dask worker(s)" in err
    got = _outputs(tmp_path)
    assert sorted(got) == sorted(plain)
    assert [k for k in plain if got[k] != plain[k]] == []
    code, out, err = _main(capsys, "validate", tmp_path / "cornell_box.lightmaps.usda")
    assert code == 0, out + err


def test_scheduler_of_an_existing_cluster_in_a_subprocess(tmp_path, plain):
    """The test starts a scheduler and a worker process on localhost; the bake (a separate
    ``python -m usdahd``) sends its tiles there."""
    stage = copy_sample(tmp_path, STAGE)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
        host="127.0.0.1",
    ) as cluster:  # fmt: skip
        env = dict(os.environ, PYTHONPATH=USDAHD_PATH)
        proc = subprocess.run(
            [sys.executable, "-m", "usdahd", "bake", str(stage), *SMALL,
             "--scheduler", cluster.scheduler_address],
            capture_output=True, text=True, env=env, timeout=900,
        )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert f"of {cluster.scheduler_address}" in proc.stderr
    got = _outputs(tmp_path)
    assert sorted(got) == sorted(plain)
    assert [k for k in plain if got[k] != plain[k]] == []


@pytest.mark.parametrize("value", ["0", "-3"])
def test_bad_worker_counts_are_usage_errors(tmp_path, capsys, value):
    stage = copy_sample(tmp_path, STAGE)
    code, _, err = _main(capsys, "bake", stage, *SMALL, "--workers", value)
    assert code == 2
    assert f"--workers must be >= 1 (local Dask worker processes), got {value}" in err
    assert "omit it for a single-process bake" in err
    assert not (tmp_path / "lightmaps").exists()


def test_unreachable_scheduler_names_the_address_and_the_fix(tmp_path, capsys, monkeypatch):
    from usdahd.pipeline import distributed as dist

    monkeypatch.setattr(dist, "CONNECT_TIMEOUT", 2)
    stage = copy_sample(tmp_path, STAGE)
    address = "tcp://127.0.0.1:9"  # the discard port: nothing listens
    code, _, err = _main(capsys, "bake", stage, *SMALL, "--scheduler", address)
    assert code == 2
    assert f"--scheduler {address}: cannot reach a Dask scheduler there" in err
    assert "dask scheduler" in err
    assert not (tmp_path / "cornell_box.lightmaps.usda").exists()


def test_without_dask_the_flags_fail_before_anything_is_traced(tmp_path, capsys, monkeypatch):
    from usdahd.pipeline import run

    stage = copy_sample(tmp_path, STAGE)
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    traced = []
    monkeypatch.setattr(run, "bake_jobs", lambda *a, **k: traced.append(1))
    for flag, value in (("--workers", "2"), ("--scheduler", "tcp://127.0.0.1:8786")):
        code, _, err = _main(capsys, "bake", stage, *SMALL, flag, value)
        assert code == 2
        assert f"{flag} needs Dask's distributed scheduler" in err
        assert "pip install 'usdahd[distributed]'" in err
    assert not traced


def test_a_tile_that_keeps_failing_fails_its_prim_naming_the_tile(tmp_path, capsys, monkeypatch):
    """Every attempt of the TallBox's tile raises (an in-process cluster, so the patched
    function runs): the prim fails with the tile, texel range and attempts named; the other
    prims bake and the bake exits 1."""
    real = tiles.trace_tile
    log = tmp_path / "attempts.txt"  # the task may be a copy of this closure: count in a file

    def flaky(key, scene, tile, backend, threads=None):
        if tile.prim.endswith("TallBox"):
            with open(log, "a") as f:
                f.write(f"{tile.index}\n")
            raise RuntimeError("simulated worker fault")
        return real(key, scene, tile, backend, threads)

    monkeypatch.setattr(tiles, "trace_tile", flaky)
    stage = copy_sample(tmp_path, STAGE)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        code, _, err = _main(capsys, "bake", stage, *SMALL, "--scheduler",
                             cluster.scheduler_address)  # fmt: skip
    assert code == 1
    assert log.read_text().split() == ["0"] * 3
    assert (
        "tile 1/1 (texels 0..155) of /World/Geometry/TallBox failed 3 times on the cluster: "
        "RuntimeError: simulated worker fault"
    ) in err
    assert "ShortBox" not in err


def test_a_worker_killed_mid_bake_is_replaced_and_the_bake_is_identical(
    tmp_path, capsys, monkeypatch, plain
):
    """The first worker to start the Floor's tile dies on the spot (os._exit, as a crash or
    an OOM kill would); Dask reschedules the tile on a live worker and the outputs are still
    the plain bake's, byte for byte."""
    real = tiles.trace_tile
    marker = tmp_path / "killed.txt"

    def dying(key, scene, tile, backend, threads=None):
        if tile.prim.endswith("Floor") and not marker.exists():
            marker.write_text(str(os.getpid()))
            os._exit(1)
        return real(key, scene, tile, backend, threads)

    monkeypatch.setattr(tiles, "trace_tile", dying)
    stage = copy_sample(tmp_path / "bake", STAGE)
    code, _, err = _main(capsys, "bake", stage, *SMALL, "--workers", "2")
    assert code == 0, err
    assert int(marker.read_text()) != os.getpid()  # a worker process died, not this one
    got = _outputs(tmp_path / "bake")
    assert sorted(got) == sorted(plain)
    assert [k for k in plain if got[k] != plain[k]] == []


def test_a_scheduler_without_workers_is_a_usage_error(tmp_path, capsys, monkeypatch):
    from usdahd.pipeline import distributed as dist

    monkeypatch.setattr(dist, "CONNECT_TIMEOUT", 1)
    stage = copy_sample(tmp_path, STAGE)
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as c:
        code, _, err = _main(capsys, "bake", stage, *SMALL, "--scheduler", c.scheduler_address)
    assert code == 2
    assert "no Dask worker is connected to it" in err
    assert f"dask worker {c.scheduler_address} --nthreads 1" in err
