"""Rule ``Staleness``: the stored content hash still matches the stage."""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from usdahd import models
from usdahd.usd import inspect, schema
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import LOCK, baked_record

__all__ = ["check_staleness", "settings_drift"]

# -------------------------------------------------------------------------- rule 6: Staleness


class _SceneCache:
    """Scene hash parts per (stage layers, uv name).

    The key is every used layer's identifier with its file's size and mtime, so a stage whose
    layers changed on disk is re-read; stages with unsaved (dirty) or anonymous layers are not
    cached at all (an in-memory edit must never see an older scene).
    """

    def __init__(self):
        self._data: OrderedDict = OrderedDict()

    @staticmethod
    def key(stage, uv_name: str, time=None):
        layers = inspect.layers_stamp(stage)
        if layers is None:
            return None
        return (layers, uv_name, repr(time))

    def get(self, stage, uv_name: str, time=None):
        """Hash parts of the stage read at ``time`` (the bake's: a number or "default")."""
        from usdahd.usd.reader import load_scene

        key = self.key(stage, uv_name, time)
        if key is not None:
            with LOCK:
                if key in self._data:
                    self._data.move_to_end(key)
                    return self._data[key]
        from usdahd.scene.hashing import scene_hash_parts

        parts = scene_hash_parts(load_scene(stage, uv_name=uv_name, time=time))
        if key is not None:
            with LOCK:
                self._data[key] = parts
                while len(self._data) > 8:
                    self._data.popitem(last=False)
        return parts

    def auto_time(self, stage):
        """The time a bake would pick now (usd.time.resolve_time): a number or "default"."""
        from usdahd.usd.time import resolve_time

        key = self.key(stage, "", "auto-time")
        if key is not None:
            with LOCK:
                if key in self._data:
                    return self._data[key]
        t, _ = resolve_time(stage, None)
        now = "default" if t.IsDefault() else float(t.GetValue())
        if key is not None:
            with LOCK:
                self._data[key] = now
        return now

    def clear(self):
        with LOCK:
            self._data.clear()


_SCENES = _SceneCache()


def settings_drift(prim, settings: dict) -> list[str]:
    """Authored bake inputs that differ from the settings the bake used (valid inputs only)."""
    inputs = schema.read_inputs(prim, validate=False)
    if schema.input_problems(inputs):
        return []  # SchemaValues reports invalid inputs; do not guess
    out = []
    authored = schema.authored_input_fields(prim)
    for f, key in schema.SETTING_KEYS.items():
        if f not in authored or key not in settings:
            continue
        v, old = getattr(inputs, f), settings[key]
        try:
            if f == "resolution":
                if v == 0:
                    continue
                same = old == v or (isinstance(old, list | tuple) and list(old) == [v, v])
            elif f == "texel_density":
                if "resolution" in authored and inputs.resolution:
                    continue
                same = old is not None and math.isclose(float(old), float(v), rel_tol=1e-6)
            elif f == "ratio":
                try:
                    if v not in models.get(inputs.model).RATIOS:
                        continue  # ignored by the bake for models without that ratio type
                except Exception:
                    continue
                same = v == old
            elif f == "solver" and v == "":
                continue
            else:
                same = v == old
        except (TypeError, ValueError):
            # A hand-edited record with a value of the wrong type (a string density, ...):
            # it cannot be what this input gave, so it reads as drift, naming the value.
            same = False
        if not same:
            out.append(f"{schema.property_name(schema.INPUT_KEYS[f])} ({old!r} -> {v!r})")
    return out


def check_staleness(prim) -> list[Finding]:
    """Rule Staleness (see RULES)."""
    r = RuleFindings("Staleness", prim)
    results = baked_record(prim)
    if results is None:
        return r.out
    if not results.content_hash:
        r.warning(
            "NoHash",
            "the bake has no content hash, so staleness cannot be checked",
            "re-bake the prim",
        )
        return r.out
    from usdahd.scene.hashing import changed_parts, content_hash
    from usdahd.usd.author import generator_id

    uv_name = str(results.settings.get("uv") or results.uv_primvar or "st")
    from usdahd.errors import StageError

    # Read the stage at the time the bake read it (older bakes: the default time).
    time = results.settings.get("time", "default")
    try:
        parts = _SCENES.get(prim.GetStage(), uv_name, time)
    except StageError as exc:
        r.error(
            "SceneUnreadable",
            f"the stage cannot be read as a scene, so staleness cannot be checked: {exc}",
            "fix the stage (the baker reports the same error)",
        )
        return r.out
    path = str(prim.GetPath())
    if path not in parts:
        r.error(
            "NotInScene",
            "the prim is no longer a visible mesh the baker would bake",
            "re-bake the stage or remove the stale results",
        )
        return r.out
    current, named = content_hash(parts, path, results.settings, generator_id())
    drift = settings_drift(prim, results.settings)
    if results.settings.get("time_auto"):
        # A time chosen from the stage: a re-bake would read the stage's time now.
        now = _SCENES.auto_time(prim.GetStage())
        if now != time:
            drift.append(f"bake time ({time!r} -> {now!r}: the stage's startTimeCode or animation)")
    if current == results.content_hash and not drift:
        return r.out
    changed = changed_parts(results.part_hashes, named) if results.part_hashes else []
    if drift:
        changed = sorted(set(changed) - {"settings"})
    what = ", ".join(changed) if changed else ""
    if drift:
        what = (what + "; " if what else "") + "settings: " + ", ".join(drift)
    if current != results.content_hash and not changed and not drift:
        what = "unknown (no part hashes stored)"
    stale_normals = _normals_drift(prim, results) if "geometry" in changed else None
    if stale_normals:
        what += f" ({stale_normals})"
    if changed == ["generator"] and not drift:
        r.warning(
            "OtherGenerator",
            f"the bake was written by {results.generator or 'another usdahd'}; the scene is "
            "unchanged but the baker version differs",
            "re-bake the prim to pick up baker fixes",
        )
        return r.out
    r.error(
        "Stale",
        f"the bake is stale: changed since the bake: {what}",
        "re-bake the stage (usdahd bake)",
        changed=changed,
        settings=drift,
    )
    return r.out


def _normals_drift(prim, results) -> str | None:
    """When the bake computed and authored the prim's normals (``baked:normals`` not
    "authored"): a sentence if the rule (usdahd.usd.normals, the baker's own function) gives
    other normals on the current points, i.e. the mesh changed under the authored normals."""
    from usdahd.usd import normals as N

    if results.normals not in (N.RULE_CREASE, N.RULE_SMOOTH):
        return None
    time = results.settings.get("time", "default")
    pts, counts, idx, authored, left = inspect.normals_inputs(prim, time)
    if pts is None or counts is None or idx is None or authored is None:
        return None
    idx = np.asarray(idx, np.int64)
    if len(idx) == 0 or idx.min() < 0 or idx.max() >= len(pts) or len(authored) != len(idx):
        return "the normals the bake authored no longer fit the mesh's topology"
    want = N.compute_normals(np.asarray(pts, np.float64), counts, idx, results.normals, left)
    got = np.asarray(authored, np.float32).reshape(-1, 3)
    if np.abs(got - want).max() > 1e-5:
        return (
            f"the {results.normals} normals the bake authored no longer match the mesh: "
            "re-baking recomputes them"
        )
    return None
