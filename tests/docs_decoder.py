"""A lightmap decoder written from docs/schema.md (and docs/conventions.md) alone.

What an engine or tools programmer writes after reading the page: it imports numpy,
OpenImageIO and pxr, never ``usdahd``. It reads the layout table out of the page itself
(:func:`parse_layouts`), finds textures through the ``ahdLightmap:*`` properties, reads
channels **by name**, and evaluates every model's decode formula in float64.
tests/test_docs_decoder.py compares it with the package.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

DOC = Path(__file__).resolve().parents[1] / "docs" / "schema.md"

# docs/conventions.md: the real SH basis, order Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22.
_C0 = 1 / (2 * math.sqrt(math.pi))
_C1 = math.sqrt(3 / (4 * math.pi))
_C2 = math.sqrt(15 / (4 * math.pi))
_C20 = math.sqrt(5 / (16 * math.pi))
_C22 = math.sqrt(15 / (16 * math.pi))
COSINE = np.array([1.0] + [2 / 3] * 3 + [1 / 4] * 5)  # A_l per band (schema.md)
HL2 = np.array(
    [
        [math.sqrt(2 / 3), 0.0, 1 / math.sqrt(3)],
        [-1 / math.sqrt(6), 1 / math.sqrt(2), 1 / math.sqrt(3)],
        [-1 / math.sqrt(6), -1 / math.sqrt(2), 1 / math.sqrt(3)],
    ]
)
FACTOR_NAMES = (
    "izScale",
    "ratioScale",
    "ambientScale",
    "directionalScale",
    "coefficientsScale",
    "l0Scale",
)


def sh_basis(n: np.ndarray) -> np.ndarray:
    """(..., 3) unit vectors -> (..., 9), docs/conventions.md."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    return np.stack(
        [
            np.full_like(x, _C0),
            -_C1 * y,
            _C1 * z,
            -_C1 * x,
            _C2 * x * y,
            -_C2 * y * z,
            _C20 * (3 * z * z - 1),
            -_C2 * x * z,
            _C22 * (x * x - y * y),
        ],
        axis=-1,
    )


# ------------------------------------------------------------------------ the page's tables


def parse_layouts(text: str | None = None) -> dict[tuple[str, str], list[dict]]:
    """(model, ratio) -> textures [{role, file, packing: [(channel, quantity, code, factor)],
    color_space}] from the layout table of docs/schema.md."""
    text = DOC.read_text() if text is None else text
    out: dict[tuple[str, str], list[dict]] = {}
    head = "| model | ratio | role | file | packing | colorSpace |"
    lines = text.splitlines()
    start = lines.index(head) + 2
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        names, ratio, role, file, packing, cs = cells
        entries = []
        for item in packing.strip("`").split():
            m = re.fullmatch(r"([RGBA])=([^:]+):(\w+)(?:\*(\w+))?", item)
            assert m, f"docs/schema.md: cannot read packing entry {item!r}"
            entries.append(m.groups())
        tex = {"role": role, "file": file, "packing": entries, "color_space": cs}
        for name in names.split(", "):
            out.setdefault((name, ratio), []).append(tex)
    return out


def parse_codes(text: str | None = None) -> set[str]:
    text = DOC.read_text() if text is None else text
    return set(re.findall(r"^\| `(\w+)` \| ", text, flags=re.M))


# ---------------------------------------------------------------------------- the decoding


def decode_code(q: np.ndarray, code: str, factor: float) -> np.ndarray:
    """One channel's stored values -> its quantity (schema.md "Quantization")."""
    q = np.asarray(q, np.float64)
    if code == "half":
        return q * factor
    if code == "unorm8":
        return q / 255 * factor
    if code == "snorm8b":
        return np.maximum((q - 128) / 127, -1.0) * factor
    if code == "l0_8bit":
        return factor * (q / 255) ** 2
    if code in ("l1_8bit", "reserved"):
        return q  # needs L0 of the same texture / ignored: handled by the caller
    raise AssertionError(f"docs/schema.md has no code {code!r}")


def quantities(layout: list[dict], stored: dict, factors: dict) -> dict[str, np.ndarray]:
    """Stored channels (role -> (..., c) arrays in channel order R, G, B, A) -> every named
    quantity of the packing (``u``, ``v``, ``w_a``, ``I_z.R``, ``Y10.G``, ``L1x.B`` ...)."""
    out = {}
    for tex in layout:
        arr = stored[tex["role"]]
        l0 = None
        for k, (_ch, name, code, factor) in enumerate(tex["packing"]):
            f = factors.get(factor, 1.0) if factor else 1.0
            v = decode_code(arr[..., k], code, f)
            if code == "l0_8bit":
                l0 = v
            if code == "l1_8bit":
                v = (np.asarray(arr[..., k], np.float64) - 127) / 127 * l0
            if code != "reserved":
                out[name] = v
    return out


def _rgb(q: dict, name: str) -> np.ndarray:
    return np.stack([q[f"{name}.{c}"] for c in "RGB"], axis=-1)


def _hemioct(u, v):
    px, py = (u + v) / 2, (u - v) / 2
    p = np.stack([px, py, 1 - np.abs(px) - np.abs(py)], axis=-1)
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def irradiance(model: str, ratio: str, q: dict, n: np.ndarray) -> np.ndarray:
    """schema.md "Decode formulas": normalized irradiance (..., 3) at tangent normals (..., 3).

    q : :func:`quantities` of one or more texels (leading shape of n, or broadcastable)."""
    n = np.asarray(n, np.float64)
    nz = n[..., 2:3]
    if model in ("ahd", "hhd", "hlsh"):
        iz = _rgb(q, "I_z")
        d = _hemioct(q["u"], q["v"])
        wa = q["w_a"][..., None] if ratio == "luminance" else _rgb(q, "w_a")
        ca, cd = wa * iz, iz * (1 - wa) / d[..., 2:3]
        nd = np.sum(n * d, axis=-1, keepdims=True)
        if model == "ahd":
            return ca + np.maximum(nd, 0) * cd
        if model == "hhd":
            return (1 + nz) / 2 * ca + np.maximum(nd, 0) * cd
        return ca + nd * cd
    if model == "ahd_classic":
        d = _hemioct(q["u"], q["v"])
        nd = np.sum(n * d, axis=-1, keepdims=True)
        return _rgb(q, "C_a") + np.maximum(nd, 0) * _rgb(q, "C_d")
    if model == "hemisphere":
        return _rgb(q, "C") * (1 + nz) / 2
    if model == "sh_l1" and ratio == "8bit":
        l0 = np.stack([q[f"L0.{c}"] for c in "RGB"], axis=-1)
        l1 = np.stack([np.stack([q[f"L1{a}.{c}"] for a in "xyz"], -1) for c in "RGB"], -2)
        return l0 + 2 * np.einsum("...ck,...k->...c", l1, n)
    if model in ("sh_l1", "sh_l2"):
        names = ["Y00", "Y1m1", "Y10", "Y11", "Y2m2", "Y2m1", "Y20", "Y21", "Y22"]
        k = 4 if model == "sh_l1" else 9
        e = np.stack([_rgb(q, b) for b in names[:k]], axis=-2)  # (..., k, RGB)
        if ratio == "nonlinear":
            l0 = e[..., 0, :] / (2 * math.sqrt(math.pi))
            l1 = np.stack([-e[..., 3, :], -e[..., 1, :], e[..., 2, :]], -1)
            l1 = l1 / (2 * math.sqrt(3 * math.pi))
            mod = np.linalg.norm(l1, axis=-1)
            qq = 0.5 + 0.5 * np.einsum("...ck,...k->...c", l1, n) / np.where(mod > 0, mod, 1)
            r = mod / np.where(l0 > 0, l0, 1)
            p, a = 1 + 2 * r, (1 - r) / (1 + r)
            val = l0 * ((1 - a) * (1 + p) * np.clip(qq, 0, 1) ** p + a)
            return np.where(l0 > 0, np.maximum(np.where(mod > 0, val, l0), 0), 0)
        basis = sh_basis(n)[..., :k] * COSINE[:k]
        return np.einsum("...kc,...k->...c", e, basis)
    if model == "ambient_cube":
        faces = ["posX", "negX", "posY", "negY", "posZ", "negZ"]
        e = np.stack([_rgb(q, f) for f in faces], axis=-2)
        sq = n * n
        w = np.stack(
            [
                sq[..., i // 2] * ((n[..., i // 2] > 0) if i % 2 == 0 else (n[..., i // 2] < 0))
                for i in range(6)
            ],
            axis=-1,
        )
        return np.einsum("...kc,...k->...c", e, w)
    if model == "hl2":
        e = np.stack([_rgb(q, b) for b in ("B0", "B1", "B2")], axis=-2)
        w = np.maximum(n @ HL2.T, 0) ** 2
        return np.einsum("...kc,...k->...c", e, w / w.sum(axis=-1, keepdims=True))
    raise AssertionError(f"docs/schema.md gives no decoder for {model}")


def iz_reference(model: str, sh: np.ndarray) -> np.ndarray | None:
    """I(z) the page says a texel must reproduce, from the sidecar's radiance SH (..., 3, 9),
    for the models whose fit the page defines: IrradZ (``I_z = max(0, 2/√(3π) l_1^0)``),
    hemisphere with solver iz (``C = I_z``) and sh_l2 (the coefficients are the SH)."""
    if model in ("ahd", "hhd", "hlsh", "hemisphere"):
        return np.maximum(2 / math.sqrt(3 * math.pi) * sh[..., 2], 0.0)
    if model == "sh_l2":
        return np.einsum("...ck,k->...c", sh, sh_basis(np.array([0.0, 0, 1])) * COSINE)
    return None


# ------------------------------------------------------------------------------- the files


def read_channels(path: str, names) -> tuple[np.ndarray, dict]:
    """(h, w, len(names)) stored values (float16 or uint8) by channel *name*, and attributes."""
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # PNG alpha is data
    inp = oiio.ImageInput.open(path, config)
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, oiio.UNKNOWN))
    inp.close()
    data = data.reshape(spec.height, spec.width, spec.nchannels)
    have = list(spec.channelnames)
    attrs = {p.name: p.value for p in spec.extra_attribs}
    return data[..., [have.index(c) for c in names]], attrs


def read_prim(prim, layouts=None) -> dict:
    """One baked prim: model, ratio, factors, stored channels per role (h, w, c), the SH
    sidecar (h, w, 3, 9) and coverage (h, w) bool, read the way schema.md describes."""
    layouts = layouts or parse_layouts()

    def get(name):
        return prim.GetAttribute(f"ahdLightmap:{name}").Get()

    model, ratio = str(get("baked:model")), str(get("baked:ratio"))
    factors = {k: float(get(f"baked:{k}")) for k in FACTOR_NAMES}
    layout = layouts[(model, ratio)]
    stored = {}
    for tex in layout:
        path = get(f"texture:{tex['role']}").resolvedPath
        assert path.endswith(".exr" if tex["file"].startswith("EXR") else ".png"), path
        stored[tex["role"]] = read_channels(path, [c for c, *_ in tex["packing"]])[0]
    side = get("sidecar:sh").resolvedPath
    names = [f"{c}{k}" for c in "RGB" for k in range(9)] + ["A"]
    data = read_channels(side, names)[0].astype(np.float64)
    h, w = data.shape[:2]
    return {
        "model": model,
        "ratio": ratio,
        "factors": factors,
        "layout": layout,
        "stored": stored,
        "sh": data[..., :27].reshape(h, w, 3, 9),
        "covered": data[..., 27] > 0.5,
    }


def iz_figures(bake: dict) -> dict | None:
    """validate's IzCheck figures recomputed from the page: max and mean over covered texels of
    |I(z) − reference| relative to the texel's brightest reference channel (None when the page
    does not define the model's fit)."""
    cov = bake["covered"]
    ref = iz_reference(bake["model"], bake["sh"][cov])
    if ref is None:
        return None
    texels = {role: a[cov] for role, a in bake["stored"].items()}
    q = quantities(bake["layout"], texels, bake["factors"])
    z = np.zeros((int(cov.sum()), 3))
    z[:, 2] = 1
    got = irradiance(bake["model"], bake["ratio"], q, z)
    denom = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1e-30)
    rel = np.abs(got - ref) / denom
    return {"max_relative": float(rel.max()), "mean_relative": float(rel.mean())}
