"""Where block compression errs: BC6H / BC7 error of each KTX2 texture's level 0, split into
texels of 4x4 blocks inside one chart and of blocks that straddle charts (or a gutter).

Bakes one stage with ``--container ktx2`` and keeps what :func:`usdahd.ktx2.write` is given
(stored values, coverage, chart ids), compresses level 0 with BC6H / BC7 as ``--container
ktx2-bc`` would without its checks (every HDR texture BC6H, every 8-bit one BC7, direction
codes included: :func:`usdahd.ktx2.encode_levels` with no error bound) and decodes it with
tests/ktx2_reader.py's independent decoders (texture2ddecoder for BC7, Mesa for BC6H).
Errors: BC6H relative (max over channels / max |value|), BC7 in 8-bit codes (max over
channels); mean and 99th percentile. ``--causes``: per HDR texture, BC6H's error (RMSE / mean
over the covered texels) with each ispc-texcomp profile, and with each block's gutter texels
filled with the mean of its covered ones.

    python benchmarks/ktx2_blocks.py pillar_room.usda --resolution 32 --samples 256
    python benchmarks/ktx2_blocks.py floor_lamp.usda --resolution 32 --samples 256 --causes
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tests")]

import ktx2_reader as KR  # noqa: E402

from usdahd import cli, ktx2  # noqa: E402


def _bake(stage: str, resolution: int, samples: int, tmp: Path) -> list[dict]:
    shutil.copy(REPO / "samples" / stage, tmp / stage)
    for sub in ("textures", "sh"):
        if (REPO / "samples" / sub).is_dir():
            shutil.copytree(REPO / "samples" / sub, tmp / sub)
    seen, real = [], ktx2.write

    def keep(path, image, mask, charts, fmt, **kw):
        seen.append({"path": Path(path), "image": np.array(image), "mask": np.array(mask)})
        seen[-1].update(charts=np.array(charts), fmt=fmt)
        return real(path, image, mask, charts, fmt, **kw)

    argv = ["bake", str(tmp / stage), "--resolution", str(resolution), "--samples", str(samples)]
    ktx2.write = keep
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            code = cli.main([*argv, "--container", "ktx2", "--quiet"])
    finally:
        ktx2.write = real
    if code != 0:
        raise SystemExit(f"bake failed: {stage}")
    return seen


def _straddling(mask: np.ndarray, charts: np.ndarray) -> np.ndarray:
    """(h, w) bool: the texel's 4x4 block holds more than one chart or an uncovered texel."""
    h, w = mask.shape
    ch = np.where(mask, charts, -1)
    out = np.zeros((h, w), bool)
    for by in range(0, h, 4):
        for bx in range(0, w, 4):
            ids = np.unique(ch[by : by + 4, bx : bx + 4])
            out[by : by + 4, bx : bx + 4] = len(ids) > 1
    return out


def measure(tex: dict) -> dict:
    img, m = tex["image"], tex["mask"]
    h, w = m.shape
    level0 = ktx2.mip_chain(img.astype(np.float64), m, tex["charts"])[:1]
    # what BC6H / BC7 would do (no error bound, direction codes too): the causes, not the output
    vk, (blocks,) = ktx2.encode_levels(level0, tex["fmt"], "bc", max_rel_rmse=math.inf)
    c = img.shape[-1]
    if vk == ktx2.VK_FORMAT_BC6H_UFLOAT_BLOCK:
        dec = KR.bc6h_float(blocks, w, h)[..., :c].astype(np.float64)
        ref = img.astype(np.float64)
        err = np.abs(dec - ref).max(-1) / np.maximum(np.abs(ref).max(-1), 1e-6)
        unit = "rel"
    elif vk == ktx2.VK_FORMAT_BC7_UNORM_BLOCK:
        import texture2ddecoder

        bw, bh = math.ceil(w / 4), math.ceil(h / 4)
        bgra = texture2ddecoder.decode_bc7(blocks, 4 * bw, 4 * bh)
        px = np.frombuffer(bgra, np.uint8).reshape(4 * bh, 4 * bw, 4)[..., [2, 1, 0, 3]]
        err = np.abs(px[:h, :w, :c].astype(int) - img.astype(int)).max(-1).astype(float)
        unit = "codes"
    else:
        return {}
    s = _straddling(m, tex["charts"])
    row = {"texture": tex["path"].name, "unit": unit}
    for name, sel in (("inside", m & ~s), ("straddling", m & s)):
        e = err[sel]
        row[name] = (int(e.size), float(e.mean()) if e.size else 0.0)
        row[name] += (float(np.quantile(e, 0.99)) if e.size else 0.0,)
    return row


PROFILES = ("veryfast", "basic", "slow", "veryslow")


def _block_fill(img: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Each 4x4 block's uncovered texels set to the mean of its covered ones."""
    out = img.copy()
    for by in range(0, m.shape[0], 4):
        for bx in range(0, m.shape[1], 4):
            bm = m[by : by + 4, bx : bx + 4]
            if bm.any() and not bm.all():
                blk = out[by : by + 4, bx : bx + 4]
                blk[~bm] = blk[bm].mean(axis=0)
    return out


def _bc6h_rel(level0: np.ndarray, ref: np.ndarray, m: np.ndarray, profile: str) -> float:
    """BC6H of level 0 with one ispc-texcomp profile, decoded by Mesa: RMSE / mean |value|."""
    t = ktx2._encoder()
    h, w, c = ref.shape
    px = np.ones((h, w, 4), np.float16)
    px[..., :c] = level0.astype(np.float16)
    px = np.ascontiguousarray(ktx2._pad4(np.where(px == 0, np.float16(0), px)))
    surf = t.RGBASurface(px.tobytes(), px.shape[1], px.shape[0], px.shape[1] * 8)
    blocks = t.compress_blocks_bc6h(surf, t.BC6HEncSettings.from_profile(profile))
    d = KR.bc6h_float(blocks, w, h)[..., :c].astype(np.float64) - ref
    return math.sqrt(float((d[m] ** 2).mean())) / float(np.abs(ref[m]).mean())


def causes(tex: dict) -> dict:
    """BC6H error (RMSE / mean over the covered texels) of a non-negative HDR texture per
    ispc-texcomp profile, and with the "slow" profile after filling each block's gutter texels
    with its covered mean; {} for other textures."""
    img, m = tex["image"].astype(np.float64), tex["mask"]
    if tex["fmt"] != "half" or (img < 0).any():
        return {}
    level0 = ktx2.mip_chain(img, m, tex["charts"])[0][0]
    row = {p: _bc6h_rel(level0, img, m, p) for p in PROFILES}
    row["slow, gutters = block mean"] = _bc6h_rel(_block_fill(level0, m), img, m, "slow")
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", help="a file name in samples/")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument(
        "--causes",
        action="store_true",
        help="also BC6H's error per ispc-texcomp profile and with block-mean gutters",
    )
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        baked = _bake(a.stage, a.resolution, a.samples, Path(tmp))
    rows = [measure(t) for t in baked]
    print("| texture | error | inside: texels, mean, p99 | straddling: texels, mean, p99 |")
    print("|---|---|---|---|")
    for r in filter(None, rows):
        i, s = r["inside"], r["straddling"]
        print(
            f"| {r['texture']} | {r['unit']} | {i[0]}, {i[1]:.3g}, {i[2]:.3g} "
            f"| {s[0]}, {s[1]:.3g}, {s[2]:.3g} |"
        )
    if a.causes:
        names = [*PROFILES, "slow, gutters = block mean"]
        print()
        print("| texture | BC6H rel. RMSE: " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        for t in baked:
            row = causes(t)
            if row:
                vals = " | ".join(f"{row[k]:.4f}" for k in names)
                print(f"| {t['path'].name} | {vals} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
