"""Instance copies in the glTF export (docs/gltf.md, "Instances").

The baked copies of a PointInstancer prototype mesh become one ``EXT_mesh_gpu_instancing``
node per lightmap page: node TRS = the PointInstancer's local-to-world, per-instance
TRANSLATION/ROTATION/SCALE = its instance transforms, and per-instance
``_LIGHTMAP_SCALE_OFFSET`` (VEC4: the node placement's scale.xy, offset.xy) and
``_LIGHTMAP_PAGE`` (SCALAR) attributes; the copies share the prototype's glTF mesh
(:mod:`usdahd.export.gltf` deduplicates meshes by content in node space).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "GPU_INSTANCING",
    "INSTANCING",
    "PAGE_ATTRIBUTE",
    "SCALE_OFFSET_ATTRIBUTE",
    "instanced_node",
    "instancer_copies",
]

INSTANCING = ("gpu", "nodes")
GPU_INSTANCING = "EXT_mesh_gpu_instancing"
#: Per-instance attributes of EXT_mesh_gpu_instancing nodes (docs/gltf.md, "Instances").
SCALE_OFFSET_ATTRIBUTE = "_LIGHTMAP_SCALE_OFFSET"
PAGE_ATTRIBUTE = "_LIGHTMAP_PAGE"


def instancer_copies(stage, prims, time) -> dict:
    """{id(BakedPrim): (carrier, row-vector matrix of the instance relative to the
    PointInstancer, PointInstancer world matrix)} of the PointInstancer copies among ``prims``
    (scene reader keys ``<PI>/instance_<i><path in prototype>``); the copy's world matrix is
    ``proto_local @ M_i @ W``."""
    from usdahd.usd.transforms import point_instancer_transforms, world_matrices

    out, cache = {}, {}
    for p in prims:
        ref = getattr(p.mesh, "instance", None)
        if ref is None:
            continue
        if ref.carrier not in cache:
            xfs = point_instancer_transforms(stage, ref.carrier, time)
            world = world_matrices(stage, [ref.carrier], time).get(ref.carrier)
            cache[ref.carrier] = (xfs, world)
        xfs, world = cache[ref.carrier]
        if xfs is None or world is None or not 0 <= ref.index < len(xfs):
            continue
        out[id(p)] = (ref.carrier, xfs[ref.index], world)
    return out


def instanced_node(b, carrier: str, rel: str, mesh: int, page: int, members, copies) -> dict:
    """The EXT_mesh_gpu_instancing node of ``members`` ([(BakedPrim, instance TRS)]: copies
    of the prototype mesh ``rel`` of the PointInstancer ``carrier`` on lightmap ``page``,
    sharing glTF ``mesh``); ``copies`` is :func:`instancer_copies`' result. Instance
    attributes are FLOAT accessors with no bufferView target."""
    from usdahd.export.gltf import EXTENSION, LIGHTMAP_TEXCOORD, decompose, placement, trs_fields

    world = decompose(copies[id(members[0][0])][2])
    t = np.array([trs[0] for _, trs in members], np.float32)
    r = np.array([trs[1] for _, trs in members], np.float32)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    s = np.array([trs[2] for _, trs in members], np.float32)
    so = np.array([sum(placement(p.results), []) for p, _ in members], np.float32)
    pages = np.full(len(members), page, np.float32)
    attrs = {
        "TRANSLATION": b.accessor(t, "VEC3", target=None),
        "ROTATION": b.accessor(r, "VEC4", target=None),
        "SCALE": b.accessor(s, "VEC3", target=None),
        SCALE_OFFSET_ATTRIBUTE: b.accessor(so, "VEC4", target=None),
        PAGE_ATTRIBUTE: b.accessor(pages, "SCALAR", target=None),
    }
    inner = "" if rel == "." else "/" + rel
    node = {
        "name": f"{carrier}{inner} (page {page})",
        "mesh": mesh,
        "extensions": {
            GPU_INSTANCING: {"attributes": attrs},
            EXTENSION: {
                "page": page,
                "texCoord": LIGHTMAP_TEXCOORD,
                "prim": carrier,
                "instances": [p.mesh.path for p, _ in members],
            },
        },
    }
    trs_fields(node, world)
    return node
