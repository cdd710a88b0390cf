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
    role_sq: dict[str, float] = {}
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
        "| stage | model | ratio | container | rays | rel. RMSE | each texture alone "
        "| BC7 code RMSE | B/texel level 0 | B/texel chain |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        out.append(
            f"| {r['stage']} | {r['model']} | {r['ratio']} | {r['container']} | {r['rays']} "
            f"| {r['rel_rmse']:.3g} | {_roles(r)} "
            f"| {r['code_rmse']:.2f} | {r['bytes_level0']:.2f} | {r['bytes_chain']:.2f} |"
        )
    out += [
        "",
        "`ktx2` stores the values as they are (0 error by construction, 8 B/texel per HDR "
        "texture and 4 per 8-bit one): the default encoding through it holds issue 39's 2 % "
        "bound on every sample. `ktx2-bc` (1 B/texel per texture) does not, and the column "
        "*each texture alone* (the model decoded with that one texture from the KTX2 and the "
        "others from the EXR/PNG) says which texture costs what:",
        "",
        "- **The IrradZ `direction` texture** (BC7 of the codes (u, v, w_a)) carries most of the "
        "error of ahd/hhd/hlsh: the decode divides by d_z (C_d = I_z (1 - w_a) / d_z), so a "
        "(u, v) code that BC7 moves towards the horizon multiplies C_d. It is a few outlier "
        "texels, not the average: on pillar_room (16x16, 64 samples, hhd/luminance; a throwaway "
        "analysis of the bench's files) 10 of 676 covered texels carry 99 % of the squared "
        "error, the worst a u code 17 decoded as 2 (d_z 0.19 -> 0.008, C_d x 24). The atlas does "
        "not change it (pages are block aligned, no block mixes two records; pillar_room 1.41 "
        "at 16x16 with 64 samples, was 1.22 with one map per prim): blocks inside one chart "
        "are as bad (`benchmarks/ktx2_blocks.py`, below). Tried on that page, each as an "
        "encoder change in `usdahd/ktx2.py` would be: ispc-texcomp's BC7 profiles (slow 1.47, "
        "basic 1.34, fast 19.5, ultrafast 3.28); error feedback (re-encoding with the "
        "targets moved by the last round's "
        "error, 6 rounds: 1.80 to 20.7); the best of those 10 encodings per 4x4 block, chosen "
        "by the irradiance error itself: 1.25; refitting w_a (B) to the decoded (u, v) and "
        "re-encoding, 4 rounds: 1.47 -> 0.62; the w_a that fits each texel best given the "
        "decoded (u, v), an unreachable lower bound for that idea: 0.39. None comes within 10x "
        "of 2 %: BC7's 4x4 blocks cannot hold (u, v) codes that vary texel to texel where "
        "1 / d_z magnifies them.",
        "- **BC6H alone** (the `iz` texture) misses 2 % where a small hotspot dominates the "
        "mean: floor_lamp's floor "
        "under the lamp reads up to 3.5 where the page's mean I_z is 0.05, and a 4x4 block "
        "spanning 0.12 to 2.84 interpolates in the half-float bit domain with 8 or 16 levels: "
        "up to 13 % off per texel; ispc-texcomp's BC6H profiles from veryfast to veryslow give "
        "0.151 to 0.178 relRMSE of floor_lamp's I_z at 16x16 (throwaway script on the bench's "
        "page).",
        "- **A bug, fixed**: a float16 texture whose only non-positive values were -0.0 "
        "(an SH coefficient that cancels: open_plane's L1 x and y) went BC6H UFLOAT, and "
        "ispc-texcomp read the bits of -0.0 as 65504; `usdahd/ktx2.py` now writes them as +0 "
        "(open_plane sh_l1 linear 0.761 -> 0.0002, sh_l1 nonlinear 0.945 -> 0.0003, sh_l2 "
        "1.06 -> 0.0002; every other row unchanged; `tests/test_ktx2.py::"
        "test_bc6h_reads_a_negative_zero_as_zero`).",
        "",
        "So no block-compressed encoding of the default model holds the 2 % bound on every "
        "sample; `ktx2` (lossless) is the container that does, `ktx2-bc` is for size and its "
        "error is listed here per model. Earlier measurements (one map per prim, pillar_room "
        "32x32, 256 samples, hhd/luminance): BC7 by etcpak 1.10, by ispc-texcomp's slow "
        "profile 0.56 (hhd/rgb: 0.53 vs etcpak's 7.49); filling each block's uncovered texels "
        "from its dominant chart first: no change (1.100 vs 1.101); (u, v, w_a) as three BC4 "
        "channels: 0.76; BC6H on I_z alone with exact directions: 0.075 (0.088 at 64x64). "
        "`python benchmarks/ktx2_blocks.py pillar_room.usda --resolution 32 --samples 256`: "
        "texels of Room blocks inside one chart have a mean BC7 (u, v, w_a) error of 9.3 codes "
        "(blocks straddling charts or a gutter: 7.5) and a mean BC6H I_z error of 3.5 % "
        "(4.1 %); the Pillar 6.9 vs 8.0 codes, 0.8 % vs 2.2 %.",
        END,
    ]
    return "\n".join(out) + "\n"


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
