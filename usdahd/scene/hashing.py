"""Content hashing of a parsed scene (pxr-free; the baker and the validator share it).

A prim's bake depends on its own geometry with its lightmap UVs, every other mesh's shape
(shadows and bounces), the lights, the materials, its settings and the generator version.
:func:`scene_hash_parts` hashes a :class:`~usdahd.scene.types.Scene` into those parts,
:func:`content_hash` combines them for one prim, :func:`changed_parts` names what differs.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

__all__ = ["changed_parts", "content_hash", "is_dark", "scene_hash_parts", "shape_digest"]


def shape_digest(m):
    """sha256 object over a mesh's geometry without its lightmap UVs (points (N, 3), triangles
    (T, 3), normals, material ids: the bytes of each array as stored); a subdivision mesh adds
    its scheme and the refinement's version (:data:`usdahd.scene.subdiv.SUBDIV_VERSION`), so a
    change of the refinement re-bakes it and a cage baked before refinement is stale."""
    shape = hashlib.sha256()
    for a in (m.points, m.triangles, m.normals, m.material):
        shape.update(np.ascontiguousarray(a).tobytes())
    cage = getattr(m, "cage", None)
    if cage is not None:
        from usdahd.scene.subdiv import SUBDIV_VERSION

        shape.update(f"{cage.scheme}; {SUBDIV_VERSION}".encode())
    return shape


def scene_hash_parts(scene) -> dict:
    """Content hashes a bake depends on, from a Scene (the baker and the validator share this).

    Keys: ``<prim path>`` -> the mesh's geometry *with* its lightmap UVs (what its own textures
    depend on); ``shape:<prim path>`` -> geometry without UVs (what other prims' lighting
    depends on: another mesh's lightmap UVs never change this one's bake); ``lights``,
    ``materials`` (from ``Scene.hash_parts``).
    """
    out = {}
    for m in scene.meshes:
        shape = shape_digest(m)
        out[f"shape:{m.path}"] = shape.hexdigest()
        full = shape.copy()
        full.update(b"-" if m.uv is None else np.ascontiguousarray(m.uv, np.float32).tobytes())
        out[m.path] = full.hexdigest()
    base = scene.hash_parts()
    for key in ("lights", "materials"):
        out[key] = base.get(key, "")
    return out


def content_hash(parts: dict, prim_path: str, settings: dict, generator: str) -> tuple[str, dict]:
    """The hash a prim's bake depends on, and its named parts (stored for staleness checks).

    parts : :func:`scene_hash_parts`; the prim's own geometry, every other mesh (shadows and
    bounces), lights, materials, the prim's settings and the generator version.
    generator : the generator id (:func:`usdahd.usd.author.generator_id`: the usdahd version and
        the normals rule, so a rule change re-bakes every prim).
    returns : ("sha256:<hex>", {part name: hex}).
    """
    others = hashlib.sha256()
    for k in sorted(parts):
        if k.startswith("shape:") and k != f"shape:{prim_path}":
            others.update(k.encode() + parts[k].encode())
    named = {
        "geometry": parts.get(prim_path, ""),
        "shape": parts.get(f"shape:{prim_path}", ""),
        "scene_geometry": others.hexdigest(),
        "lights": parts.get("lights", ""),
        "materials": parts.get("materials", ""),
        "settings": hashlib.sha256(
            json.dumps(settings, sort_keys=True, default=str).encode()
        ).hexdigest(),
        "generator": hashlib.sha256(generator.encode()).hexdigest(),
    }
    total = hashlib.sha256(json.dumps(named, sort_keys=True).encode()).hexdigest()
    return f"sha256:{total}", named


def changed_parts(old: dict, new: dict) -> list[str]:
    """Names of hash parts that differ (what changed since the bake)."""
    return sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))


def is_dark(scene) -> bool:
    """True when nothing in the scene emits light (no lights, no emissive material)."""
    return not scene.lights and not any(m.emissive for m in scene.materials)
