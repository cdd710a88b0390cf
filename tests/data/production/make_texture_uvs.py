"""(Re)write ``texture_uvs.usda``: props whose only UV set ``st`` is a texture layout, the
lightmap case of the production assets (issue 37, the OpenChessSet's pieces): charts packed
edge to edge with no gutter, a few texels wide at the automatic density's 32x32 minimum.

Usage::

    python tests/data/production/make_texture_uvs.py [--out DIR]

Deterministic (fixed float formatting, no dates). ``upAxis = "Y"``, ``metersPerUnit = 1``,
default prim ``/World``. The meshes:

- ``Ground``: an 8 m quad whose ``st`` is one chart over [0, 1]^2 (a good lightmap layout); it
  makes the stage 8 m across, so the automatic density stays at its 16/m ceiling (the floor by
  stage size, docs/texels.md, raises it only for smaller stages) and the props are at 32x32.
- ``StripBox``: a 20 cm box whose six faces are six vertical strips of ``st`` side by side,
  1/500 apart (a texture layout: at 32x32 each strip is 5 texels wide and touches its
  neighbours).
  A 64x64 map gives the strips gutters, so its map is raised and ``st`` kept, with a note.
- ``Fence``: 40 upright 1 x 10 cm cards in a row, each card one of 40 strips of ``st`` side by
  side: even at the largest raised map (128x128) the strips are 3 texels wide and touch, so
  the baker unwraps it into ``st_lightmap`` and says why in a note.
- ``Ribbons``: six cards, one on a big chart of ``st`` and five on strips 2 texels wide at
  32x32, two of which touch (fewer than 25 % of the texels touch another chart's, the share
  that alone would trigger a raise): the narrow charts make it raise all the same.
- ``Pieces``: two instanceable references to ``/Proto`` (a box with the strip layout): their
  maps are raised like ``StripBox``'s (an instance copy could not be unwrapped).
- ``Sparks``: 27 separate 1 cm cubes in one mesh with no ``st``: unwrapped, its 162 charts are
  under a texel across at 32x32, so the map is raised until they are ``CHART_MIN_TEXELS`` wide.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HERE = Path(__file__).resolve().parent
GAP = 0.002

# a unit box's 6 faces (counter-clockwise seen from outside), corners as (x, y, z) in {0, 1}
FACES = [
    [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],  # +z
    [(1, 0, 0), (0, 0, 0), (0, 1, 0), (1, 1, 0)],  # -z
    [(1, 0, 1), (1, 0, 0), (1, 1, 0), (1, 1, 1)],  # +x
    [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)],  # -x
    [(0, 1, 1), (1, 1, 1), (1, 1, 0), (0, 1, 0)],  # +y
    [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)],  # -y
]


def _f(x: float) -> str:
    s = f"{x:.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _box(size, centre, strips: bool, cubes=None) -> str:
    """Points, counts, indices (and the strip st when ``strips``) of boxes as usda lines."""
    cubes = cubes or [centre]
    pts, idx, st = [], [], []
    for c in cubes:
        base = {}
        for face_i, face in enumerate(FACES):
            for k, corner in enumerate(face):
                if corner not in base:
                    base[corner] = len(pts)
                    pts.append(tuple(c[a] + (corner[a] - 0.5) * size for a in range(3)))
                idx.append(base[corner])
                u0, u1 = face_i / 6 + GAP / 2, (face_i + 1) / 6 - GAP / 2
                st.append(((u0, u1, u1, u0)[k], (0.0, 0.0, 1.0, 1.0)[k]))
    lines = [
        "        int[] faceVertexCounts = [" + ", ".join(["4"] * (len(idx) // 4)) + "]",
        "        int[] faceVertexIndices = [" + ", ".join(map(str, idx)) + "]",
        "        point3f[] points = ["
        + ", ".join("(" + ", ".join(_f(v) for v in p) + ")" for p in pts)
        + "]",
    ]
    if strips:
        lines.append(
            "        texCoord2f[] primvars:st = ["
            + ", ".join(f"({_f(u)}, {_f(v)})" for u, v in st)
            + '] (\n            interpolation = "faceVarying"\n        )'
        )
    lines.append('        uniform token subdivisionScheme = "none"')
    return "\n".join(lines)


def _fence(cards: int = 40) -> str:
    """``cards`` upright 1 x 10 cm cards along x, card k on the k-th of ``cards`` strips of st."""
    pts, idx, st = [], [], []
    for k in range(cards):
        x = 0.4 + 0.015 * k
        pts += [(x, 0.0, 0.5), (x + 0.01, 0.0, 0.5), (x + 0.01, 0.1, 0.5), (x, 0.1, 0.5)]
        idx += [4 * k + i for i in range(4)]
        u0, u1 = k / cards + GAP / 2, (k + 1) / cards - GAP / 2
        st += [(u0, 0.0), (u1, 0.0), (u1, 1.0), (u0, 1.0)]
    return "\n".join(
        [
            "        int[] faceVertexCounts = [" + ", ".join(["4"] * cards) + "]",
            "        int[] faceVertexIndices = [" + ", ".join(map(str, idx)) + "]",
            "        point3f[] points = ["
            + ", ".join("(" + ", ".join(_f(v) for v in p) + ")" for p in pts)
            + "]",
            "        texCoord2f[] primvars:st = ["
            + ", ".join(f"({_f(u)}, {_f(v)})" for u, v in st)
            + '] (\n            interpolation = "faceVarying"\n        )',
            '        uniform token subdivisionScheme = "none"',
        ]
    )


def _ribbons() -> str:
    """Six upright cards: card 0 on st [0.02, 0.5] x [0.02, 0.98], cards 1-5 on 0.06-wide
    strips, the first two touching (0.54-0.6, 0.6-0.66), the others 0.02-0.06 apart."""
    boxes = [(0.02, 0.5), (0.54, 0.6), (0.6, 0.66), (0.72, 0.78), (0.84, 0.9), (0.92, 0.98)]
    boxes.insert(3, None)  # no card here: a gap in the row (keeps card k at x = k)
    pts, idx, st = [], [], []
    for k, b in enumerate(boxes):
        if b is None:
            continue
        x, w = -0.8 + 0.2 * k, (0.12 if k == 0 else 0.02)
        n = len(pts)
        pts += [(x, 0.0, -0.6), (x + w, 0.0, -0.6), (x + w, 0.15, -0.6), (x, 0.15, -0.6)]
        idx += [n, n + 1, n + 2, n + 3]
        u0, u1 = b
        st += [(u0, 0.02), (u1, 0.02), (u1, 0.98), (u0, 0.98)]
    return "\n".join(
        [
            "        int[] faceVertexCounts = [" + ", ".join(["4"] * (len(idx) // 4)) + "]",
            "        int[] faceVertexIndices = [" + ", ".join(map(str, idx)) + "]",
            "        point3f[] points = ["
            + ", ".join("(" + ", ".join(_f(v) for v in p) + ")" for p in pts)
            + "]",
            "        texCoord2f[] primvars:st = ["
            + ", ".join(f"({_f(u)}, {_f(v)})" for u, v in st)
            + '] (\n            interpolation = "faceVarying"\n        )',
            '        uniform token subdivisionScheme = "none"',
        ]
    )


def write(out: Path) -> Path:
    sparks = [(0.3 + 0.03 * i, 0.02 + 0.03 * j, -0.3 + 0.03 * k)
              for i in range(3) for j in range(3) for k in range(3)]  # fmt: skip
    text = f"""#usda 1.0
(
    defaultPrim = "World"
    doc = "Written by tests/data/production/make_texture_uvs.py: texture-layout UV sets (issue 37)."
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{{
    def Mesh "Ground"
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-4, 0, 4), (4, 0, 4), (4, 0, -4), (-4, 0, -4)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "faceVarying"
        )
        uniform token subdivisionScheme = "none"
    }}

    def Mesh "StripBox"
    {{
{_box(0.2, (0.0, 0.1, 0.0), True)}
    }}

    def Mesh "Fence"
    {{
{_fence()}
    }}

    def Mesh "Ribbons"
    {{
{_ribbons()}
    }}

    def Xform "Pieces"
    {{
        def "A" (
            instanceable = true
            prepend references = </Proto>
        )
        {{
            double3 xformOp:translate = (-0.4, 0, 0.3)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}

        def "B" (
            instanceable = true
            prepend references = </Proto>
        )
        {{
            double3 xformOp:translate = (-0.4, 0, -0.3)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}
    }}

    def Mesh "Sparks"
    {{
{_box(0.01, None, False, sparks)}
    }}

    def DomeLight "Sky"
    {{
        float inputs:intensity = 0.3
    }}

    def DistantLight "Sun"
    {{
        float inputs:angle = 0.53
        float inputs:intensity = 3
        float3 xformOp:rotateXYZ = (-50, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
}}

over "Proto"
{{
    def Mesh "Geom"
    {{
{_box(0.1, (0.0, 0.05, 0.0), True)}
    }}
}}
"""
    path = out / "texture_uvs.usda"
    path.write_text(text)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=HERE)
    print(write(ap.parse_args().out))


if __name__ == "__main__":
    main()
