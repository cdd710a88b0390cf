"""``python -m usdahd.export LAYER...``: the error the RGBM and RGBE PNG encodings add to the
float16 lightmap textures of baked layers, per model/ratio and role, as a markdown table
(docs/gltf.md publishes it).

relRMSE = sqrt(sum (decoded - stored)^2 / sum stored^2) over all texels of every texture of that
model and role; max = the largest |decoded - stored| over the largest |stored| of its texture.
"""

from __future__ import annotations

import sys
from collections import defaultdict

import numpy as np


def texture_errors(layers) -> dict:
    """{(model/ratio, role): {encoding: (sum err^2, sum ref^2, max rel)}} over the float16
    textures of every baked prim of ``layers``."""
    from usdahd import images, models
    from usdahd.export import hdr
    from usdahd.export.gltf import check_stage

    acc = defaultdict(lambda: defaultdict(lambda: [0.0, 0.0, 0.0]))
    for layer in layers:
        _, records = check_stage(str(layer))
        for res in records.values():
            for lay in models.get(res.model).layout(res.ratio):
                if lay.format != "half":
                    continue
                v = np.asarray(
                    images.read(res.textures[lay.role], channels=lay.channels).pixels, np.float64
                )
                top = max(float(np.abs(v).max()), 1e-30)
                for enc in hdr.ENCODINGS:
                    px, params = hdr.encode(v, enc)
                    d = hdr.decode(px, enc, params) - v
                    a = acc[(f"{res.model}/{res.ratio}", lay.role)][enc]
                    a[0] += float((d**2).sum())
                    a[1] += float((v**2).sum())
                    a[2] = max(a[2], float(np.abs(d).max()) / top)
    return acc


def main(argv) -> int:
    from usdahd.export import hdr

    acc = texture_errors(argv)
    head = " | ".join(f"{e} relRMSE | {e} max" for e in hdr.ENCODINGS)
    print(f"| model/ratio | role | {head} |")
    print("|---|---|" + "---:|" * (2 * len(hdr.ENCODINGS)))
    for (model, role), by in sorted(acc.items()):
        cells = []
        for e in hdr.ENCODINGS:
            se, sr, mx = by[e]
            cells += [f"{np.sqrt(se / sr) if sr > 0 else 0.0:.3%}", f"{mx:.3%}"]
        print(f"| {model} | {role} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
