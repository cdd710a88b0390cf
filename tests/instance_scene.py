"""The instances test stage (issue 39 item 2), written by :func:`write_stage`.

A 60 x 60 m ground, a closed roof slab (x in [-12, -1], y in [2.5, 2.7], z in [-9, 9]), a sun
(DistantLight, normalize on: illuminance ``SUN`` at normal incidence, elevation
``SUN_ELEVATION_DEG``) and a uniform sky (DomeLight, radiance ``SKY``). One prototype, the
class ``/Proto`` (a 1 m box mesh ``Box`` standing on y = 0, six faces in six UV charts of
``st``), is instanced twice: four scenegraph instances (instanceable Xforms referencing it)
and a PointInstancer with five instances (one hidden by ``invisibleIds``). Half of the
visible copies stand under the roof (x = -6), half in the open (x = +14).

An open top face sees the whole sky except the roof, which rises at most 6.5 degrees above
its horizon over less than a third of the azimuths: it hides under 0.5 % of the
cosine-weighted sky (``OPEN_SKY_OCCLUSION``). So with ``--bounces 0`` the top face's I_z is
``SKY + SUN * sin(elevation) / pi`` within that bound.
"""

from __future__ import annotations

import math
from pathlib import Path

SUN = 3.0
SUN_COLOR = (1.0, 0.95, 0.85)
SUN_ELEVATION_DEG = 60.0
SKY = (0.3, 0.45, 0.7)
#: Upper bound of the share of the cosine-weighted sky the roof hides from an open top face:
#: elevation atan(1.7 / 15) = 6.5 deg, sin^2 = 0.0128, over < 1/3 of the azimuths.
OPEN_SKY_OCCLUSION = 0.005

SCENEGRAPH = {
    "/World/Instances/open_0": (14.0, -2.0),
    "/World/Instances/open_1": (14.0, 2.0),
    "/World/Instances/roofed_0": (-6.0, -2.0),
    "/World/Instances/roofed_1": (-6.0, 2.0),
}
#: PointInstancer positions (x, z); index 4 is hidden (invisibleIds = [4]).
POINTS = [(14.0, -6.0), (-6.0, -6.0), (14.0, 6.0), (-6.0, 6.0), (14.0, 0.0)]
HIDDEN = (4,)
OPEN_POINTS = (0, 2)
ROOFED_POINTS = (1, 3)


def top_iz() -> tuple[float, float, float]:
    """I_z (= irradiance / pi) of an unoccluded upward face: sky radiance plus the sun."""
    s = SUN * math.sin(math.radians(SUN_ELEVATION_DEG)) / math.pi
    return tuple(k + s * c for k, c in zip(SKY, SUN_COLOR))


def _box(lo, hi, charts=True):
    """Points, counts, indices and faceVarying st of an axis-aligned box (outward faces)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    p = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    faces = [  # CCW seen from outside
        (0, 1, 3, 2),  # -x
        (4, 6, 7, 5),  # +x
        (0, 4, 5, 1),  # -y
        (2, 3, 7, 6),  # +y (top)
        (0, 2, 6, 4),  # -z
        (1, 5, 7, 3),  # +z
    ]
    idx = [i for f in faces for i in f]
    st = []
    for k in range(6):
        cx, cy = k % 3, k // 3
        u0, v0 = cx / 3 + 0.02, cy / 2 + 0.02
        u1, v1 = (cx + 1) / 3 - 0.02, (cy + 1) / 2 - 0.02
        st += [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    return p, [4] * 6, idx, st


def _fmt(vals):
    return "[" + ", ".join("(" + ", ".join(f"{x:g}" for x in v) + ")" for v in vals) + "]"


def _mesh(name, lo, hi, uv=True, indent="    ", extra=""):
    p, counts, idx, st = _box(lo, hi)
    uvs = (
        f"{indent}    texCoord2f[] primvars:st = {_fmt(st)} (\n"
        f'{indent}        interpolation = "faceVarying"\n{indent}    )\n'
        if uv
        else ""
    )
    return (
        f'{indent}def Mesh "{name}"\n{indent}{{\n'
        f"{indent}    int[] faceVertexCounts = {counts}\n"
        f"{indent}    int[] faceVertexIndices = {idx}\n"
        f"{indent}    point3f[] points = {_fmt(p)}\n"
        f"{uvs}"
        f'{indent}    uniform token subdivisionScheme = "none"\n{extra}'
        f"{indent}}}\n"
    )


def write_stage(
    path: Path, *, proto_uv: bool = True, moved: dict | None = None, point_instancer=True
) -> Path:
    """Write the stage to ``path``. proto_uv False: the prototype has no ``st``; moved:
    scenegraph instance path -> new (x, z); point_instancer False: without the
    PointInstancer (the Cycles reference exporter does not expand PointInstancers)."""
    moved = moved or {}
    sg = ""
    for p, (x, z) in SCENEGRAPH.items():
        x, z = moved.get(p, (x, z))
        name = p.rsplit("/", 1)[1]
        sg += (
            f'        def Xform "{name}" (\n            instanceable = true\n'
            f"            references = </Proto>\n        )\n        {{\n"
            f"            double3 xformOp:translate = ({x:g}, 0, {z:g})\n"
            f'            uniform token[] xformOpOrder = ["xformOp:translate"]\n        }}\n'
        )
    pos = _fmt([(x, 0, z) for x, z in POINTS])
    text = f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
    doc = "Instances test stage (tests/instance_scene.py)"
)

class Xform "Proto"
{{
{_mesh("Box", (-0.5, 0, -0.5), (0.5, 1, 0.5), uv=proto_uv)}}}

def Xform "World"
{{
{_mesh("Ground", (-30, -0.2, -30), (30, 0, 30))}
{_mesh("Roof", (-12, 2.5, -9), (-1, 2.7, 9))}
    def Xform "Instances"
    {{
{sg}    }}

    def PointInstancer "Pawns" (
        active = {"true" if point_instancer else "false"}
    )
    {{
        point3f[] positions = {pos}
        int[] protoIndices = {[0] * len(POINTS)}
        int64[] ids = {list(range(len(POINTS)))}
        int64[] invisibleIds = {list(HIDDEN)}
        rel prototypes = </World/Pawns/Prototypes/Pawn>

        def Scope "Prototypes"
        {{
            def Xform "Pawn" (
                references = </Proto>
            )
            {{
            }}
        }}
    }}

    def Xform "Lights"
    {{
        def DistantLight "Sun"
        {{
            float inputs:angle = 0.53
            color3f inputs:color = {_fmt([SUN_COLOR])[1:-1]}
            float inputs:intensity = {SUN:g}
            bool inputs:normalize = 1
            float3 xformOp:rotateXYZ = ({-SUN_ELEVATION_DEG:g}, 90, 0)
            uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
        }}

        def DomeLight "Sky"
        {{
            color3f inputs:color = {_fmt([SKY])[1:-1]}
            float inputs:intensity = 1
            bool inputs:normalize = 0
        }}
    }}
}}
"""
    path = Path(path)
    path.write_text(text)
    return path
