"""``usdahd fit`` on bad and large inputs (issue 18): dtype, shape and finiteness checked with
one message each, pickles refused without a traceback, large files streamed in chunks."""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import usdahd
from usdahd import cli
from usdahd.commands import fit as fitcmd

ROOT = Path(__file__).resolve().parents[2]
SKY = ROOT / "samples" / "sh" / "sky_sun.npy"


def _run(capsys, *argv):
    code = cli.main(["fit", *map(str, argv)])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return code, cap.out, cap.err


def _sh(n=64, seed=0):
    return np.load(SKY)[:n] if n <= len(np.load(SKY)) else np.resize(np.load(SKY), (n, 3, 9))


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda p: np.save(p, np.zeros((0, 3, 9), np.float32)), ["empty"]),
        (lambda p: np.save(p, np.zeros((4, 3, 8), np.float32)), ["(..., 3, 9)"]),
        (lambda p: np.save(p, np.full((4, 3, 9), np.nan)), ["non-finite", "texel 0"]),
        (lambda p: np.save(p, _with(np.inf, 2)), ["non-finite", "first at texel 2"]),
        (lambda p: np.save(p, np.zeros((4, 3, 9), np.complex64)), ["complex"]),
        (lambda p: np.save(p, np.zeros((4, 3, 9), "U1")), ["not numeric"]),
        (lambda p: np.save(p, np.array([{"a": 1}] * 4), allow_pickle=True), ["pickle"]),
        (lambda p: p.write_bytes(b"not numpy at all"), ["not a readable"]),
    ],
    ids=["empty", "shape", "nan", "inf", "complex", "string", "pickle", "garbage"],
)
def test_bad_npy_is_one_message_exit_2(tmp_path, capsys, make, words):
    path = tmp_path / "bad.npy"
    make(path)
    code, out, err = _run(capsys, path, "--json")
    assert code == 2
    line = [ln for ln in err.splitlines() if ln.startswith("usdahd fit: error: ")]
    assert len(line) == 1 and str(path) in line[0], err
    for w in words:
        assert w in line[0], line
    assert json.loads(out)["exit_code"] == 2


def _with(value, texel):
    a = np.zeros((4, 3, 9))
    a[texel, 1, 3] = value
    return a


def test_pickled_npz_is_refused(tmp_path, capsys):
    path = tmp_path / "obj.npz"
    np.savez(path, sh=np.array([object()] * 3, dtype=object))
    code, _, err = _run(capsys, path)
    assert code == 2 and "pickle" in err


def test_output_path_that_is_a_directory_is_refused_before_fitting(tmp_path, capsys):
    code, _, err = _run(capsys, SKY, "-o", tmp_path)
    assert code == 2 and "is a directory" in err


def test_chunked_fit_equals_one_shot(tmp_path, capsys, monkeypatch):
    sh = _sh(200)
    path = tmp_path / "sh.npz"
    np.savez_compressed(path, sh=sh.reshape(10, 20, 3, 9).astype(np.float32))
    monkeypatch.setattr(fitcmd, "CHUNK", 7)  # 29 chunks, the last one partial
    code, out, _ = _run(capsys, path, "--json", "-o", tmp_path / "p.npz")
    assert code == 0
    report = json.loads(out)
    whole = usdahd.fit(sh.astype(np.float32).astype(np.float64), model="hhd")
    rel = fitcmd.hemispherical_rmse(sh.astype(np.float32).astype(np.float64), whole)
    assert report["relative_rmse_mean"] == pytest.approx(float(rel.mean()), rel=1e-9)
    assert report["relative_rmse_max"] == pytest.approx(float(rel.max()), rel=1e-9)
    got = np.load(tmp_path / "p.npz")
    for k, v in whole.params.items():
        assert got[k].shape == (10, 20) + v.shape[1:]
        np.testing.assert_array_equal(got[k].reshape(v.shape), v)


def _peak(tmp_path, capsys, n: int) -> int:
    sh = np.resize(np.load(SKY).astype(np.float32), (n, 3, 9))
    path = tmp_path / f"big{n}.npz"
    np.savez_compressed(path, sh=sh)
    del sh
    tracemalloc.start()
    try:
        code, out, _ = _run(capsys, path, "--json", "--model", "sh_l1")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert code == 0 and json.loads(out)["texels"] == n
    return peak


def test_large_npz_is_streamed_with_bounded_memory(tmp_path, capsys, monkeypatch):
    """Peak memory depends on the chunk, not on the file: 5x the texels, same peak (one shot,
    60000 x 256 x 3 float64 would be 369 MB per temporary)."""
    monkeypatch.setattr(fitcmd, "CHUNK", 2048)
    small = _peak(tmp_path, capsys, 12000)
    large = _peak(tmp_path, capsys, 60000)
    assert large < 1.25 * small, (small, large)
    assert large < 120e6, large
