"""KTX2 compression error per model (docs/benchmarks.md, section "KTX2 engine containers").

Bakes each stage once with ``--container ktx2``, then refits every model/ratio variant from the
SH sidecar (0 rays) with ``--container ktx2`` (lossless) and ``--container ktx2-bc`` (BC6H/BC7),
and reads each KTX2 back with tests/ktx2_reader.py (written from the KTX 2.0 specification),
texture2ddecoder (an independent BC7 decoder) and Mesa's BC6H decoder. For every variant: the
relative hemispherical RMSE of the model decoded from the KTX2 level 0 against the same model
decoded from the EXR/PNG textures (32 upper-hemisphere normals, every covered texel; RMSE over
texels, normals and colours divided by the mean |irradiance|), the BC7 code RMSE, and bytes
per texel of level 0 and of the whole mip chain.

    python benchmarks/ktx2_bench.py                         # print the section
    python benchmarks/ktx2_bench.py --update docs/benchmarks.md
    python benchmarks/ktx2_bench.py --stages all --resolution 16 --samples 64   # every sample
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "tests")]

import ktx2_reader as KR  # noqa: E402

from usdahd import cli, images, models, sidecar  # noqa: E402
from usdahd.numerics import sh as shm  # noqa: E402
from usdahd.usd import schema  # noqa: E402

BEGIN = "<!-- BEGIN ktx2: python benchmarks/ktx2_bench.py --update docs/benchmarks.md -->"
END = "<!-- END ktx2 -->"
STAGES = ("cornell_box.usda", "pillar_room.usda")
CONTAINERS = ("ktx2", "ktx2-bc")
DEFAULT_COMMAND = "python benchmarks/ktx2_bench.py --update docs/benchmarks.md"


def measure(layer: Path) -> dict:
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    dirs = shm.fibonacci_sphere(32, hemisphere=True)
    sq = absum = count = code_sq = code_n = 0.0
    level0 = chain = texels = 0
    for prim in schema.prims_with_api(stage):
        res = schema.read_results(prim)
        mod = models.get(res.model)
        _, cov = sidecar.split(sidecar.read(res.textures["sh"]))
        files, packed = {}, {}
        for lay in mod.layout(res.ratio):
            files[lay.role] = images.read(res.textures[lay.role], channels=lay.channels).pixels[cov]
            k = KR.read(Path(res.textures[lay.role]).with_suffix(".ktx2"))
            packed[lay.role] = k["images"][0][..., : len(lay.channels)][cov].astype(
                files[lay.role].dtype
            )
            if lay.role == "direction":  # docs/schema.md: clamp block-decoded (u, v) codes
                packed[lay.role][..., :2] = np.clip(packed[lay.role][..., :2], 2, 254)
            if lay.format == "unorm8" and k["vk_format"] == KR.VK_BC7_UNORM_BLOCK:
                d = packed[lay.role].astype(np.float64) - files[lay.role]
                code_sq += float((d**2).sum())
                code_n += d.size
            level0 += k["level_index"][0][1]
            chain += sum(n for _, n, _ in k["level_index"])
        texels += int(cov.size)
        n = np.broadcast_to(dirs, (int(cov.sum()),) + dirs.shape)
        want = mod.evaluate(mod.decode(files, ratio=res.ratio, factors=res.factors), n)
        got = mod.evaluate(mod.decode(packed, ratio=res.ratio, factors=res.factors), n)
        sq += float(((got.astype(np.float64) - want) ** 2).sum())
        absum += float(np.abs(want).sum())
        count += want.size
    return {
        "rel_rmse": math.sqrt(sq / count) / (absum / count),
        "code_rmse": math.sqrt(code_sq / code_n) if code_n else 0.0,
        "bytes_level0": level0 / texels,
        "bytes_chain": chain / texels,
    }


def run(stages=STAGES, resolution: int = 32, samples: int = 256) -> dict:
    """Every stage x variant x container; rows of measure() plus stage/model/ratio/rays."""
    rows = []
    t0 = time.perf_counter()
    variants = [(m, r) for m in models.names() for r in models.get(m).RATIOS]
    with tempfile.TemporaryDirectory() as tmp:
        for name in stages:
            d = Path(tmp) / Path(name).stem
            d.mkdir()
            for f in (REPO / "samples").glob("*.usda"):
                shutil.copy(f, d / f.name)
            for sub in ("textures", "sh"):
                if (REPO / "samples" / sub).is_dir():
                    shutil.copytree(REPO / "samples" / sub, d / sub)
            argv = ["bake", str(d / name), "--resolution", str(resolution)]
            argv += ["--samples", str(samples), "--quiet", "--json"]
            for model, ratio in variants:
                for container in CONTAINERS:
                    buf = io.StringIO()
                    with contextlib.redirect_stdout(buf):
                        code = cli.main(
                            [*argv, "--container", container, "--model", model, "--ratio", ratio]
                        )
                    if code != 0:
                        raise SystemExit(f"bake failed: {name} {model} {ratio} {container}")
                    rays = sum(p.get("rays", 0) for p in json.loads(buf.getvalue())["prims"])
                    layer = d / name.replace(".usda", ".lightmaps.usda")
                    row = {"stage": name, "model": model, "ratio": ratio, "container": container}
                    rows.append({**row, "rays": rays, **measure(layer)})
    return {
        "rows": rows,
        "resolution": resolution,
        "samples": samples,
        "seconds": time.perf_counter() - t0,
    }


def section(result: dict) -> str:
    res, spp = result["resolution"], result["samples"]
    out = [
        BEGIN,
        "## KTX2 engine containers (`usdahd bake --container ktx2|ktx2-bc`)",
        "",
        f"Each stage baked once at {res}x{res}, {spp} samples, default bounces, then every "
        "variant refitted from the SH sidecar (0 rays: the `rays` column counts the refits' "
        "traced rays, the first variant carries the one trace) and written with `--container "
        "ktx2` (lossless: RGBA16F for HDR, RGBA8 for 8-bit) and `--container ktx2-bc` (BC6H "
        "UFLOAT for non-negative HDR, RGBA16F for signed HDR, BC7 for 8-bit; ispc-texcomp). "
        "KTX2 read back with `tests/ktx2_reader.py` (written from the KTX 2.0 specification), "
        "**texture2ddecoder** for BC7 and Mesa's decoder (lavapipe through wgpu) for BC6H. "
        "`rel. RMSE`: model decoded from KTX2 level 0 vs the same model decoded from the "
        "EXR/PNG textures, over 32 upper-hemisphere normals and every covered texel (RMSE / "
        "mean |irradiance|: `pooled_rmse_over_mean_abs` of `usdahd.numerics.stats`). "
        "`BC7 code RMSE`: in 8-bit codes. Bytes per texel: level 0, and "
        "the full chart-aware mip chain. "
        f"Run: `{result.get('command', DEFAULT_COMMAND)}` "
        f"({result['seconds']:.0f} s here).",
        "",
        *_summary(result["rows"]),
        "",
        "| stage | model | ratio | container | rays | rel. RMSE | BC7 code RMSE "
        "| B/texel level 0 | B/texel chain |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        out.append(
            f"| {r['stage']} | {r['model']} | {r['ratio']} | {r['container']} | {r['rays']} "
            f"| {r['rel_rmse']:.3g} "
            f"| {r['code_rmse']:.2f} | {r['bytes_level0']:.2f} | {r['bytes_chain']:.2f} |"
        )
    out += [
        "",
        "`ktx2` stores the values as they are (0 error by construction, 8 B/texel per HDR "
        "texture and 4 per 8-bit one). `ktx2-bc` is 1 B/texel per texture: BC7 works on 4x4 "
        "blocks of three or four channels, and the IrradZ `direction` texture packs (u, v, "
        "w_a), quantities that vary independently texel to texel, in maps whose blocks "
        "straddle charts (pillar_room's Room: floor, walls and ceiling in one map); the IrradZ "
        "decode divides by d_z, so a (u, v) code moved towards the horizon multiplies C_d. "
        "Options measured once on pillar_room (32x32, 256 samples, hhd/luminance, I_z "
        "exact, rel. RMSE of irradiance; a throwaway script, not in the repository, that "
        "encoded the textures `usdahd.ktx2.write` receives): BC7 by etcpak 1.10 (the "
        "previous table of this section), by ispc-texcomp's slow profile 0.56 (hhd/rgb: 0.53 "
        "vs etcpak's 7.49); filling each block's uncovered texels from its dominant chart "
        "first: no change (1.100 vs 1.101); (u, v, w_a) as three BC4 channels: 0.76; BC6H on "
        "I_z alone with exact directions: 0.075, where the Room's I_z spans 0.012 to 7.5 "
        "across neighbouring texels (0.088 at 64x64). "
        "4x4 blocks. Chart straddling is not the main cause (`python benchmarks/ktx2_blocks.py "
        "pillar_room.usda --resolution 32 --samples 256`): texels of Room blocks inside one "
        "chart have a mean BC7 (u, v, w_a) error of 9.3 codes (blocks straddling charts or "
        "a gutter: 7.5) and a mean BC6H I_z error of 3.5 % (4.1 %); the Pillar 6.9 vs 8.0 "
        "codes, 0.8 % vs 2.2 %. The codes vary texel to texel, so block-aligned atlas pages "
        "alone will not bring BC7 directions within 2 %. "
        "So no block-compressed encoding of the default model holds the 2 % bound "
        "on every sample; `ktx2` (lossless) is the container that does, `ktx2-bc` is for "
        "size and its error is listed here per model.",
        END,
    ]
    return "\n".join(out) + "\n"


def _summary(rows: list) -> list[str]:
    """The default model's worst case per container (the 2 % bound of issue 39)."""
    from usdahd.pipeline.settings import DEFAULTS

    model = DEFAULTS["model"]
    ratio = DEFAULTS["ratio"] or models.get(model).RATIOS[0]
    out = []
    for container in CONTAINERS:
        key = (model, ratio, container)
        sel = [r for r in rows if (r["model"], r["ratio"], r["container"]) == key]
        if sel:
            worst = max(sel, key=lambda r: r["rel_rmse"])
            out.append(
                f"- Default encoding ({model}/{ratio}), `--container {container}`: worst rel. RMSE "
                f"{worst['rel_rmse']:.3g} ({worst['stage']}) over {len(sel)} stages, "
                f"{worst['bytes_level0']:.0f} B/texel at level 0."
            )
    return out


def splice(text: str, block: str) -> str:
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        return head + block.rstrip("\n") + rest.split(END, 1)[1]
    return text.rstrip("\n") + "\n\n" + block


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--update", metavar="MD", help="splice the section into this markdown file")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--stages", default=",".join(STAGES), help="comma list, or 'all' (samples/)")
    a = ap.parse_args(argv)
    stages = a.stages.split(",")
    if a.stages == "all":
        stages = sorted(f.name for f in (REPO / "samples").glob("*.usda"))
    result = run(stages, resolution=a.resolution, samples=a.samples)
    result["command"] = "python benchmarks/ktx2_bench.py " + " ".join(argv or sys.argv[1:])
    block = section(result)
    if a.update:
        p = Path(a.update)
        p.write_text(splice(p.read_text(), block))
    else:
        print(block)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
