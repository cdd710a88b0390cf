"""Rule ``Textures``: every lightmap texture resolves, opens and matches what the schema
declares."""

from __future__ import annotations

import os

import numpy as np

from usdahd import models, sidecar
from usdahd.usd import inspect, schema
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import baked_record, file_digest, image_info
from usdahd.validate.options import OIIO_FORMATS

__all__ = ["check_textures"]

# --------------------------------------------------------------------------- rule 2: Textures


def _uv_tiles(prim, uv_name: str) -> set[int]:
    uv = inspect.corner_uvs(prim, uv_name)
    if uv is None:
        return set()
    u = np.floor(uv[..., 0].mean(axis=1)).astype(int)
    v = np.floor(uv[..., 1].mean(axis=1)).astype(int)
    return {1001 + a + 10 * b for a, b in zip(u, v) if 0 <= a < 10 and b >= 0}


def check_textures(prim) -> list[Finding]:
    """Rule Textures (see RULES)."""
    from usdahd.usd import assets

    r = RuleFindings("Textures", prim)
    results = baked_record(prim)  # None: SchemaValues reports it
    if results is None or results.format_version not in schema.KNOWN_FORMAT_VERSIONS:
        return r.out  # SchemaValues reports the version (RebakeNeeded / UnknownVersion)
    try:
        layout = {t.role: t for t in models.get(results.model).layout(results.ratio)}
    except Exception:
        layout = {}
    for role in results.textures:
        prop = schema.file_property_name(role)
        attr = prim.GetAttribute(prop)
        asset = results.asset_paths.get(role, "")
        want_cs = schema.COLOR_SPACES.get(role)
        cs = attr.GetColorSpace() if attr.HasColorSpace() else ""
        if want_cs and cs != want_cs:
            r.error(
                "ColorSpace",
                f"{prop} has colorSpace {cs or '(none)'!r}, the schema declares {want_cs!r}",
                f"author colorSpace = {want_cs!r} on {prop} (or re-bake)",
                property=prop,
            )
        if "<UDIM>" in asset:
            tiles = inspect.udim_tiles(attr, asset)
            have = {t for t, _ in tiles}
            want = _uv_tiles(prim, results.uv_primvar)
            missing = sorted(want - have)
            if not tiles or missing:
                r.error(
                    "UdimIncomplete",
                    f"{prop} @{asset}@ is a UDIM set missing tile(s) "
                    f"{', '.join(map(str, missing)) or '(all)'} that the UVs use",
                    "write the missing tiles or re-bake",
                    property=prop,
                    missing=missing,
                )
            files = [(f"tile {t}", p) for t, p in tiles]
        else:
            resolved = attr.Get().resolvedPath if attr.Get() else ""
            if not assets.exists(resolved):  # Ar: files and assets inside usdz packages
                r.error(
                    "MissingFile",
                    f"{prop} @{asset}@ does not resolve to a file",
                    "re-bake the prim, or restore the lightmaps/ folder next to the layer",
                    property=prop,
                    asset=asset,
                )
                continue
            files = [("", resolved)]
            digest = results.digests.get(role)
            if not digest:
                r.warning(
                    "NoDigest",
                    f"{schema.digest_property_name(role)} is not authored, so a replaced "
                    f"{os.path.basename(resolved)} would go unnoticed",
                    "re-bake the prim (usdahd bake records a digest per texture)",
                    property=prop,
                )
            else:
                actual = file_digest(resolved)  # a file or an asset in a package (cached)
                if actual != digest:
                    r.error(
                        "TextureReplaced",
                        f"{prop} ({os.path.basename(resolved)}) is not the file the bake wrote: "
                        f"its digest is {actual[:19]}..., {schema.digest_property_name(role)} "
                        f"records {digest[:19]}...",
                        "re-bake the prim; edit lightmaps only through usdahd bake",
                        property=prop,
                        expected=digest,
                        actual=actual,
                    )
        for label, path in files:
            base = os.path.basename(path.rstrip("]"))  # a package path ends in ...[dir/a.exr]
            where = f"{prop}{' ' + label if label else ''} ({base})"
            try:
                img = image_info(path)  # decoded once per file (an atlas page: once)
            except OSError as exc:
                r.error(
                    "Unreadable",
                    f"{where} does not open with OpenImageIO: {str(exc).strip()[:200]}",
                    "re-bake the prim",
                    property=prop,
                )
                continue
            why = schema.rect_problem(results, (img.width, img.height))
            if why is not None:
                r.error(
                    "Resolution",
                    f"{where} {why}",
                    "re-bake the prim (every texture of a bake has the same resolution, or "
                    "holds its rectangle in an atlas page)",
                    property=prop,
                )
            if role == schema.SIDECAR_ROLE:
                missing_ch = [c for c in sidecar.CHANNELS if c not in img.channel_names]
                if missing_ch:
                    r.error(
                        "Channels",
                        f"{where} lacks channel(s) {', '.join(missing_ch[:6])}"
                        f"{'...' if len(missing_ch) > 6 else ''} of the SH sidecar layout",
                        "re-bake the prim",
                        property=prop,
                    )
                if img.format != "float":
                    r.error(
                        "DataFormat",
                        f"{where} stores {img.format}; the SH sidecar is float32",
                        "re-bake the prim",
                        property=prop,
                    )
                continue
            lay = layout.get(role)
            if lay is None:
                continue
            if sorted(img.channel_names) != sorted(lay.channels):
                r.error(
                    "Channels",
                    f"{where} has channel(s) {' '.join(img.channel_names)}; model "
                    f"{results.model!r} with ratio {results.ratio!r} stores "
                    f"{' '.join(lay.channels)}",
                    "re-bake the prim",
                    property=prop,
                )
            fmt = OIIO_FORMATS.get(img.format, img.format)
            if fmt != lay.format:
                r.error(
                    "DataFormat",
                    f"{where} stores {img.format} but the {role} texture is {lay.format}",
                    "re-bake the prim",
                    property=prop,
                )
            file_cs = img.color_space
            want_ext = lay.extension
            if assets.extension(path) != want_ext:
                r.error(
                    "FileType",
                    f"{where} is not a {want_ext} file; the {role} texture is {lay.format} "
                    f"({want_ext}: what engines and usdz packages accept)",
                    "re-bake the prim",
                    property=prop,
                )
            # PNG says "not sRGB" only with a gAMA chunk of 1.0 (OpenImageIO then reports it
            # linear); without one every reader takes the bytes as sRGB and converts them.
            if assets.extension(path) == ".png":
                if "srgb" in (file_cs or "srgb").lower() and "srgb" not in lay.color_space:
                    r.warning(
                        "FileColorSpace",
                        f"{where} carries no gAMA 1.0 chunk, so image tools and engine "
                        f"importers read it as sRGB although it holds {lay.color_space} data",
                        "re-bake the prim (usdahd writes the gAMA chunk)",
                        property=prop,
                    )
            elif file_cs:
                lin = lay.color_space == "lin_rec709_scene"
                srgb_claim = "srgb" in file_cs.lower()
                if srgb_claim or (not lin and "rec709" in file_cs.lower() and "lin" in file_cs):
                    r.warning(
                        "FileColorSpace",
                        f"{where} declares colour space {file_cs!r} but holds "
                        f"{lay.color_space} data; tools that honour the file tag will convert it",
                        "re-bake the prim (usdahd writes the right tag)",
                        property=prop,
                    )
    return r.out
