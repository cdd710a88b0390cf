"""Atlas fill a bake would reach, without tracing: ``usdahd bake STAGE --dry-run`` plans every
prim (automatic density, unwraps included), then each planned record's texels are rasterised
(``usdahd.bake.texels.rasterize``: the bake's own coverage, which does not depend on samples)
and the records' rectangles are packed exactly as the bake packs them
(``usdahd.numerics.atlas.pack`` with the bake's ``--atlas-size`` / ``--atlas-padding``).

    python benchmarks/atlas_fill.py STAGE [usdahd bake flags ...] [--records]

Prints one JSON line: pages, covered texels, map texels (the prims' own maps, the fill of
``--atlas off``), fill = covered texels / page texels and rect_fill (docs/scenes.md, "Atlas
pages"); ``--records`` adds one row per record (prim, map size, covered texels, unwrapped,
page, whether the plan raised the map above the density for its charts or its minimum).
Seconds of a bake on the classroom instead of minutes; the bake's ``--json`` report gives the
same ``covered_texels`` (a few texels fewer where contacts drop texels). Its cost is the plan's
(``usdahd bake STAGE --dry-run``) plus the rasterisation of every record: 2.9 s of 88.7 s on the
classroom (cProfile, load 6-8, branch i39-plancost). ``plan_exit`` is the plan's exit code: not
0 when a prim failed (its texels are then missing from the figures; stderr says so).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys

import numpy as np


def main(argv: list[str]) -> int:
    from usdahd import cli
    from usdahd.bake.texels import rasterize
    from usdahd.numerics import atlas as packer
    from usdahd.pipeline import atlas as pipeline_atlas

    got: dict = {}
    records = "--records" in argv
    argv = [a for a in argv if a != "--records"]

    def plan_pages(todo, rebuild, opts):
        rows = []
        for job in sorted(todo, key=lambda j: j.path):
            res = tuple(int(r) for r in job.resolution)
            texels = job.texels if job.texels is not None else rasterize(job.mesh, res)
            notes = " ".join(job.report.get("notes", []))
            raised = "unwrapped into" in notes
            rows.append(
                (job.path, res, int(len(np.asarray(texels.xy))), bool(job.unwrapped), raised)
            )
        packing = packer.pack(
            [r[1] for r in rows],
            [r[0] for r in rows],
            max_size=pipeline_atlas.max_size(opts),
            padding=pipeline_atlas.padding(opts),
        )
        covered = sum(r[2] for r in rows)
        area = sum(w * h for w, h in packing.pages)
        got.update(
            prims=len(rows),
            unwrapped=sum(bool(j.unwrapped) for j in todo),
            pages=[list(p) for p in packing.pages],
            covered_texels=covered,
            map_texels=sum(r[1][0] * r[1][1] for r in rows),
            page_texels=area,
            fill=covered / area if area else 0.0,
            rect_fill=packing.fill(),
        )
        if records:
            got["records"] = [
                [r[0], list(r[1]), r[2], r[3], p.page, r[4]]
                for r, p in zip(rows, packing.placements)
            ]
        return {"planned": True}

    pipeline_atlas.plan_pages = plan_pages
    with contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(["bake", *argv, "--dry-run", "--json", "--quiet"])
    if not got:
        print(f"no atlas planned (exit {code})", file=sys.stderr)
        return 1
    got["plan_exit"] = code
    if code:
        # a prim the plan failed (e.g. an unwrap that crashed or stalled) is not in the fill
        print(f"the plan exited {code}: the failed prims are not counted", file=sys.stderr)
    print(json.dumps(got))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
