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
FORMAT_NAMES = {
    KR.VK_R8G8B8A8_UNORM: "RGBA8",
    KR.VK_R16G16B16A16_SFLOAT: "RGBA16F",
    KR.VK_E5B9G9R9_UFLOAT_PACK32: "E5B9G9R9",
    KR.VK_BC6H_UFLOAT_BLOCK: "BC6H",
    KR.VK_BC7_UNORM_BLOCK: "BC7",
}


def measure(layer: Path) -> dict:
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    dirs = shm.fibonacci_sphere(32, hemisphere=True)
    sq = absum = count = code_sq = code_n = 0.0
    role_sq: dict[str, float] = {}
    formats: dict[str, set] = {}
    level0 = chain = texels = 0
    seen = set()  # atlas pages: every record of a page names its files; measure each page once
    for prim in schema.prims_with_api(stage):
        res = schema.read_results(prim)
        if res.textures["sh"] in seen:
            continue
        seen.add(res.textures["sh"])
        mod = models.get(res.model)
        _, cov = sidecar.split(sidecar.read(res.textures["sh"]))
        files, packed = {}, {}
        for lay in mod.layout(res.ratio):
            files[lay.role] = images.read(res.textures[lay.role], channels=lay.channels).pixels[cov]
            k = KR.read(Path(res.textures[lay.role]).with_suffix(".ktx2"))
            formats.setdefault(lay.role, set()).add(FORMAT_NAMES.get(k["vk_format"], "?"))
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
        for role in packed:  # the error of each texture alone (the others from the files)
            one = mod.decode({**files, role: packed[role]}, ratio=res.ratio, factors=res.factors)
            d = mod.evaluate(one, n).astype(np.float64) - want
            role_sq[role] = role_sq.get(role, 0.0) + float((d**2).sum())
        absum += float(np.abs(want).sum())
        count += want.size
    return {
        "rel_rmse": math.sqrt(sq / count) / (absum / count),
        "role_rel_rmse": {r: math.sqrt(v / count) / (absum / count) for r, v in role_sq.items()},
        "code_rmse": math.sqrt(code_sq / code_n) if code_n else 0.0,
        "formats": {r: "/".join(sorted(v)) for r, v in formats.items()},
        "bytes_level0": level0 / texels,
        "bytes_chain": chain / texels,
    }


def run(stages=STAGES, resolution: int = 32, samples: int = 256, variants=None) -> dict:
    """Every stage x variant x container; rows of measure() plus stage/model/ratio/rays.
    ``variants``: [(model, ratio)] (default: every model and ratio)."""
    rows = []
    t0 = time.perf_counter()
    if variants is None:
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
        f"Each stage baked once at {res}x{res}, {spp} samples, default bounces and the default "
        "atlas pages (per page: one KTX2 per texture role, rectangles on 4x4 block boundaries), "
        "then every "
        "variant refitted from the SH sidecar (0 rays: the `rays` column counts the refits' "
        "traced rays, the first variant carries the one trace) and written with `--container "
        "ktx2` (lossless: RGBA16F for HDR, RGBA8 for 8-bit) and `--container ktx2-bc` "
        "(docs/schema.md: BC6H UFLOAT for non-negative RGB HDR when the writer's own decode "
        "is within 1.5 % RMSE/mean, else E5B9G9R9; RGBA16F for signed HDR; BC7 for 8-bit "
        "except the IrradZ direction / ratio codes, RGBA8; ispc-texcomp). "
        "KTX2 read back with `tests/ktx2_reader.py` (written from the KTX 2.0 specification), "
        "**texture2ddecoder** for BC7 and Mesa's decoders (lavapipe through wgpu) for BC6H and "
        "E5B9G9R9. "
        "`rel. RMSE`: model decoded from KTX2 level 0 vs the same model decoded from the "
        "EXR/PNG textures, over 32 upper-hemisphere normals and every covered texel (RMSE / "
        "mean |irradiance|: `pooled_rmse_over_mean_abs` of `usdahd.numerics.stats`). "
        "`formats`: the vkFormat of each texture (several when pages differ). `BC7 code "
        "RMSE`: in 8-bit codes. Bytes per texel: level 0, and the full chart-aware mip chain. "
        f"Run: `{result.get('command', DEFAULT_COMMAND)}` "
        f"({result['seconds']:.0f} s here).",
        "",
        *_summary(result["rows"]),
        "",
        "| stage | model | ratio | container | rays | rel. RMSE | each texture alone "
        "| formats | BC7 code RMSE | B/texel level 0 | B/texel chain |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        out.append(
            f"| {r['stage']} | {r['model']} | {r['ratio']} | {r['container']} | {r['rays']} "
            f"| {r['rel_rmse']:.3g} | {_roles(r)} | {_formats(r)} "
            f"| {r['code_rmse']:.2f} | {r['bytes_level0']:.2f} | {r['bytes_chain']:.2f} |"
        )
    out += [
        "",
        "`ktx2` stores the values as they are (0 error by construction, 8 B/texel per HDR "
        "texture and 4 per 8-bit one). `ktx2-bc` block-compresses only what holds up, so the "
        "default encoding holds issue 39's 2 % bound on every sample at 5 B/texel (BC6H I_z "
        "+ RGBA8 directions) or 8 (E5B9G9R9 I_z where BC6H misses its bound), against 12 "
        "lossless and 2 for BC6H + BC7 (which missed the bound on 7 of 9 samples, worst "
        "0.614 on pillar_room, before this check). The causes, per texture (column *each "
        "texture alone*: the model decoded with that one texture from the KTX2, the others "
        "from the EXR/PNG):",
        "",
        "- **The IrradZ `direction` texture through BC7** (the codes (u, v, w_a)) carried most "
        "of the error of ahd/hhd/hlsh: the decode divides by d_z (C_d = I_z (1 - w_a) / d_z), "
        "so a (u, v) code that BC7 moves towards the horizon multiplies C_d. It is a few "
        "outlier texels where the direction varies texel to texel inside a 4x4 block: on "
        "pillar_room (16x16, 64 samples, hhd/luminance) 10 of 676 covered texels carried 99 % "
        "of the squared error, the worst a u code 17 decoded as 2 (d_z 0.19 -> 0.008, C_d x "
        "24). Neither chart edges nor gutters cause it: blocks inside one chart are as bad "
        "(`benchmarks/ktx2_blocks.py`, below), block-aligned atlas pages did not change it, "
        "and filling each block's gutter texels with the mean of its covered ones (cornell_box "
        "32x32, 64 samples: 0.114 -> 0.115) neither. Tried, all more than 10x over 2 %: "
        "ispc-texcomp's BC7 profiles (pillar_room: slow 1.47, basic 1.34, fast 19.5, "
        "ultrafast 3.28); error feedback (1.80 to 20.7); the best of 10 encodings per block by "
        "irradiance error (1.25); refitting w_a to the decoded (u, v) (0.62; lower bound 0.39); "
        "(u, v, w_a) as three BC4 channels (0.76); a layout without 1 / d_z in the decode, V = "
        "(1 - w_a) d / d_z in BC7 with a per-page scale (cornell_box 32x32, 64 samples: 0.048, "
        "but 0.013 from its 8-bit quantization alone, worse than the format it would replace). "
        "So the direction codes stay RGBA8 (4 B/texel, exact). These figures come from "
        "throwaway analyses of the bench's pages, not from this script.",
        "- **BC6H** (the `iz` texture and the other HDR ones) misses 2 % where a 4x4 block spans "
        "a steep gradient or a hotspot: BC6H interpolates in its half-float bit domain with 8 "
        "or 16 levels, so floor_lamp's floor under the lamp (a block spanning 0.12 to 2.84 "
        "where the page's mean I_z is 0.05) is up to 13 % off per texel. Neither the encoder "
        "nor gutters fix it (`python benchmarks/ktx2_blocks.py STAGE --resolution 32 "
        "--samples 256 --causes`: I_z relRMSE with the veryfast / basic / slow / veryslow "
        "profiles cornell_box 0.0283 / 0.0225 / 0.0222 / 0.0221, pillar_room 0.0547 / 0.0567 "
        "/ 0.0565 / 0.0565, floor_lamp 0.221 / 0.213 / 0.225 / 0.219; slow with each block's "
        "gutter texels set to the mean of its covered ones 0.0211, 0.0576, 0.225). So the "
        "writer decodes its BC6H "
        "again (bcdec, through imagecodecs) and keeps it only within 1.5 % RMSE / mean over the "
        "covered texels (`usdahd.ktx2.BC6H_MAX_REL_RMSE`: hhd's irradiance is linear in I_z, "
        "and the BC6H rows above stay under 1.4 %); otherwise the texture is E5B9G9R9 "
        "(shared exponent, 4 B/texel, within 2^-8 of each texel's largest channel).",
        "- **The IrradZ `ratio` texture** (w_a per channel, ratio rgb) feeds the same 1 / d_z "
        "(C_d = I_z (1 - w_a) / d_z): through BC7, with BC6H I_z within its bound and exact "
        "directions, hhd/rgb held 2 % on 7 of 9 stages (worst 0.0305, cornell_box) and hlsh/rgb "
        "on 4 (worst 0.147, pillar_room) (this script at the commit before); so it stays RGBA8 "
        "too.",
        "- **BC7 of `sh_l1` 8bit** is not checked: its rows above show where it misses 2 %.",
        "- **Where in the page** (`python benchmarks/ktx2_blocks.py pillar_room.usda "
        "--resolution 32 --samples 256`, BC6H / BC7 without the checks, one atlas page): "
        "texels of 4x4 blocks inside one chart have a mean BC7 (u, v, w_a) error of 5.6 codes "
        "(p99 27) and a mean BC6H I_z error of 1.6 % (p99 8.8 %); texels of blocks that "
        "straddle charts or a gutter 7.3 codes (p99 27) and 2.9 % (p99 10.2 %): chart edges "
        "add some error, the outliers are everywhere.",
        "- **A bug, fixed earlier**: a float16 texture whose only non-positive values were -0.0 "
        "went BC6H UFLOAT, and ispc-texcomp read the bits of -0.0 as 65504; they are written as "
        "+0 (`tests/test_ktx2.py::test_bc6h_reads_a_negative_zero_as_zero`).",
        END,
    ]
    return "\n".join(out) + "\n"


def _formats(row: dict) -> str:
    f = row.get("formats") or {}
    return ", ".join(f"{k} {v}" for k, v in sorted(f.items())) or "-"


def _roles(row: dict) -> str:
    """Each texture's own error (the others exact): where a variant's error comes from."""
    roles = row.get("role_rel_rmse") or {}
    if row["container"] == "ktx2" or len(roles) < 2:
        return "-"
    return ", ".join(f"{k} {v:.3g}" for k, v in sorted(roles.items()))


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
    per = {}
    for r in rows:
        if r["container"] == "ktx2-bc":
            per.setdefault(f"{r['model']}/{r['ratio']}", []).append(r)
    if per:
        parts = []
        for key, sel in per.items():
            ok = sum(r["rel_rmse"] <= 0.02 for r in sel)
            worst = max(sel, key=lambda r: r["rel_rmse"])
            parts.append(
                f"{key} {ok}/{len(sel)} (worst {worst['rel_rmse']:.3g}, "
                f"{worst['stage'].removesuffix('.usda')})"
            )
        head = "- `--container ktx2-bc` within 2 %, stages per model: "
        out.append(head + "; ".join(parts) + ".")
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
    ap.add_argument(
        "--default-only", action="store_true", help="only the default model/ratio (quick check)"
    )
    ap.add_argument("--json", metavar="PATH", help="also save the rows as JSON")
    ap.add_argument(
        "--from-json", metavar="PATH", help="render the section from a saved --json (no bake)"
    )
    a = ap.parse_args(argv)
    if a.from_json:
        result = json.loads(Path(a.from_json).read_text())
        return _emit(result, a.update)
    stages = a.stages.split(",")
    if a.stages == "all":
        stages = sorted(f.name for f in (REPO / "samples").glob("*.usda"))
    variants = None
    if a.default_only:
        from usdahd.pipeline.settings import DEFAULTS

        m = DEFAULTS["model"]
        variants = [(m, DEFAULTS["ratio"] or models.get(m).RATIOS[0])]
    result = run(stages, resolution=a.resolution, samples=a.samples, variants=variants)
    result["command"] = "python benchmarks/ktx2_bench.py " + " ".join(argv or sys.argv[1:])
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
    return _emit(result, a.update)


def _emit(result: dict, update: str | None) -> int:
    block = section(result)
    if update:
        p = Path(update)
        p.write_text(splice(p.read_text(), block))
    else:
        print(block)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
