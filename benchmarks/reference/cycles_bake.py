"""Bake a scene file (``export.save_scene``) with Blender Cycles; run by the bpy interpreter.

Usage (the harness calls it; it imports only bpy, numpy and the standard library)::

    $USDAHD_BPY_PYTHON benchmarks/reference/cycles_bake.py SCENE.npz OUT.npz --spp 1024 \
        [--seed 0] [--threads 0]

Writes ``OUT.npz`` atomically with one float32 array ``iz_<k>`` (h, w, 3) per baked mesh
``k`` (row 0 = the top of the image, the project's texel layout; NaN where Cycles covers no
texel) and ``meta`` (JSON: per-mesh paths, spp, seconds, Blender version).

The set-up (calibrated on analytic cases, see README.md): a DIFFUSE bake with pass_filter
{DIRECT, INDIRECT} and without COLOR, which is E/pi = the project's normalized irradiance I_z
around the shading normal; no denoising, no adaptive sampling, no clamping,
light_sampling_threshold 0, 64 bounces with Russian roulette, light tree on, margin 0.
Lambertian (Diffuse BSDF, roughness 0) surfaces; emission is one-sided (front faces) unless
the material is double-sided. Lights: sphere -> point light with radius (soft falloff off),
power 4 pi^2 r^2 L; point (treatAsPoint) -> power 4 pi I; rect/disk -> area light, spread
180 deg, power pi A L; distant -> sun, strength = illuminance; dome -> world background
(colour or an equirect image already in Blender's convention).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
from npzio import save_npz  # this script's folder is on sys.path (run as a script by bpy)

#: Value written into bake images before baking: texels Cycles does not cover keep it.
SENTINEL = -1.0
#: Cycles drops closures of zero weight: albedo is raised to at least this elsewhere than at
#: the baked point (its bounce light changes by < 1e-4 of the incident).
MIN_ALBEDO = 1e-4


def _setup_cycles(scene, spp: int, seed: int, threads: int) -> None:
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = int(spp)
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.light_sampling_threshold = 0.0
    cy.max_bounces = 64
    cy.diffuse_bounces = 64
    cy.glossy_bounces = 64
    cy.transmission_bounces = 64
    cy.transparent_max_bounces = 64
    cy.volume_bounces = 0
    cy.min_light_bounces = 0
    cy.min_transparent_bounces = 0
    cy.use_light_tree = True
    cy.seed = int(seed)
    cy.use_animated_seed = False
    cy.blur_glossy = 0.0
    if hasattr(cy, "use_guiding"):
        cy.use_guiding = False
    if threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(threads)
    bake = scene.render.bake
    bake.margin = 0
    bake.use_clear = False
    bake.target = "IMAGE_TEXTURES"


def _scaled_color(rgb):
    """(color (r, g, b) with max 1, scale) so that color * scale = rgb."""
    m = max(float(max(rgb)), 0.0)
    if m <= 0:
        return (0.0, 0.0, 0.0), 0.0
    return tuple(float(c) / m for c in rgb), m


def _linear_float(bpy, img):
    """An 8-bit sRGB image as a float image of its decoded (linear) values, cached per image.

    Cycles filters a byte sRGB image in sRGB space and decodes the filtered value
    (``NODE_IMAGE_COMPRESS_AS_SRGB``); usdahd, like a GPU sampling an sRGB texture format,
    decodes the texels and filters the linear values. On noisy pixel-art albedo the two differ
    by several per cent in the mean (decode is convex): measured on McUsd's grass, bounce light
    onto a card in front of it +5.4 % in usdahd before this. A float image is filtered as is."""
    name = f"{img.name}:linear"
    if name in bpy.data.images:
        return bpy.data.images[name]
    w, h = img.size
    c = img.channels
    raw = np.empty(w * h * c, np.float32)
    img.colorspace_settings.name = "Non-Color"  # the stored code values, undecoded
    img.pixels.foreach_get(raw)
    raw = raw.reshape(h, w, c)
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., : min(c, 3)] = raw[..., : min(c, 3)]
    if c == 4:
        rgba[..., 3] = raw[..., 3]
    rgb = rgba[..., :3]
    rgba[..., :3] = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    out = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    out.colorspace_settings.name = "Non-Color"
    out.alpha_mode = "STRAIGHT"
    out.pixels.foreach_set(rgba.ravel())
    return out


def _tex_node(bpy, nt, path: str, srgb: bool, reuse: bool = False):
    """An Image Texture node reading ``path`` through the material's texture UV map ("tex").
    reuse: share an image datablock already loaded from ``path`` (a diffuse texture; masks
    and metallic channels load their own, since the colour space is set per datablock)."""
    img = bpy.data.images.load(path, check_existing=reuse)
    if srgb and not img.is_float:
        img = _linear_float(bpy, img)
    else:
        img.colorspace_settings.name = "sRGB" if srgb else "Non-Color"
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.extension = "REPEAT"
    tex.interpolation = "Linear"
    uvn = nt.nodes.new("ShaderNodeUVMap")
    uvn.uv_map = "tex"
    nt.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    return tex


def _channel(nt, tex, ch: str):
    """The float socket of one channel ("r", "g", "b", "a") of an Image Texture node."""
    if ch == "a":
        return tex.outputs["Alpha"]
    sep = nt.nodes.new("ShaderNodeSeparateColor")
    nt.links.new(tex.outputs["Color"], sep.inputs["Color"])
    return sep.outputs[{"r": "Red", "g": "Green", "b": "Blue"}[ch]]


def _opacity(bpy, nt, desc: dict, shader, baked: bool):
    """``shader`` mixed with a Transparent BSDF by the material's opacity, as usdahd traces it
    (usdahd/bake/kernels/trace.py ``nb_transmits``): a cut-out where opacity < threshold when
    the threshold is > 0, else transmission with probability 1 - opacity. On a baked object
    the baked point itself stays opaque (Light Path "Is Camera Ray"): usdahd bakes every
    covered texel as a surface point; only rays arriving at a cut-out pass through."""
    texture = desc.get("opacity_texture")
    if not texture and float(desc.get("opacity", 1.0)) >= 1.0:
        return shader
    if texture:
        tex = _tex_node(bpy, nt, texture, False)  # alpha/mask values are linear
        op = _channel(nt, tex, desc.get("opacity_channel", "a"))
    else:
        val = nt.nodes.new("ShaderNodeValue")
        val.outputs[0].default_value = float(desc["opacity"])
        op = val.outputs[0]
    thr = float(desc.get("opacity_threshold", 0.0))
    if thr > 0:  # opaque where opacity >= threshold: 1 - (opacity < threshold)
        less = nt.nodes.new("ShaderNodeMath")
        less.operation = "LESS_THAN"
        less.inputs[1].default_value = thr
        nt.links.new(op, less.inputs[0])
        keep = nt.nodes.new("ShaderNodeMath")
        keep.operation = "SUBTRACT"
        keep.inputs[0].default_value = 1.0
        nt.links.new(less.outputs[0], keep.inputs[1])
        op = keep.outputs[0]
    if baked:
        path = nt.nodes.new("ShaderNodeLightPath")
        top = nt.nodes.new("ShaderNodeMath")
        top.operation = "MAXIMUM"
        nt.links.new(op, top.inputs[0])
        nt.links.new(path.outputs["Is Camera Ray"], top.inputs[1])
        op = top.outputs[0]
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(op, mix.inputs["Fac"])
    nt.links.new(clear.outputs["BSDF"], mix.inputs[1])
    nt.links.new(shader, mix.inputs[2])
    return mix.outputs["Shader"]


def _material(bpy, desc: dict, name: str, bake_image=None):
    """A Cycles material: Diffuse BSDF (+ one-sided emission) [+ active bake image node].

    On a baked object the albedo is white *at the baked point* (Light Path "Is Camera Ray",
    which Cycles sets for the bake's primary evaluation) and the material's own elsewhere:
    the DIFFUSE pass without COLOR divides the albedo out anyway, and a dark albedo at the
    baked point would only make Russian roulette kill its paths (fireflies on black surfaces).
    """
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Roughness"].default_value = 0.0
    rgb = nt.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (*[max(float(c), MIN_ALBEDO) for c in desc["albedo"]], 1)
    albedo = rgb.outputs[0]
    if desc.get("texture"):
        tex = _tex_node(bpy, nt, desc["texture"], bool(desc.get("texture_srgb")), reuse=True)
        floor = nt.nodes.new("ShaderNodeVectorMath")
        floor.operation = "MAXIMUM"
        floor.inputs[1].default_value = (MIN_ALBEDO,) * 3
        nt.links.new(tex.outputs["Color"], floor.inputs[0])
        albedo = floor.outputs["Vector"]
    if desc.get("metallic_texture") or float(desc.get("albedo_scale", 1.0)) != 1.0:
        # metallic workflow: diffuse albedo x (1 - metallic) (export._read_metallic)
        if desc.get("metallic_texture"):
            mt = _tex_node(bpy, nt, desc["metallic_texture"], bool(desc.get("metallic_srgb")))
            one_minus = nt.nodes.new("ShaderNodeMath")
            one_minus.operation = "SUBTRACT"
            one_minus.inputs[0].default_value = 1.0
            nt.links.new(_channel(nt, mt, desc.get("metallic_channel", "r")), one_minus.inputs[1])
            k = one_minus.outputs[0]
        else:
            kv = nt.nodes.new("ShaderNodeValue")
            kv.outputs[0].default_value = float(desc["albedo_scale"])
            k = kv.outputs[0]
        scale = nt.nodes.new("ShaderNodeVectorMath")
        scale.operation = "SCALE"
        nt.links.new(albedo, scale.inputs[0])
        nt.links.new(k, scale.inputs["Scale"])
        top = nt.nodes.new("ShaderNodeVectorMath")
        top.operation = "MAXIMUM"
        top.inputs[1].default_value = (MIN_ALBEDO,) * 3
        nt.links.new(scale.outputs["Vector"], top.inputs[0])
        albedo = top.outputs["Vector"]
    if bake_image is not None:
        path = nt.nodes.new("ShaderNodeLightPath")
        mix = nt.nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.inputs["B"].default_value = (1.0, 1.0, 1.0, 1.0)
        nt.links.new(path.outputs["Is Camera Ray"], mix.inputs["Factor"])
        nt.links.new(albedo, mix.inputs["A"])
        albedo = mix.outputs["Result"]
    nt.links.new(albedo, diff.inputs["Color"])
    shader = diff.outputs["BSDF"]
    color, strength = _scaled_color(desc["emission"])
    if desc.get("emission_texture"):
        strength = 1.0
    if strength > 0:
        em = nt.nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = (*color, 1.0)
        em.inputs["Strength"].default_value = strength
        if desc.get("emission_texture"):
            et = _tex_node(bpy, nt, desc["emission_texture"], bool(desc.get("emission_srgb")))
            nt.links.new(et.outputs["Color"], em.inputs["Color"])
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(diff.outputs["BSDF"], add.inputs[0])
        nt.links.new(em.outputs["Emission"], add.inputs[1])
        shader = add.outputs["Shader"]
        if not desc.get("double_sided"):
            geo = nt.nodes.new("ShaderNodeNewGeometry")
            mix = nt.nodes.new("ShaderNodeMixShader")
            nt.links.new(geo.outputs["Backfacing"], mix.inputs["Fac"])
            nt.links.new(add.outputs["Shader"], mix.inputs[1])
            nt.links.new(diff.outputs["BSDF"], mix.inputs[2])
            shader = mix.outputs["Shader"]
    shader = _opacity(bpy, nt, desc, shader, bake_image is not None)
    nt.links.new(shader, out.inputs["Surface"])
    if bake_image is not None:
        _bake_target(nt, bake_image)
    return mat


def _matrix(bpy, rot, pos):
    from mathutils import Matrix

    r = np.asarray(rot, float)  # rows = local axes in world space (USD row-vector matrix)
    m = np.eye(4)
    m[:3, :3] = r.T  # Blender: columns are the local axes
    m[:3, 3] = pos
    return Matrix(m.tolist())


def _add_light(bpy, coll, ld: dict, k: int) -> None:
    t = ld["type"]
    name = f"light{k}"
    if t in ("sphere", "point"):
        light = bpy.data.lights.new(name, "POINT")
        if t == "sphere":
            color, L = _scaled_color(ld["radiance"])
            r = float(ld["radius"])
            light.shadow_soft_size = r
            light.energy = 4.0 * math.pi**2 * r * r * L
        else:
            color, inten = _scaled_color(ld["intensity"])
            light.shadow_soft_size = 0.0
            light.energy = 4.0 * math.pi * inten
        if hasattr(light, "use_soft_falloff"):
            light.use_soft_falloff = False
        rot = np.eye(3)
    elif t in ("rect", "disk"):
        light = bpy.data.lights.new(name, "AREA")
        color, L = _scaled_color(ld["radiance"])
        w, h = (float(s) for s in ld["size"])
        if t == "rect":
            light.shape = "RECTANGLE"
        else:
            light.shape = "DISK" if abs(w - h) <= 1e-9 * max(w, h) else "ELLIPSE"
        light.size, light.size_y = w, h
        light.spread = math.pi
        light.energy = math.pi * float(ld["area"]) * L
        rot = ld["rotation"]
    elif t == "distant":
        light = bpy.data.lights.new(name, "SUN")
        color, E = _scaled_color(ld["illuminance"])
        light.energy = E
        light.angle = float(ld["angle"])
        rot = ld["rotation"]
    else:
        raise SystemExit(f"cycles_bake: unknown light type {t!r} ({ld.get('path')})")
    light.color = color
    obj = bpy.data.objects.new(name, light)
    obj.matrix_world = _matrix(bpy, rot, ld.get("position", (0.0, 0.0, 0.0)))
    coll.objects.link(obj)


def _world(bpy, scene, meta: dict, dome):
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    if dome is not None:
        rows, cols = dome.shape[:2]
        img = bpy.data.images.new("dome", cols, rows, float_buffer=True, alpha=False)
        img.colorspace_settings.name = "Non-Color"
        px = np.ones((rows, cols, 4), np.float32)
        px[..., :3] = dome
        img.pixels.foreach_set(px.ravel())
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.image = img
        env.interpolation = "Linear"
        env.projection = "EQUIRECTANGULAR"
        nt.links.new(env.outputs["Color"], bg.inputs["Color"])
        bg.inputs["Strength"].default_value = 1.0
    elif meta.get("dome_color"):
        color, s = _scaled_color(meta["dome_color"])
        bg.inputs["Color"].default_value = (*color, 1.0)
        bg.inputs["Strength"].default_value = s
    else:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0
    scene.world = world


def _bake_image(bpy, k: int, w: int, h: int):
    """A (w, h) float bake image for mesh k, filled with SENTINEL (texels Cycles does not bake
    keep it)."""
    img = bpy.data.images.new(f"bake{k}", w, h, float_buffer=True, alpha=True)
    img.colorspace_settings.name = "Non-Color"
    init = np.zeros((h, w, 4), np.float32)
    init[..., :3] = SENTINEL
    img.pixels.foreach_set(init.ravel())
    return img


def _bake_target(nt, bake_image) -> None:
    """An Image Texture node of ``bake_image``, selected and active: where Blender bakes to."""
    node = nt.nodes.new("ShaderNodeTexImage")
    node.image = bake_image
    for n in nt.nodes:
        n.select = False
    node.select = True
    nt.nodes.active = node


#: The probes' material (probes.py): white, no emission; the DIFFUSE pass without COLOR
#: divides the albedo out, so any albedo > 0 gives the same I_z.
PROBE_MATERIAL = {"albedo": [1.0, 1.0, 1.0], "emission": [0.0, 0.0, 0.0]}


def _probe_object(bpy, coll, k: int, p, n, uv, bake_image):
    """Mesh k's probe triangles (probes.py) as an object no bounce or shadow ray sees, baked
    into bake_image."""
    t = len(p)
    me = bpy.data.meshes.new(f"probe{k}")
    me.from_pydata(p.reshape(-1, 3).tolist(), [], np.arange(3 * t).reshape(t, 3).tolist())
    me.validate(clean_customdata=False)
    if len(me.polygons) != t:
        raise SystemExit(f"cycles_bake: mesh {k}: Blender dropped probe triangles")
    lm = me.uv_layers.new(name="lightmap")
    lm.data.foreach_set("uv", uv.reshape(-1, 2).astype(np.float32).ravel())
    me.uv_layers.active = lm
    lm.active_render = True
    me.polygons.foreach_set("use_smooth", np.ones(t, bool))
    me.normals_split_custom_set(np.repeat(n, 3, axis=0).tolist())
    me.materials.append(_material(bpy, PROBE_MATERIAL, f"probe{k}", bake_image))
    obj = bpy.data.objects.new(f"probe{k}", me)
    # camera visibility stays on: the bake's primary evaluation is a camera ray (with it off
    # every probe bakes 0); a bake has no camera, so no other camera ray can see a probe
    for flag in ("visible_diffuse", "visible_glossy", "visible_transmission",
                 "visible_volume_scatter", "visible_shadow"):  # fmt: skip
        setattr(obj, flag, False)
    coll.objects.link(obj)
    return obj


def bake(
    scene_file: str, out_file: str, spp: int, seed: int = 0, threads: int = 0,
    oversample: int = 1, probes: str | None = None,
) -> dict:  # fmt: skip
    """Bake every baked mesh; ``oversample`` k (odd) bakes at k x the resolution and keeps the
    centre sub-texel of each texel (same centre and coverage rule, a k x smaller footprint of
    Cycles' in-texel jitter: for steep gradients such as a lamp near a floor). ``probes`` (a
    probes.py file) bakes each mesh's probe triangles instead: the value at each texel's
    centre point, Cycles' jitter confined to 1/100 of a texel."""
    if oversample < 1 or oversample % 2 == 0:
        raise SystemExit(f"cycles_bake: --oversample must be odd and >= 1, got {oversample}")
    if probes is not None and oversample != 1:
        raise SystemExit("cycles_bake: --probes samples texel centres; it takes no --oversample")
    import bpy

    probe_data = np.load(probes, allow_pickle=False) if probes else None

    t0 = time.perf_counter()
    data = np.load(scene_file, allow_pickle=False)
    meta = json.loads(str(data["meta"]))
    tri_p, tri_n, tri_uv = data["tri_p"], data["tri_n"], data["tri_uv"]
    tri_tuv, tri_mesh, tri_mat = data["tri_tuv"], data["tri_mesh"], data["tri_mat"]
    dome = data["dome"] if "dome" in data.files else None

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    _setup_cycles(scene, spp, seed, threads)
    coll = scene.collection
    materials = meta["materials"]
    shared = {}
    images = {}
    baked_objs = []
    for k, m in enumerate(meta["meshes"]):
        sel = np.flatnonzero(tri_mesh == k)
        if len(sel) == 0:
            continue
        n = len(sel)
        me = bpy.data.meshes.new(f"mesh{k}")
        verts = tri_p[sel].reshape(-1, 3)
        faces = np.arange(3 * n).reshape(n, 3)
        me.from_pydata(verts.tolist(), [], faces.tolist())
        me.validate(clean_customdata=False)
        if len(me.polygons) != n:
            raise SystemExit(f"cycles_bake: {m['path']}: Blender dropped triangles")
        lm = me.uv_layers.new(name="lightmap")
        uv = tri_uv[sel].reshape(-1, 2)
        lm.data.foreach_set("uv", np.nan_to_num(uv).astype(np.float32).ravel())
        tex = me.uv_layers.new(name="tex")
        tex.data.foreach_set("uv", tri_tuv[sel].reshape(-1, 2).astype(np.float32).ravel())
        me.uv_layers.active = lm
        lm.active_render = True
        me.polygons.foreach_set("use_smooth", np.ones(n, bool))
        me.normals_split_custom_set(tri_n[sel].reshape(-1, 3).tolist())
        obj = bpy.data.objects.new(f"obj{k}", me)
        coll.objects.link(obj)
        used = np.unique(tri_mat[sel])
        slot = {int(mi): j for j, mi in enumerate(used)}
        bake_img = None
        if m["baked"] and probe_data is not None:
            if f"p_{k}" not in probe_data.files:
                raise SystemExit(f"cycles_bake: {m['path']}: no probes for mesh {k}")
            img = images[k] = _bake_image(bpy, k, *(int(r) for r in m["resolution"]))
            p, n, uv = (probe_data[f"{a}_{k}"] for a in ("p", "n", "uv"))
            if len(p):  # a mesh no texel centre falls in (all edge texels) stays all NaN
                baked_objs.append(_probe_object(bpy, coll, k, p, n, uv, img))
        elif m["baked"]:
            w, h = (int(r) * oversample for r in m["resolution"])
            bake_img = images[k] = _bake_image(bpy, k, w, h)
            baked_objs.append(obj)
        for mi in used:
            desc = materials[int(mi)]
            if bake_img is not None:
                mat = _material(bpy, desc, f"m{k}_{int(mi)}", bake_img)
            else:
                if int(mi) not in shared:
                    shared[int(mi)] = _material(bpy, desc, f"m{int(mi)}")
                mat = shared[int(mi)]
            me.materials.append(mat)
        me.polygons.foreach_set("material_index", np.array([slot[int(x)] for x in tri_mat[sel]]))
    for i, ld in enumerate(meta["lights"]):
        _add_light(bpy, coll, ld, i)
    _world(bpy, scene, meta, dome)
    if not baked_objs:
        raise SystemExit("cycles_bake: no baked mesh in the scene file")
    for o in scene.objects:
        o.select_set(False)
    for o in baked_objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = baked_objs[0]
    t_setup = time.perf_counter() - t0
    t1 = time.perf_counter()
    bpy.ops.object.bake(
        type="DIFFUSE",
        pass_filter={"DIRECT", "INDIRECT"},
        margin=0,
        use_clear=False,
        target="IMAGE_TEXTURES",
    )
    t_bake = time.perf_counter() - t1
    arrays = {}
    out_meshes = []
    for k, img in images.items():
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        px = px.reshape(h, w, 4)[::-1]  # Blender stores bottom-up; ours is row 0 = top
        iz = px[..., :3].copy()
        iz[px[..., 0] <= SENTINEL * 0.5] = np.nan
        c = oversample // 2
        iz = np.ascontiguousarray(iz[c::oversample, c::oversample])
        arrays[f"iz_{k}"] = iz
        out_meshes.append({"index": k, "path": meta["meshes"][k]["path"],
                           "size": [iz.shape[1], iz.shape[0]]})  # fmt: skip
    info = {
        "meshes": out_meshes,
        "spp": int(spp),
        "seed": int(seed),
        "oversample": int(oversample),
        "footprint": "point" if probes else "box",
        "setup_seconds": t_setup,
        "bake_seconds": t_bake,
        "blender": bpy.app.version_string,
    }
    arrays["meta"] = np.array(json.dumps(info))
    save_npz(out_file, arrays, prefix=".cycles.")
    return info


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Bake a reference scene file with Blender Cycles")
    p.add_argument("scene")
    p.add_argument("out")
    p.add_argument("--spp", type=int, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--oversample", type=int, default=1)
    p.add_argument("--probes", help="probes.py file: bake texel centres (point footprint)")
    a = p.parse_args(argv)
    if a.spp < 1:
        print("cycles_bake: --spp must be >= 1", file=sys.stderr)
        return 2
    info = bake(a.scene, a.out, a.spp, a.seed, a.threads, a.oversample, a.probes)
    print(json.dumps(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
