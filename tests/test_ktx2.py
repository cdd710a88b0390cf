"""KTX2 engine containers (``usdahd bake --container ktx2|ktx2-bc``): chart-aware mips, a
container that an independent reader parses (tests/ktx2_reader.py, written from the KTX 2.0
specification), BC7 decoded by texture2ddecoder, BC6H decoded by Mesa (lavapipe through wgpu;
texture2ddecoder's BC6H decoder clamps to 8 bits, so it only cross-checks data in [0, 1]), and
the compression error of every model. (pyktx2 0.3.1, the
KTX2 parser on the package index, pads key/value entries with ``pos % 8`` instead of ``% 4`` and
knows only the ETC1S/UASTC colour models, so it cannot serve as a second reader.)"""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ispc_texcomp")
pytest.importorskip("imagecodecs")
pytest.importorskip("texture2ddecoder")

from usdahd import cli, images, ktx2, models  # noqa: E402
from usdahd.numerics import sh as shm  # noqa: E402
from usdahd.usd import schema  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
from tests import ktx2_reader as KR  # noqa: E402

VARIANTS = [(m, r) for m in models.names() for r in models.get(m).RATIOS]


def _two_charts(h=13, w=10):
    img = np.zeros((h, w, 3))
    m = np.zeros((h, w), bool)
    ch = np.full((h, w), -1)
    m[1:6, 1:9], ch[1:6, 1:9], img[1:6, 1:9] = True, 0, 100.0
    m[6:12, 1:9], ch[6:12, 1:9], img[6:12, 1:9] = True, 1, 200.0  # touching chart 0
    return img, m, ch


def test_mips_never_mix_two_charts_and_follow_the_ktx2_sizes():
    img, m, ch = _two_charts()
    levels = ktx2.mip_chain(img, m, ch)
    h, w = m.shape
    assert len(levels) == math.floor(math.log2(max(h, w))) + 1
    for k, (lv, cov) in enumerate(levels):
        assert lv.shape[:2] == (max(1, h >> k), max(1, w >> k))
        vals = set(np.unique(lv[cov]))
        assert vals <= {100.0, 200.0}, (k, vals)  # a plain box filter would give 150 here
        assert np.isfinite(lv).all() and (lv[~cov] > 0).all()  # gutters dilated, not black
    # level 1 keeps both charts apart where a box filter would blend them
    assert {100.0, 200.0} <= set(np.unique(levels[1][0][levels[1][1]]))


def test_container_parses_with_an_independent_reader(tmp_path):
    img, m, ch = _two_charts()
    rng = np.random.default_rng(0)
    half = (img + rng.uniform(0, 1, img.shape)).astype(np.float16)
    codes = np.clip(img * 0.9 + rng.integers(0, 3, img.shape), 0, 255).astype(np.uint8)
    info = {}
    for name, data, fmt, comp in (
        ("h", half, "half", "none"),
        ("b", codes, "unorm8", "none"),
        ("h6", half, "half", "bc"),
        ("b7", codes, "unorm8", "bc"),
    ):
        kv = {"usdahd:x": "1"}
        info[name] = ktx2.write(
            tmp_path / f"{name}.ktx2", data, m, ch, fmt, compression=comp, attributes=kv
        )
    # vkFormat, typeSize, DFD colour model, texel block dims, bytes per plane (texel or block)
    for name, vk, tsize, model, block, plane in (
        ("h", 97, 2, 1, (0, 0, 0, 0), 8),
        ("b", 37, 1, 1, (0, 0, 0, 0), 4),
        ("h6", 131, 1, 133, (3, 3, 0, 0), 16),
        ("b7", 145, 1, 134, (3, 3, 0, 0), 16),
    ):
        f = KR.read(tmp_path / f"{name}.ktx2")
        assert f["vk_format"] == vk and f["size"] == (10, 13) and f["levels"] == 4
        assert f["type_size"] == tsize
        assert f["depth_layers_faces"] == (0, 0, 1) and f["supercompression"] == 0
        d = f["dfd"]
        assert (d["model"], d["transfer"], d["primaries"]) == (model, 1, 1)  # linear, BT.709
        assert d["block_dims"] == block and d["bytes_plane"][0] == plane
        assert d["vendor_type"] == 0 and d["version"] == 2
        assert f["kv"]["KTXorientation"] == "rd" and f["kv"]["KTXwriter"].startswith("usdahd")
        assert f["kv"]["usdahd:x"] == "1"
        offsets = [o for o, _, _ in f["level_index"]]
        assert offsets == sorted(offsets, reverse=True)  # smallest level stored first
        align = math.lcm(plane, 4)
        assert all(o % align == 0 for o in offsets)
        for k, (_, n, un) in enumerate(f["level_index"]):  # no supercompression: sizes agree
            lw, lh = max(1, 10 >> k), max(1, 13 >> k)
            want = lw * lh * plane if block[0] == 0 else math.ceil(lw / 4) * math.ceil(lh / 4) * 16
            assert n == un == want, (name, k)
        if vk == 131:  # BC6H: one 128-bit sample, channel 0, float, unsigned, 0.0 .. 1.0
            assert d["samples"] == [(0, 128, 0, 0x80, 0, 0x3F800000)]
        if vk == 145:
            assert d["samples"] == [(0, 128, 0, 0, 0, 0xFFFFFFFF)]
        if vk == 37:  # R, G, B, A bytes, 0 .. 255
            assert d["samples"] == [(8 * i, 8, c, 0, 0, 255) for i, c in enumerate((0, 1, 2, 15))]
    assert info["h"]["bytes_per_texel"] == 8 and info["b"]["bytes_per_texel"] == 4
    assert info["h6"]["vk_format"] == 131 and info["b7"]["vk_format"] == 145
    hf = KR.read(tmp_path / "h.ktx2")
    np.testing.assert_array_equal(hf["images"][0][..., :3][m], half[m])  # lossless at level 0
    assert (hf["images"][0][..., 3] == 1).all()
    bf = KR.read(tmp_path / "b.ktx2")
    np.testing.assert_array_equal(bf["images"][0][..., :3][m], codes[m])  # lossless
    assert (bf["images"][0][..., 3] == 255).all()
    b7 = KR.read(tmp_path / "b7.ktx2")
    err = np.abs(b7["images"][0][..., :3].astype(int) - codes.astype(int))[m]
    assert err.max() <= 8, err.max()  # BC7 on near-constant data


def test_bc6h_matches_the_float16_source_within_its_expected_error(tmp_path):
    """A smooth HDR lightmap over three decades (a factor ~2 across each 4x4 block): BC6H
    interpolates 16 weights (one-region modes) between two endpoints in its half-float bit
    space, nearly logarithmic, so half a step is ln(2.2)/15/2 ~ 2.6 % of a value, plus endpoint
    quantization: max 6 %, mean 2 % (measured with Mesa's decoder: 5.2 %, 1.3 %). A signed
    texture stays RGBA16F."""
    h, w = 24, 36
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    base = 0.05 * 1000 ** (0.5 * x + 0.5 * y)  # 0.05 .. 50
    src = np.stack([base, 0.7 * base, 0.4 * base + 0.01], axis=-1).astype(np.float16)
    m = np.ones((h, w), bool)
    m[:, 30:] = False  # a gutter
    ch = np.zeros((h, w), int)
    # forced to BC6H (no error bound): what its blocks do to such data
    ktx2.write(tmp_path / "hdr.ktx2", src, m, ch, "half", compression="bc", max_rel_rmse=math.inf)
    f = KR.read(tmp_path / "hdr.ktx2")
    assert f["vk_format"] == KR.VK_BC6H_UFLOAT_BLOCK and f["levels"] == 6
    got = f["images"][0][..., :3].astype(np.float64)
    ref = src.astype(np.float64)
    rel = np.abs(got - ref)[m] / ref[m]
    assert rel.max() < 0.06 and rel.mean() < 0.02, (rel.max(), rel.mean())
    assert np.allclose(f["images"][0][..., 3], 1.0)  # BC6H has no alpha: decoders give 1
    # level 1 is the chart-aware average of level 0, then BC6H; its blocks span twice the
    # distance, a factor ~4.7, so half a weight step is ~5 %: max 10 %
    lv1 = ktx2.mip_chain(src.astype(np.float64), m, ch)[1]
    rel1 = np.abs(f["images"][1][..., :3] - lv1[0])[lv1[1]] / lv1[0][lv1[1]]
    assert rel1.max() < 0.10, rel1.max()
    # texture2ddecoder (a second, independent BC6H decoder) agrees where it can: [0, 1]
    low = (src / 64).astype(np.float16)  # <= 0.8
    ktx2.write(tmp_path / "low.ktx2", low, m, ch, "half", compression="bc", max_rel_rmse=1.0)
    fl = KR.read(tmp_path / "low.ktx2")
    t2d = KR.bc6h_u8(fl["raw"][0], w, h)[..., :3].astype(int)
    mesa = np.rint(np.clip(fl["images"][0][..., :3], 0, 1) * 255).astype(int)
    assert np.abs(t2d - mesa).max() <= 1
    assert np.abs(t2d / 255 - low.astype(np.float64))[m].max() < 0.5 / 255 + 0.06 * 0.8
    # signed data (SH coefficients) cannot go to BC6H_UFLOAT: RGBA16F, exact
    signed = src.copy()
    signed[0, 0, 0] = -1.0
    info = ktx2.write(tmp_path / "s.ktx2", signed, m, ch, "half", compression="bc")
    assert info["vk_format"] == KR.VK_R16G16B16A16_SFLOAT
    with pytest.raises(Exception, match="compression must be one of"):
        ktx2.write(tmp_path / "x.ktx2", src, m, ch, "half", compression="bc9")
    assert not (tmp_path / "x.ktx2").exists()


def _errors(layer: Path, roles: dict | None = None) -> tuple[float, float, float, float, set]:
    """(rel. RMSE of irradiance KTX2 vs EXR/PNG, B/texel level 0, B/texel chain, BC7 code RMSE,
    the VkFormats seen) over every prim of a lightmap layer. Every BC6H texture is within
    ktx2.BC6H_MAX_REL_RMSE of its EXR (Mesa's decoder), every direction texture RGBA8.
    ``roles``: a dict that receives each texture's own irradiance error (the others exact),
    the worst over the prims."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    dirs = shm.fibonacci_sphere(32, hemisphere=True)
    sq = absum = count = code_rmse = 0.0
    level0 = chain = texels = 0
    formats = set()
    for prim in schema.prims_with_api(stage):
        res = schema.read_results(prim)
        mod = models.get(res.model)
        side = images.read(res.textures["sh"], channels=schema.SH_SIDECAR_CHANNELS).pixels
        cov = side[..., 27] > 0.5
        files, packed = {}, {}
        for lay in mod.layout(res.ratio):
            files[lay.role] = images.read(res.textures[lay.role], channels=lay.channels).pixels[cov]
            k = KR.read(Path(res.textures[lay.role]).with_suffix(".ktx2"))
            formats.add(k["vk_format"])
            assert k["kv"]["usdahd:packing"] == lay.packing
            assert k["levels"] == math.floor(math.log2(max(k["size"]))) + 1  # full chain
            px = k["images"][0][..., : len(lay.channels)]
            packed[lay.role] = px[cov].astype(files[lay.role].dtype)
            if lay.role == "direction":  # docs/schema.md: clamp block-decoded (u, v) codes
                packed[lay.role][..., :2] = np.clip(packed[lay.role][..., :2], 2, 254)
            diff = packed[lay.role].astype(np.float64) - files[lay.role]
            if k["vk_format"] in (KR.VK_R16G16B16A16_SFLOAT, KR.VK_R8G8B8A8_UNORM):  # lossless
                assert np.array_equal(packed[lay.role], files[lay.role]), lay.role
            elif k["vk_format"] == KR.VK_BC7_UNORM_BLOCK:  # lossy, close to the 8-bit codes
                code_rmse = max(code_rmse, float(np.sqrt((diff**2).mean())))
            elif k["vk_format"] == KR.VK_E5B9G9R9_UFLOAT_PACK32:  # within 2^-8 of the max
                # half a step of the 9-bit mantissa at the shared exponent: 2^-9 of the power of
                # two above the texel's largest channel (a largest channel that rounds up to it
                # bumps the exponent: 0.2499 -> step 2^-10, error 2^-11), at least the format's
                # smallest step 2^-24 (every channel near 0)
                top = files[lay.role].astype(np.float64).max(axis=-1, keepdims=True)
                pow2 = np.exp2(np.floor(np.log2(np.maximum(top, 2.0**-24))) + 1)
                bound = 2.0**-9 * pow2 + 2.0**-24
                bad = np.abs(diff) > bound
                assert not bad.any(), (lay.role, diff[bad][:5], top[bad.any(-1)][:5])
            else:  # BC6H: within the writer's bound, decoded here by Mesa
                rmse, mean = np.sqrt((diff**2).mean()), np.abs(files[lay.role]).mean()
                assert rmse <= ktx2.BC6H_MAX_REL_RMSE * (1 + 1e-6) * mean, (lay.role, rmse, mean)
            if lay.packing.startswith(ktx2.LOSSLESS_PACKINGS):
                assert k["vk_format"] == KR.VK_R8G8B8A8_UNORM, lay.role
            level0 += k["level_index"][0][1]
            chain += sum(n for _, n, _ in k["level_index"])
        texels += int(cov.size)
        n = np.broadcast_to(dirs, (int(cov.sum()),) + dirs.shape)
        want = mod.evaluate(mod.decode(files, ratio=res.ratio, factors=res.factors), n)
        got = mod.evaluate(mod.decode(packed, ratio=res.ratio, factors=res.factors), n)
        sq += float(((got.astype(np.float64) - want) ** 2).sum())
        absum += float(np.abs(want).sum())
        count += want.size
        for role in packed if roles is not None else ():
            one = mod.decode({**files, role: packed[role]}, ratio=res.ratio, factors=res.factors)
            d = mod.evaluate(one, n).astype(np.float64) - want
            rel = math.sqrt(float((d**2).mean())) / float(np.abs(want).mean())
            roles[role] = max(roles.get(role, 0.0), rel)
    err = math.sqrt(sq / count) / (absum / count)
    return err, level0 / texels, chain / texels, code_rmse, formats


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    top = tmp_path_factory.mktemp("ktx2")
    shutil.copy(ROOT / "samples" / "cornell_box.usda", top / "cornell_box.usda")
    return top


FAST = ["--resolution", "16", "--samples", "256", "--bounces", "1", "--quiet"]
LOSSLESS = {KR.VK_R16G16B16A16_SFLOAT, KR.VK_R8G8B8A8_UNORM}


@pytest.mark.slow  # 28 refits, half of them block-compressed: ~3 min on 2 busy cores
def test_bc6h_reads_a_negative_zero_as_zero(tmp_path):
    """-0.0 (an SH coefficient that cancels: open_plane's L1 x/y, sh_l1 / sh_l2) is not < 0,
    so the texture goes BC6H UFLOAT, whose encoder read its bits 0x8000 as 65504: open_plane's
    sh_l1 irradiance from KTX2 was 76 % off (docs/benchmarks.md). Now +0, decoded 0 by Mesa."""
    h, w = 8, 8
    src = np.full((h, w, 3), 0.5, np.float16)
    src[:4, :4] = np.float16(-0.0)
    src[4:, 4:, 1] = np.float16(0.0)
    assert np.signbit(src[0, 0, 0]) and not (src < 0).any()
    m = np.ones((h, w), bool)
    ktx2.write(tmp_path / "z.ktx2", src, m, np.zeros((h, w), int), "half", compression="bc")
    f = KR.read(tmp_path / "z.ktx2")
    assert f["vk_format"] == KR.VK_BC6H_UFLOAT_BLOCK
    got = f["images"][0][..., :3].astype(np.float64)
    np.testing.assert_allclose(got, np.abs(src.astype(np.float64)), atol=1e-3)
    for img in f["images"][1:]:  # the mips average zeros and halves: within [0, 0.5]
        assert img[..., :3].max() <= 0.5 + 1e-3


def _mesa_rel_rmse(path: Path, src: np.ndarray, m: np.ndarray) -> float:
    """RMSE / mean |value| of a KTX2's level 0 (Mesa's BC6H decoder) over the covered texels."""
    got = KR.read(path)["images"][0][..., : src.shape[-1]].astype(np.float64)
    ref = src.astype(np.float64)
    return float(np.sqrt(((got - ref)[m] ** 2).mean()) / np.abs(ref[m]).mean())


def test_bc_holds_its_error_bound_or_writes_lossless(tmp_path):
    """issue 39: `ktx2-bc` textures that hold up. A BC6H texture whose level-0 error (RMSE /
    mean over the covered texels, decoded by bcdec in the writer) exceeds
    ktx2.BC6H_MAX_REL_RMSE is written E5B9G9R9 (shared exponent: within 2^-8 of each texel's
    largest channel, Mesa's decoder); the error the writer reports is the one Mesa's decoder
    gives; hemi-octahedral direction codes stay RGBA8 (BC7 moves them where 1 / d_z magnifies
    every code), other 8-bit textures go BC7."""
    rng = np.random.default_rng(7)
    h, w = 16, 20
    m = np.ones((h, w), bool)
    m[:, 17:] = False
    ch = np.zeros((h, w), int)
    y, x = np.mgrid[0:h, 0:w]
    smooth = 0.5 + 0.3 * (x / w)[..., None] * np.array([1.0, 0.8, 0.6]) + 0.1 * (y / h)[..., None]
    smooth = smooth.astype(np.float16)
    info = ktx2.write(tmp_path / "smooth.ktx2", smooth, m, ch, "half", compression="bc")
    assert info["vk_format"] == KR.VK_BC6H_UFLOAT_BLOCK and "bc_fallback" not in info
    mesa = _mesa_rel_rmse(tmp_path / "smooth.ktx2", smooth, m)
    assert 0 < mesa <= ktx2.BC6H_MAX_REL_RMSE
    assert info["bc_rel_rmse"] == pytest.approx(mesa, rel=1e-6)  # bcdec and Mesa agree
    # a dim floor with a lamp's hotspot (floor_lamp: 0.12 .. 2.84 inside one 4x4 block)
    hot = np.full((h, w, 3), 0.05) * rng.uniform(0.9, 1.1, (h, w, 1))
    hot[5:7, 5:7] = 2.84
    hot[4:8, 4] = hot[4, 4:8] = 0.12
    hot = hot.astype(np.float16)
    forced = ktx2.write(
        tmp_path / "forced.ktx2", hot, m, ch, "half", compression="bc", max_rel_rmse=math.inf
    )
    assert forced["vk_format"] == KR.VK_BC6H_UFLOAT_BLOCK
    mesa = _mesa_rel_rmse(tmp_path / "forced.ktx2", hot, m)
    assert mesa > ktx2.BC6H_MAX_REL_RMSE and forced["bc_rel_rmse"] == pytest.approx(mesa, 1e-6)
    info = ktx2.write(tmp_path / "hot.ktx2", hot, m, ch, "half", compression="bc")
    assert info["vk_format"] == KR.VK_E5B9G9R9_UFLOAT_PACK32 and info["bytes_per_texel"] == 4
    assert info["bc_rel_rmse"] == forced["bc_rel_rmse"]
    assert (
        info["bc_fallback"] == f"BC6H error {mesa:.3g} > 0.015 (RMSE / mean of level 0): E5B9G9R9"
    )
    f = KR.read(tmp_path / "hot.ktx2")
    # the DFD libktx expects for VK_FORMAT_E5B9G9R9_UFLOAT_PACK32 (its e5b9g9r9 comparator)
    assert f["type_size"] == 4 and f["dfd"]["bytes_plane"][0] == 4
    assert f["dfd"]["samples"] == [
        (0, 9, 0, 0, 0, 8448),  # R mantissa: bits 0..8, sampleLower 0, sampleUpper 8448
        (27, 5, 0, 0x20, 15, 31),  # the shared exponent: qualifier EXPONENT, bias 15, max 31
        (9, 9, 1, 0, 0, 8448),
        (27, 5, 1, 0x20, 15, 31),
        (18, 9, 2, 0, 0, 8448),
        (27, 5, 2, 0x20, 15, 31),
    ]
    got, ref = f["images"][0][..., :3][m], hot[m].astype(np.float64)  # the gutter: dilated
    assert (np.abs(got - ref) <= 2.0**-9 * ref.max(axis=-1, keepdims=True)).all()
    for k, (lv, cov) in enumerate(ktx2.mip_chain(hot.astype(np.float64), m, ch)):
        d = np.abs(f["images"][k][..., :3] - lv)[cov]
        assert (d <= 2.0**-9 * lv[cov].max(axis=-1, keepdims=True) + 1e-12).all(), k
    # with an alpha (no shared-exponent RGBA format): RGBA16F, exact
    hot4 = np.concatenate([hot, np.full((h, w, 1), 0.5, np.float16)], axis=-1)
    info = ktx2.write(tmp_path / "hot4.ktx2", hot4, m, ch, "half", compression="bc")
    assert info["vk_format"] == KR.VK_R16G16B16A16_SFLOAT and info["bc_fallback"].endswith(
        "RGBA16F"
    )
    assert np.array_equal(KR.read(tmp_path / "hot4.ktx2")["images"][0][m], hot4[m])
    # 8-bit: direction and ratio codes RGBA8 (exact), anything else (sh_l1 8bit) BC7
    codes = rng.integers(2, 254, (h, w, 3)).astype(np.uint8)
    kv = {"usdahd:packing": "R=u:snorm8b G=v:snorm8b B=w_a:unorm8"}
    info = ktx2.write(tmp_path / "d.ktx2", codes, m, ch, "unorm8", compression="bc", attributes=kv)
    assert info["vk_format"] == KR.VK_R8G8B8A8_UNORM and info["bytes_per_texel"] == 4
    assert info["bc_fallback"].startswith("direction / ratio codes")
    assert np.array_equal(KR.read(tmp_path / "d.ktx2")["images"][0][..., :3][m], codes[m])
    kv = {"usdahd:packing": "R=w_a.R:unorm8 G=w_a.G:unorm8 B=w_a.B:unorm8"}
    info = ktx2.write(tmp_path / "r.ktx2", codes, m, ch, "unorm8", compression="bc", attributes=kv)
    assert info["vk_format"] == KR.VK_R8G8B8A8_UNORM and info["bytes_per_texel"] == 4

    # Enlighten's 8-bit SH (sh_l1/8bit): BC7 when L0 + L1 . n decoded from it is within
    # ktx2.BC7_MAX_REL_RMSE, the error measured as texture2ddecoder decodes it; else RGBA8
    packing = "R=L0.R:l0_8bit*l0Scale G=L1x.R:l1_8bit B=L1y.R:l1_8bit A=L1z.R:l1_8bit"
    kv = {"usdahd:packing": packing}
    assert ktx2.packing_codes(packing) == ["l0_8bit", "l1_8bit", "l1_8bit", "l1_8bit"]
    smooth8 = np.stack(
        [160 + 40 * x / w, 127 + 20 * y / h, 127 - 10 * x / w, np.full((h, w), 132)], axis=-1
    ).astype(np.uint8)
    info = ktx2.write(
        tmp_path / "s.ktx2", smooth8, m, ch, "unorm8", compression="bc", attributes=kv
    )
    assert info["vk_format"] == KR.VK_BC7_UNORM_BLOCK and info["bytes_per_texel"] == 1
    t2d = KR.read(tmp_path / "s.ktx2")["images"][0].astype(np.float64)
    q_src, q_t2d = smooth8.astype(np.float64)[m], t2d[m]
    e_src = _sh8_irradiance(q_src)
    t2d_err = np.sqrt(((_sh8_irradiance(q_t2d) - e_src) ** 2).mean()) / np.abs(e_src).mean()
    assert 0 < t2d_err <= ktx2.BC7_MAX_REL_RMSE
    assert info["bc_rel_rmse"] == pytest.approx(t2d_err, rel=1e-9)  # bcdec == texture2ddecoder
    # codes that change texel to texel (noisy SH): BC7 off by far more, so RGBA8, exact
    noisy = rng.integers(2, 254, (h, w, 4)).astype(np.uint8)
    info = ktx2.write(tmp_path / "n.ktx2", noisy, m, ch, "unorm8", compression="bc", attributes=kv)
    assert info["vk_format"] == KR.VK_R8G8B8A8_UNORM and info["bc_rel_rmse"] > 0.1
    assert info["bc_fallback"] == (
        f"BC7 error {info['bc_rel_rmse']:.3g} > 0.015 (RMSE / mean of level 0's decoded "
        "quantities): RGBA8"
    )
    assert np.array_equal(KR.read(tmp_path / "n.ktx2")["images"][0][m], noisy[m])


def _sh8_irradiance(q: np.ndarray) -> np.ndarray:
    """(n, 4) sh_l1/8bit codes -> (n, 15) L0 + L1 . n at 15 upper-hemisphere normals, written
    from docs/schema.md's codes (L0 = (q0 / 255)^2, L1_i = (q_i - 127) / 127 L0)."""
    l0 = (q[:, 0] / 255.0) ** 2
    l1 = (q[:, 1:] - 127.0) / 127.0 * l0[:, None]
    t = np.radians([0.0] + [45.0] * 6 + [80.0] * 8)
    a = np.concatenate([[0.0], np.arange(6) * np.pi / 3, np.arange(8) * np.pi / 4])
    n = np.stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)], axis=-1)
    return l0[:, None] + l1 @ n.T


def test_every_model_through_ktx2_and_an_independent_decoder(baked, capsys):
    stage = baked / "cornell_box.usda"
    layer = baked / "cornell_box.lightmaps.usda"
    rows = []
    for i, (model, ratio) in enumerate(VARIANTS):
        for container in ("ktx2", "ktx2-bc"):
            capsys.readouterr()
            argv = ["bake", str(stage), *FAST, "--model", model, "--ratio", ratio, "--json"]
            assert cli.main([*argv, "--container", container]) == 0
            rep = json.loads(capsys.readouterr().out)
            if i or container != "ktx2":  # after the first bake: a refit, still written as KTX2
                assert all(p["rays"] == 0 for p in rep["prims"] if p["status"] == "baked")
            err, b0, chain, code_rmse, formats = _errors(layer)
            rows.append((model, ratio, container, err, b0, chain, code_rmse))
            lay = models.get(model).layout(ratio)
            if container == "ktx2":  # lossless: the same values as the EXR/PNG
                assert formats <= LOSSLESS and err == 0.0, (model, ratio, formats)
                assert b0 == sum(8 if t.format == "half" else 4 for t in lay)
            else:
                # 8-bit textures BC7 within ktx2.BC7_MAX_REL_RMSE or RGBA8 (direction / ratio
                # codes always RGBA8), non-negative HDR ones BC6H within
                # ktx2.BC6H_MAX_REL_RMSE or E5B9G9R9 (both checked in _errors),
                # signed ones RGBA16F; the rest's error is measured in docs/benchmarks.md
                if not formats - LOSSLESS:
                    # lossless throughout: every HDR texture signed (no signed BC6H encoder),
                    # every 8-bit one direction / ratio codes
                    assert err == 0.0, (model, ratio)
                else:
                    assert math.isfinite(err) and err > 0, (model, ratio)
                if model in ("hhd", "ahd", "hlsh"):
                    # I_z (BC6H within its bound or RGBA16F) + exact directions: issue 39's 2 %
                    assert err <= 0.02, (model, ratio, err)
                assert code_rmse < 24, (model, ratio, code_rmse)
                bound = sum(8 if t.format == "half" else 4 for t in lay)
                assert b0 <= bound, (model, ratio, b0)
    print("\nmodel | ratio | container | KTX2 rel. RMSE | B/texel level 0 | chain | BC7 code RMSE")
    for r in rows:
        print(" | ".join([*r[:3], *(f"{v:.3g}" for v in r[3:])]))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cornell_box.usda", "pillar_room.usda", "exterior_sun_sky.usda"])
def test_the_default_encoding_holds_within_two_percent(tmp_path, capsys, name):
    """issue 39: the default encoding's irradiance from KTX2 (`--container ktx2` and
    `ktx2-bc`) within 2 % relRMSE of the same bake's EXR/PNG decode, read by the independent
    reader (BC6H: Mesa); per texture: I_z BC6H within its bound (or RGBA16F), the direction
    codes exact."""
    shutil.copy(ROOT / "samples" / name, tmp_path / name)
    argv = ["bake", str(tmp_path / name), "--resolution", "16", "--samples", "32", "--quiet"]
    layer = tmp_path / name.replace(".usda", ".lightmaps.usda")
    assert cli.main([*argv, "--container", "ktx2"]) == 0
    err, b0, _, _, formats = _errors(layer)
    assert formats == LOSSLESS and err <= 0.02, (err, formats)
    assert b0 == 12  # hhd/luminance: I_z RGBA16F (8) + direction RGBA8 (4)
    roles = {}
    assert cli.main([*argv, "--container", "ktx2-bc"]) == 0
    err, b0, _, _, formats = _errors(layer, roles)
    assert err <= 0.02 and roles["direction"] == 0.0 and roles["iz"] <= 0.02, (err, roles)
    # I_z BC6H (1 B/texel) or E5B9G9R9 (4, over the BC6H bound) + direction RGBA8 (4)
    assert formats <= {KR.VK_BC6H_UFLOAT_BLOCK, KR.VK_E5B9G9R9_UFLOAT_PACK32, *LOSSLESS}
    assert b0 == (5 if KR.VK_BC6H_UFLOAT_BLOCK in formats else 8), (b0, formats)


def test_block_compressed_container_as_a_subprocess(tmp_path):
    """`usdahd bake --container ktx2-bc` in a subprocess: BC6H I_z (1 B/texel, its measured
    error in --json), direction codes RGBA8 (4 B/texel, the reason in --json: bc_fallback); a bad
    --container value is a usage error (exit 2)."""
    import os
    import subprocess

    import usdahd

    shutil.copy(ROOT / "samples" / "open_plane.usda", tmp_path / "open_plane.usda")
    env = dict(os.environ, PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1]))
    base = [sys.executable, "-m", "usdahd", "bake", str(tmp_path / "open_plane.usda")]
    fast = ["--resolution", "8", "--samples", "4", "--bounces", "0", "--json"]
    proc = subprocess.run(
        [*base, *fast, "--container", "ktx2-bc"], capture_output=True, text=True, env=env
    )
    assert proc.returncode == 0, proc.stderr
    prims = json.loads(proc.stdout)["prims"]
    assert prims and all(p["ktx2"]["iz"]["vk_format"] == 131 for p in prims)
    assert all(p["ktx2"]["iz"]["bc_rel_rmse"] <= ktx2.BC6H_MAX_REL_RMSE for p in prims)
    for p in prims:
        d = p["ktx2"]["direction"]
        f = KR.read(d["path"])
        assert f["vk_format"] == d["vk_format"] == 37 and d["bytes_per_texel"] == 4
        assert d["bc_fallback"].startswith("direction / ratio codes")
    proc = subprocess.run(
        [*base, *fast, "--container", "ktx3"], capture_output=True, text=True, env=env
    )
    assert proc.returncode == 2 and "ktx2-bc" in proc.stderr + proc.stdout
