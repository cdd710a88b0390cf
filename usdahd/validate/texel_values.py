"""Rule ``TexelValues``: decoded texels are finite and within each model's range."""

from __future__ import annotations

import numpy as np

from usdahd.usd import schema
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import Bake, load_for, read_image, record_image
from usdahd.validate.options import DZ_FLOOR, IRRADZ, NONNEGATIVE_COLOURS, UNIT_TOLERANCE

__all__ = ["check_texel_values", "texel_xy"]

# ------------------------------------------------------------------------ rule 3: TexelValues


def texel_xy(bake: Bake, i: int) -> tuple[int, int]:
    return int(bake.xy[i, 0]), int(bake.xy[i, 1])


def check_texel_values(prim) -> list[Finding]:
    """Rule TexelValues (see RULES)."""
    r = RuleFindings("TexelValues", prim)
    bake = load_for(r, prim)
    if bake is None:
        return r.out
    # Raw stored floats first: NaN/Inf anywhere in the texture, padding included.
    for role, lay in bake.layout.items():
        if lay.format not in ("half", "float"):
            continue
        img = record_image(bake.results, read_image(bake.results.textures[role]))
        bad = ~np.isfinite(img.data).all(axis=2)  # float16 or float32 as stored (no copy)
        if bad.any():
            ys, xs = np.nonzero(bad)
            r.error(
                "NonFinite",
                f"{schema.file_property_name(role)} holds {int(bad.sum())} texel(s) with NaN or "
                f"Inf, first at texel ({xs[0]}, {ys[0]})",
                "re-bake the prim; engines propagate NaN through filtering and bloom",
                count=int(bad.sum()),
                texel=(int(xs[0]), int(ys[0])),
            )
    p, model = bake.params, bake.results.model

    def report(code, mask, what, fix="re-bake the prim", **data):
        if mask.any():
            i = int(np.argmax(mask))
            x, y = texel_xy(bake, i)
            r.error(
                code,
                f"{int(mask.sum())} texel(s) {what}, first at texel ({x}, {y})",
                fix,
                count=int(mask.sum()),
                texel=(x, y),
                **data,
            )

    with np.errstate(all="ignore"):
        if "iz" in p:
            iz = p["iz"]
            report("NegativeIz", (iz < 0).any(axis=1) & np.isfinite(iz).all(axis=1), "have I_z < 0")
        if "direction" in p:
            d = p["direction"]
            fin = np.isfinite(d).all(axis=1)
            report(
                "DirectionNotUnit",
                fin & (np.abs(np.linalg.norm(d, axis=1) - 1.0) > UNIT_TOLERANCE),
                "decode to a direction that is not unit length",
            )
            report(
                "DirectionBelowFloor",
                fin & (d[:, 2] < DZ_FLOOR),
                "decode to a direction with d_z below 1/127 (the documented floor; "
                "C_d = I_z (1 - w_a) / d_z blows up)",
                "re-bake the prim; the encoder clamps codes to +-126",
            )
        if "ambient_ratio" in p:
            wa = p["ambient_ratio"]
            fin = np.isfinite(wa).all(axis=1)
            from usdahd.models.irradz import RATIO_RANGE

            lo, hi = RATIO_RANGE.get(model, (0.0, 1.0))
            report(
                "RatioRange",
                fin & ((wa < lo) | (wa > hi)).any(axis=1),
                f"have w_a outside [{lo:g}, {hi:g}] (the range of model {model})",
            )
        if model in NONNEGATIVE_COLOURS:
            if model in IRRADZ:
                from usdahd.models.irradz import colors

                ca, cd, _ = colors(p)
                cols = {"C_a": ca, "C_d": cd}
            else:
                cols = {k: v for k, v in p.items() if k in ("ambient", "directional")}
            for name, c in cols.items():
                c = np.asarray(c)
                report(
                    "NegativeColour",
                    np.isfinite(c).all(axis=1) & (c < 0).any(axis=1),
                    f"have {name} < 0 (model {model} requires colours >= 0)",
                )
    return r.out
