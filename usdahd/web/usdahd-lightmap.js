// usdahd-lightmap.js: reference three.js importer of the USDAHD_lightmap_directional glTF
// extension written by `usdahd export gltf` (docs/gltf.md). An ES module with no dependency but
// three (the app's own copy is passed in, so it works with any bundler or import map):
//
//   import * as THREE from 'three';
//   import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
//   import { UsdahdLightmapPlugin } from './usdahd-lightmap.js';
//   const loader = new GLTFLoader();
//   loader.register((parser) => new UsdahdLightmapPlugin(parser, { THREE }));
//   const gltf = await loader.loadAsync('level.glb');
//
// The plugin loads every lightmap page's textures (decoding the PNG itself: the stored bytes,
// no colour conversion, no premultiplied alpha; nearest texels) and patches the material of every node that names a page
// (onBeforeCompile): per fragment it fetches the four texels around the lightmap UV, decodes
// each (RGBM/RGBE PNG -> float, 8-bit codes as stored), filters them bilinearly, decodes the
// model with usdahd's reference GLSL (usdahd/shaders/glsl, embedded below) in the lightmap
// tangent frame and adds pi x I(n) to three.js's indirect diffuse irradiance (three's
// irradiance is in W/m^2, usdahd's I is normalized irradiance E/pi). Options:
//   THREE       the three.js namespace (required)
//   irradiance  true: the fragment shows I(n) itself (normalized irradiance, no albedo): the
//               view `usdahd preview` renders, used by the browser test
//   albedo      with irradiance: show albedo x I(n) (three.js's diffuse colour, map included,
//               at the normal-mapped normal): the view of `usdahd preview --model-view`
//   intensity   a factor on the lightmap (default 1)

export const EXTENSION = 'USDAHD_lightmap_directional';
// EXT_mesh_gpu_instancing per-instance attributes the exporter writes (docs/gltf.md, "Instances")
export const SCALE_OFFSET = '_LIGHTMAP_SCALE_OFFSET';
export const PAGE = '_LIGHTMAP_PAGE';

const FACTORS = ['izScale', 'ambientScale', 'directionalScale', 'coefficientsScale', 'l0Scale',
  'ratioScale'];
const ENCODINGS = { unorm8: 0, rgbm: 1, rgbe: 2 };

// Decode and evaluate calls of each model (usdahd.shaders.calls): s<k> is the k-th texture of
// the page in layout order.
export function modelCalls(model, ratio) {
  const rgb = ratio === 'rgb' ? 'true' : 'false';
  if (model === 'ahd' || model === 'hhd' || model === 'hlsh') {
    const ratioArg = ratio === 'rgb' ? 's2.rgb' : 's1.rgb';
    const extra = model === 'hlsh' ? ', ratioScale' : '';
    return {
      file: 'irradz',
      struct: 'UsdahdIrradZ',
      decode: `usdahd_${model}_decode(s0.rgb, s1.rgb, ${ratioArg}, izScale${extra}, ${rgb})`,
      evaluate: `usdahd_${model}_evaluate`,
    };
  }
  if (model === 'ahd_classic') {
    return {
      file: 'ahd_classic',
      struct: 'UsdahdAhdClassic',
      decode: 'usdahd_ahd_classic_decode(s0.rgb, s1.rgb, s2.rgb, ambientScale, directionalScale)',
      evaluate: 'usdahd_ahd_classic_evaluate',
    };
  }
  if (model === 'hemisphere') {
    return {
      file: 'hemisphere',
      struct: 'UsdahdHemisphere',
      decode: 'usdahd_hemisphere_decode(s0.rgb, ambientScale)',
      evaluate: 'usdahd_hemisphere_evaluate',
    };
  }
  if (model === 'sh_l1' && ratio === '8bit') {
    return {
      file: 'sh_l1',
      struct: 'UsdahdShL1',
      decode: 'usdahd_sh_l1_decode_8bit(s0, s1, s2, l0Scale)',
      evaluate: 'usdahd_sh_l1_evaluate',
    };
  }
  const n = { sh_l1: 4, sh_l2: 9, ambient_cube: 6, hl2: 3 }[model];
  if (n === undefined) throw new Error(`${EXTENSION}: unknown model ${model}`);
  const struct = { sh_l1: 'UsdahdShL1', sh_l2: 'UsdahdShL2', ambient_cube: 'UsdahdAmbientCube',
    hl2: 'UsdahdHl2' }[model];
  const args = Array.from({ length: n }, (_, k) => `s${k}.rgb`).join(', ');
  return {
    file: model,
    struct,
    decode: `usdahd_${model}_decode(${args}, coefficientsScale)`,
    evaluate: `usdahd_${model}_evaluate${ratio === 'nonlinear' ? '_nonlinear' : ''}`,
  };
}

// Texel fetch + per-texel decode + bilinear filter (clamp to edge), what a float16 texture
// under a linear sampler gives. uv: glTF texture coordinate (origin top-left).
const SAMPLING_GLSL = /* glsl */ `
vec4 usdahd_fetch_decoded(sampler2D t, ivec2 p, int enc, float mult, vec3 off) {
    vec4 s = texelFetch(t, p, 0);
    if (enc == 1) return vec4(off + mult * s.a * s.rgb, 1.0); // rgbm
    if (enc == 2) { // rgbe
        vec4 q = floor(s * 255.0 + 0.5);
        if (q.a == 0.0 && q.r + q.g + q.b == 0.0) return vec4(off, 1.0);
        return vec4(off + (q.rgb + 0.5) / 256.0 * exp2(q.a - 128.0), 1.0);
    }
    return s; // unorm8: the stored code / 255, decoded by the model's functions
}

vec4 usdahd_sample(sampler2D t, vec2 uv, int enc, float mult, vec3 off) {
    ivec2 size = textureSize(t, 0);
    vec2 p = uv * vec2(size) - 0.5;
    vec2 f = p - floor(p);
    ivec2 i0 = clamp(ivec2(floor(p)), ivec2(0), size - 1);
    ivec2 i1 = clamp(ivec2(floor(p)) + 1, ivec2(0), size - 1);
    vec4 a = usdahd_fetch_decoded(t, i0, enc, mult, off);
    vec4 b = usdahd_fetch_decoded(t, ivec2(i1.x, i0.y), enc, mult, off);
    vec4 c = usdahd_fetch_decoded(t, ivec2(i0.x, i1.y), enc, mult, off);
    vec4 d = usdahd_fetch_decoded(t, i1, enc, mult, off);
    return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
}
`;

// The fragment code of one page's model: uniforms, the shipped decoders, usdahd_lightmap(n).
function fragmentLibrary(page) {
  const calls = modelCalls(page.model, page.ratio);
  const n = page.textures.length;
  let code = 'uniform vec4 usdahdF0;\nuniform vec2 usdahdF1;\n';
  for (let k = 0; k < n; k++) {
    code += `uniform sampler2D usdahdTex${k};\nuniform vec2 usdahdEnc${k};\n`;
    code += `uniform vec3 usdahdOff${k};\n`;
  }
  code += 'varying vec2 usdahdLmUv;\nvarying vec3 usdahdLmTangent;\nvarying float usdahdLmSign;\n';
  code += GLSL.common + '\n' + GLSL[calls.file] + '\n' + SAMPLING_GLSL;
  code += '\nvec3 usdahd_lightmap(vec3 geometry_normal, vec3 shading_normal) {\n';
  FACTORS.forEach((f, k) => {
    code += `    float ${f} = ${k < 4 ? 'usdahdF0.' + 'xyzw'[k] : 'usdahdF1.' + 'xy'[k - 4]};\n`;
  });
  for (let k = 0; k < n; k++) {
    code += `    vec4 s${k} = usdahd_sample(usdahdTex${k}, usdahdLmUv, int(usdahdEnc${k}.x), ` +
      `usdahdEnc${k}.y, usdahdOff${k});\n`;
  }
  code += '    UsdahdFrame frame = usdahd_tangent_frame(geometry_normal, ' +
    'vec4(usdahdLmTangent, usdahdLmSign));\n';
  code += '    vec3 n = usdahd_to_tangent(frame, shading_normal);\n';
  code += `    ${calls.struct} p = ${calls.decode};\n`;
  code += `    return ${calls.evaluate}(p, n);\n}\n`;
  return code;
}

function pageUniforms(THREE, page, textures) {
  const f = page.factors || {};
  const get = (k) => (f[k] === undefined ? 1.0 : f[k]);
  const u = {
    usdahdF0: { value: new THREE.Vector4(get(FACTORS[0]), get(FACTORS[1]), get(FACTORS[2]),
      get(FACTORS[3])) },
    usdahdF1: { value: new THREE.Vector2(get(FACTORS[4]), get(FACTORS[5])) },
  };
  page.textures.forEach((t, k) => {
    const off = t.offset || [0, 0, 0];
    u[`usdahdTex${k}`] = { value: textures[k] };
    u[`usdahdEnc${k}`] = { value: new THREE.Vector2(ENCODINGS[t.encoding], t.multiplier || 1.0) };
    u[`usdahdOff${k}`] = { value: new THREE.Vector3(off[0], off[1], off[2]) };
  });
  return u;
}

// Patch a three.js material (MeshStandardMaterial, MeshPhysicalMaterial, MeshLambertMaterial,
// MeshPhongMaterial) to add the baked lighting of `page` at lightmap UV * scale + offset.
export function patchMaterial(THREE, material, page, textures, placement, options = {}) {
  const uniforms = pageUniforms(THREE, page, textures);
  uniforms.usdahdScaleOffset = { value: new THREE.Vector4(placement.scale[0],
    placement.scale[1], placement.offset[0], placement.offset[1]) };
  uniforms.usdahdIntensity = { value: options.intensity === undefined ? 1.0 : options.intensity };
  let show = options.irradiance ? '#define USDAHD_SHOW_IRRADIANCE\n' : '';
  // EXT_mesh_gpu_instancing: each instance's scale/offset comes from its instance attribute
  const instanced = placement.scaleOffsetAttribute ? '#define USDAHD_INSTANCED\n' : '';
  if (options.irradiance && options.albedo) show += '#define USDAHD_SHOW_ALBEDO\n';
  const texCoord = placement.texCoord === undefined ? 1 : placement.texCoord;
  const uvAttr = texCoord === 0 ? 'uv' : `uv${texCoord}`;
  const tangentAttr = placement.tangentAttribute.toLowerCase();
  material.onBeforeCompile = (shader) => {
    Object.assign(shader.uniforms, uniforms);
    let decl = instanced + `attribute vec4 ${tangentAttr};\n`;
    if (instanced) decl += `attribute vec4 ${placement.scaleOffsetAttribute};\n`;
    if (texCoord > 0) decl += `#ifndef USE_UV${texCoord}\nattribute vec2 ${uvAttr};\n#endif\n`;
    decl += 'uniform vec4 usdahdScaleOffset;\n';
    decl += 'varying vec2 usdahdLmUv;\nvarying vec3 usdahdLmTangent;\nvarying float usdahdLmSign;\n';
    shader.vertexShader = shader.vertexShader
      .replace('#include <common>', '#include <common>\n' + decl)
      .replace('#include <fog_vertex>', '#include <fog_vertex>\n' +
        '#ifdef USDAHD_INSTANCED\n' +
        `    vec4 usdahdSO = ${placement.scaleOffsetAttribute || 'usdahdScaleOffset'};\n` +
        '#else\n    vec4 usdahdSO = usdahdScaleOffset;\n#endif\n' +
        `    usdahdLmUv = ${uvAttr} * usdahdSO.xy + usdahdSO.zw;\n` +
        `    vec3 usdahdT = ${tangentAttr}.xyz;\n` +
        '#ifdef USE_INSTANCING\n    usdahdT = mat3(instanceMatrix) * usdahdT;\n#endif\n' +
        '    usdahdLmTangent = (modelViewMatrix * vec4(usdahdT, 0.0)).xyz;\n' +
        `    usdahdLmSign = ${tangentAttr}.w;\n`);
    const lib = fragmentLibrary(page);
    shader.fragmentShader = shader.fragmentShader
      .replace('#include <common>', '#include <common>\n' + show +
        'uniform float usdahdIntensity;\n' + lib)
      .replace('#include <lights_fragment_begin>', '#include <lights_fragment_begin>\n' +
        '    vec3 usdahdI = usdahdIntensity * usdahd_lightmap(nonPerturbedNormal, normal);\n')
      .replace('#include <lights_fragment_maps>', '#include <lights_fragment_maps>\n' +
        '#if defined( RE_IndirectDiffuse )\n    irradiance += PI * usdahdI;\n#endif\n')
      .replace('#include <dithering_fragment>', '#include <dithering_fragment>\n' +
        '#if defined( USDAHD_SHOW_ALBEDO )\n    gl_FragColor = vec4(usdahdI * diffuseColor.rgb, 1.0);\n' +
        '#elif defined( USDAHD_SHOW_IRRADIANCE )\n    gl_FragColor = vec4(usdahdI, 1.0);\n#endif\n');
  };
  const key = `usdahd:${page.model}:${page.ratio}:${page.textures.length}:${show}:${uvAttr}:` +
    instanced;
  material.customProgramCacheKey = () => key;
  material.needsUpdate = true;
  material.userData.usdahdLightmap = { page, textures, placement };
  return material;
}

// A PNG decoder for the lightmap textures (8-bit grey/grey-alpha/RGB/RGBA, not interlaced: what
// usdahd writes): the bytes exactly as stored. Browser image decoding is not used because it may
// colour-manage (gAMA) or premultiply alpha, losing the RGB of texels whose alpha code is 0,
// which 8-bit SH textures store (L1z = -L0). Inflate through DecompressionStream('deflate').
export async function decodePng(bytes) {
  const u8 = new Uint8Array(bytes);
  const dv = new DataView(u8.buffer, u8.byteOffset, u8.byteLength);
  let pos = 8;
  let width = 0;
  let height = 0;
  let channels = 0;
  const idat = [];
  while (pos < u8.length) {
    const len = dv.getUint32(pos);
    const type = String.fromCharCode(...u8.subarray(pos + 4, pos + 8));
    const data = u8.subarray(pos + 8, pos + 8 + len);
    if (type === 'IHDR') {
      width = dv.getUint32(pos + 8);
      height = dv.getUint32(pos + 12);
      const depth = data[8];
      const colour = data[9];
      channels = { 0: 1, 2: 3, 4: 2, 6: 4 }[colour];
      if (depth !== 8 || !channels || data[12] !== 0) {
        throw new Error(`${EXTENSION}: lightmap PNG must be 8-bit, not interlaced, no palette`);
      }
    } else if (type === 'IDAT') {
      idat.push(data);
    } else if (type === 'IEND') {
      break;
    }
    pos += 12 + len;
  }
  const stream = new Blob(idat).stream().pipeThrough(new DecompressionStream('deflate'));
  const raw = new Uint8Array(await new Response(stream).arrayBuffer());
  const stride = width * channels;
  const out = new Uint8Array(width * height * 4);
  let prev = new Uint8Array(stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = raw.slice(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let i = 0; i < stride; i++) {
      const a = i >= channels ? line[i - channels] : 0;
      const b = prev[i];
      const c = i >= channels ? prev[i - channels] : 0;
      let p = 0;
      if (filter === 1) p = a;
      else if (filter === 2) p = b;
      else if (filter === 3) p = (a + b) >> 1;
      else if (filter === 4) {
        const pa = Math.abs(b - c);
        const pb = Math.abs(a - c);
        const pc = Math.abs(a + b - 2 * c);
        p = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      }
      line[i] = (line[i] + p) & 255;
    }
    for (let x = 0; x < width; x++) {
      const o = (y * width + x) * 4;
      const q = x * channels;
      if (channels >= 3) {
        out[o] = line[q];
        out[o + 1] = line[q + 1];
        out[o + 2] = line[q + 2];
        out[o + 3] = channels === 4 ? line[q + 3] : 255;
      } else {
        out[o] = out[o + 1] = out[o + 2] = line[q];
        out[o + 3] = channels === 2 ? line[q + 1] : 255;
      }
    }
    prev = line;
  }
  return { width, height, data: out };
}

// A lightmap texture of the glTF: the PNG's bytes as a DataTexture (data, not colour).
async function loadRawTexture(THREE, parser, textureIndex) {
  const json = parser.json;
  const source = json.images[json.textures[textureIndex].source];
  let bytes;
  if (source.bufferView !== undefined) {
    bytes = await parser.getDependency('bufferView', source.bufferView);
  } else {
    const url = new URL(source.uri, new URL(parser.options.path || './', globalThis.location?.href));
    bytes = await (await fetch(url)).arrayBuffer();
  }
  const png = await decodePng(bytes);
  const tex = new THREE.DataTexture(png.data, png.width, png.height, THREE.RGBAFormat,
    THREE.UnsignedByteType);
  tex.flipY = false; // glTF: row 0 at texture coordinate v = 0
  tex.magFilter = THREE.NearestFilter;
  tex.minFilter = THREE.NearestFilter;
  tex.generateMipmaps = false;
  tex.wrapS = THREE.ClampToEdgeWrapping;
  tex.wrapT = THREE.ClampToEdgeWrapping;
  tex.colorSpace = THREE.NoColorSpace;
  tex.unpackAlignment = 1;
  tex.needsUpdate = true;
  return tex;
}

export class UsdahdLightmapPlugin {
  constructor(parser, options = {}) {
    if (!options.THREE) throw new Error(`${EXTENSION}: pass { THREE } (the three.js namespace)`);
    this.parser = parser;
    this.name = EXTENSION;
    this.options = options;
  }

  async afterRoot(result) {
    const THREE = this.options.THREE;
    const parser = this.parser;
    const ext = (parser.json.extensions || {})[EXTENSION];
    if (!ext) return;
    const pages = await Promise.all(ext.pages.map((page) =>
      Promise.all(page.textures.map((t) => loadRawTexture(THREE, parser, t.index)))));
    const tangentAttribute = ext.tangentAttribute || '_LIGHTMAP_TANGENT';
    const patched = [];
    result.scene.traverse((obj) => {
      const assoc = parser.associations.get(obj);
      if (!assoc || assoc.nodes === undefined) return;
      const nodeDef = parser.json.nodes[assoc.nodes];
      const place = nodeDef.extensions && nodeDef.extensions[EXTENSION];
      if (!place) return;
      const page = ext.pages[place.page];
      const placement = {
        scale: place.scale || [1, 1],
        offset: place.offset || [0, 0],
        texCoord: place.texCoord === undefined ? 1 : place.texCoord,
        tangentAttribute,
      };
      const meshes = obj.isMesh ? [obj] : obj.children.filter((c) => c.isMesh);
      for (const mesh of meshes) {
        if (place.instances) {
          // EXT_mesh_gpu_instancing: GLTFLoader made an InstancedMesh whose geometry holds the
          // per-instance attributes under their glTF names; one page per node (the exporter
          // splits a PointInstancer's copies by page), so _LIGHTMAP_PAGE only checks that.
          const so = mesh.geometry.getAttribute(SCALE_OFFSET);
          if (!mesh.isInstancedMesh || !so) {
            throw new Error(`${EXTENSION}: node ${place.prim} lists instances but has no ` +
              `${SCALE_OFFSET} instance attribute (EXT_mesh_gpu_instancing)`);
          }
          const pg = mesh.geometry.getAttribute(PAGE);
          for (let i = 0; pg && i < pg.count; i++) {
            if (pg.getX(i) !== place.page) {
              throw new Error(`${EXTENSION}: instance ${i} of ${place.prim} is on page ` +
                `${pg.getX(i)}, its node on page ${place.page}`);
            }
          }
          placement.scaleOffsetAttribute = SCALE_OFFSET;
          mesh.userData.usdahdInstances = place.instances; // USD key of each instance
        }
        mesh.material = patchMaterial(THREE, mesh.material.clone(), page, pages[place.page],
          placement, this.options);
        mesh.userData.usdahdPrim = place.prim; // the USD prim path (node names are sanitized)
        patched.push(mesh);
      }
    });
    result.userData.usdahdLightmap = { pages: ext.pages, meshes: patched };
  }
}

// BEGIN generated by python -m usdahd.web (the shipped usdahd/shaders/glsl; do not edit)
const GLSL = {
  common: "// usdahd reference decoders (GLSL), common part: channel codes, hemi-octahedral directions,\n// the lightmap tangent frame, normal maps and self-bounce. Format version 2: docs/schema.md.\n// Texture samples are what the GPU returns: EXR half textures as floats, 8-bit PNG textures as\n// UNORM8 (t = q / 255). Filter the stored channels first, then decode. No #version, bindings\n// or entry point: paste (or #include) this before the model's file.\n\nconst float USDAHD_DZ_MIN = 0.007874016; // 1/127: the smallest d_z an 8-bit direction decodes to\nconst float USDAHD_SH_C0 = 0.2820947918; // 1 / (2 sqrt(pi))\nconst float USDAHD_SH_C1 = 0.4886025119; // sqrt(3 / (4 pi))\nconst float USDAHD_SH_C2 = 1.0925484306; // sqrt(15 / (4 pi))\nconst float USDAHD_SH_C20 = 0.3153915653; // sqrt(5 / (16 pi))\nconst float USDAHD_SH_C22 = 0.5462742153; // sqrt(15 / (16 pi))\n\n// Lightmap UV (st of ahdLightmap:baked:uvPrimvar) -> texture coordinate: row 0 is v = 1.\nvec2 usdahd_lightmap_texcoord(vec2 st) {\n    return vec2(st.x, 1.0 - st.y);\n}\n\n// Atlas page: a record's lightmap UV st -> texture coordinate in its page. scale_offset is\n// ahdLightmap:atlas:scaleOffset (sx, sy, ox, oy): uv_page = st * (sx, sy) + (ox, oy) in USD's\n// v-up convention, (1, 1, 0, 0) without an atlas (then this is usdahd_lightmap_texcoord).\nvec2 usdahd_page_texcoord(vec2 st, vec4 scale_offset) {\n    return usdahd_lightmap_texcoord(st * scale_offset.xy + scale_offset.zw);\n}\n\n// The same for pages bound as one texture array (layer = ahdLightmap:atlas:page):\n// texture(sampler2DArray, usdahd_page_texcoord_array(st, scale_offset, page)).\nvec3 usdahd_page_texcoord_array(vec2 st, vec4 scale_offset, int page) {\n    return vec3(usdahd_page_texcoord(st, scale_offset), float(page));\n}\n\n// snorm8b: signed value biased into UNORM8, (q - 128) / 127 from the sample t = q / 255.\nfloat usdahd_snorm8b(float t) {\n    return max((255.0 * t - 128.0) / 127.0, -1.0);\n}\n\nvec3 usdahd_snorm8b3(vec3 t) {\n    return max((255.0 * t - 128.0) / 127.0, vec3(-1.0));\n}\n\n// Hemi-octahedral direction (tangent space, d_z > 0) from the R, G samples of `direction`.\nvec3 usdahd_hemioct_decode(vec2 rg) {\n    float u = usdahd_snorm8b(rg.x);\n    float v = usdahd_snorm8b(rg.y);\n    float px = 0.5 * (u + v);\n    float py = 0.5 * (u - v);\n    return normalize(vec3(px, py, 1.0 - abs(px) - abs(py)));\n}\n\n// Tangent frame (rows t, b, n) of tangentFrame = \"mikktspace_uv\": n the interpolated shading\n// normal, tangent.xyz the interpolated MikkTSpace tangent of the lightmap UV set, tangent.w its\n// sign. Gram-Schmidt, then b = sign * cross(n, t).\nstruct UsdahdFrame {\n    vec3 t;\n    vec3 b;\n    vec3 n;\n};\n\nUsdahdFrame usdahd_tangent_frame(vec3 normal, vec4 tangent) {\n    vec3 n = normalize(normal);\n    vec3 t = normalize(tangent.xyz - n * dot(n, tangent.xyz));\n    return UsdahdFrame(t, tangent.w * cross(n, t), n);\n}\n\n// A vector (e.g. the world-space shading normal) in the frame: (v.t, v.b, v.n).\nvec3 usdahd_to_tangent(UsdahdFrame f, vec3 v) {\n    return vec3(dot(v, f.t), dot(v, f.b), dot(v, f.n));\n}\n\n// A tangent-space normal map texel (UNORM RGB, 2 t - 1) in the *material's* tangent frame\n// (its own UV set) -> unit shading normal in the space of that frame.\nvec3 usdahd_apply_normal_map(vec3 texel, UsdahdFrame material) {\n    vec3 m = 2.0 * texel - 1.0;\n    return normalize(m.x * material.t + m.y * material.b + m.z * material.n);\n}\n\n// Self-bounce of 2024 App. A: albedo * I_z * (1 - n_z) / 2 (I_z: the model's I at n = z).\nvec3 usdahd_self_bounce(vec3 iz, vec3 n, vec3 albedo) {\n    return albedo * iz * (0.5 * (1.0 - n.z));\n}\n",
  ahd_classic: "// Classic AHD (GLSL): textures ambient, direction, directional -> (C_a, d, C_d) -> I(n).\n\nstruct UsdahdAhdClassic {\n    vec3 ca;\n    vec3 d;\n    vec3 cd;\n};\n\nUsdahdAhdClassic usdahd_ahd_classic_decode(vec3 ambient, vec3 direction, vec3 directional,\n                                           float ambient_scale, float directional_scale) {\n    return UsdahdAhdClassic(ambient * ambient_scale, usdahd_hemioct_decode(direction.xy),\n                            directional * directional_scale);\n}\n\nvec3 usdahd_ahd_classic_evaluate(UsdahdAhdClassic p, vec3 n) {\n    return p.ca + max(dot(n, p.d), 0.0) * p.cd;\n}\n\n// The naive engine import of an AHD bake (2018 Sec. 2, Fig. 2; `usdahd preview --ahd-classic`):\n// C_a, d (unit vector, tangent space) and C_d stored as float textures at the texel centres and\n// filtered by the sampler independently; d is renormalised after the interpolation.\nUsdahdAhdClassic usdahd_ahd_classic_filtered(vec3 ca, vec3 d, vec3 cd) {\n    return UsdahdAhdClassic(ca, d * inversesqrt(max(dot(d, d), 1e-30)), cd);\n}\n\n// The same parameters shaded with HHD's hemispherical ambient (an hhd bake imported that way).\nvec3 usdahd_hhd_classic_evaluate(UsdahdAhdClassic p, vec3 n) {\n    return 0.5 * (1.0 + n.z) * p.ca + max(dot(n, p.d), 0.0) * p.cd;\n}\n",
  ambient_cube: "// Ambient cube (GLSL): coefficients0..5 = faces +x, -x, +y, -y, +z, -z ->\n// I(n) = n_x^2 c[x face] + n_y^2 c[y face] + n_z^2 c[z face] (the -face for a negative component).\n\nstruct UsdahdAmbientCube {\n    vec3 c[6];\n};\n\nUsdahdAmbientCube usdahd_ambient_cube_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 c4,\n                                             vec3 c5, float coefficients_scale) {\n    float s = coefficients_scale;\n    UsdahdAmbientCube p;\n    p.c[0] = c0 * s;\n    p.c[1] = c1 * s;\n    p.c[2] = c2 * s;\n    p.c[3] = c3 * s;\n    p.c[4] = c4 * s;\n    p.c[5] = c5 * s;\n    return p;\n}\n\nvec3 usdahd_ambient_cube_evaluate(UsdahdAmbientCube p, vec3 n) {\n    vec3 n2 = n * n;\n    vec3 cx = n.x < 0.0 ? p.c[1] : p.c[0];\n    vec3 cy = n.y < 0.0 ? p.c[3] : p.c[2];\n    vec3 cz = n.z < 0.0 ? p.c[5] : p.c[4];\n    return n2.x * cx + n2.y * cy + n2.z * cz;\n}\n",
  hemisphere: "// Hemisphere (GLSL): texture ambient -> C -> I(n) = C (1 + n_z) / 2.\n\nstruct UsdahdHemisphere {\n    vec3 c;\n};\n\nUsdahdHemisphere usdahd_hemisphere_decode(vec3 ambient, float ambient_scale) {\n    return UsdahdHemisphere(ambient * ambient_scale);\n}\n\nvec3 usdahd_hemisphere_evaluate(UsdahdHemisphere p, vec3 n) {\n    return p.c * (0.5 * (1.0 + n.z));\n}\n",
  hl2: "// Half-Life 2 basis (GLSL): coefficients0..2 along b_0, b_1, b_2 ->\n// I(n) = sum_k w_k c_k / sum_k w_k, w_k = saturate(n . b_k)^2.\n\nstruct UsdahdHl2 {\n    vec3 c[3];\n};\n\nUsdahdHl2 usdahd_hl2_decode(vec3 c0, vec3 c1, vec3 c2, float coefficients_scale) {\n    float s = coefficients_scale;\n    UsdahdHl2 p;\n    p.c[0] = c0 * s;\n    p.c[1] = c1 * s;\n    p.c[2] = c2 * s;\n    return p;\n}\n\nvec3 usdahd_hl2_evaluate(UsdahdHl2 p, vec3 n) {\n    const vec3 b0 = vec3(0.8164965809, 0.0, 0.5773502692);\n    const vec3 b1 = vec3(-0.4082482905, 0.7071067812, 0.5773502692);\n    const vec3 b2 = vec3(-0.4082482905, -0.7071067812, 0.5773502692);\n    vec3 w = clamp(vec3(dot(n, b0), dot(n, b1), dot(n, b2)), 0.0, 1.0);\n    w = w * w;\n    float sw = w.x + w.y + w.z;\n    if (sw <= 0.0) {\n        return vec3(0.0);\n    }\n    return (w.x * p.c[0] + w.y * p.c[1] + w.z * p.c[2]) / sw;\n}\n",
  irradz: "// IrradZ models ahd, hhd, hlsh (GLSL): textures iz, direction[, ratio] -> (I_z, d, w_a) -> I(n).\n// rgb_ratio: ahdLightmap:baked:ratio is \"rgb\" (w_a from the ratio texture; else direction.B).\n\nstruct UsdahdIrradZ {\n    vec3 iz; // I_z, RGB\n    vec3 d; // unit direction, tangent space\n    vec3 wa; // ambient ratio w_a per channel (one value thrice for \"luminance\")\n};\n\nUsdahdIrradZ usdahd_irradz_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,\n                                  float ratio_scale, bool rgb_ratio, bool signed_ratio) {\n    vec3 q = rgb_ratio ? ratio : vec3(direction.z);\n    vec3 wa = signed_ratio ? usdahd_snorm8b3(q) * ratio_scale : q; // snorm8b or unorm8\n    return UsdahdIrradZ(iz * iz_scale, usdahd_hemioct_decode(direction.xy), wa);\n}\n\nUsdahdIrradZ usdahd_ahd_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,\n                               bool rgb_ratio) {\n    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);\n}\n\nUsdahdIrradZ usdahd_hhd_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,\n                               bool rgb_ratio) {\n    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);\n}\n\nUsdahdIrradZ usdahd_hlsh_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,\n                                float ratio_scale, bool rgb_ratio) {\n    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, ratio_scale, rgb_ratio, true);\n}\n\n// C_a = w_a I_z, C_d = I_z (1 - w_a) / d_z.\nvec3 usdahd_irradz_ambient(UsdahdIrradZ p) {\n    return p.wa * p.iz;\n}\n\nvec3 usdahd_irradz_directional(UsdahdIrradZ p) {\n    return p.iz * (1.0 - p.wa) / max(p.d.z, USDAHD_DZ_MIN);\n}\n\nvec3 usdahd_ahd_evaluate(UsdahdIrradZ p, vec3 n) {\n    return usdahd_irradz_ambient(p) + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);\n}\n\nvec3 usdahd_hhd_evaluate(UsdahdIrradZ p, vec3 n) {\n    return 0.5 * (1.0 + n.z) * usdahd_irradz_ambient(p)\n        + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);\n}\n\nvec3 usdahd_hlsh_evaluate(UsdahdIrradZ p, vec3 n) {\n    return usdahd_irradz_ambient(p) + dot(n, p.d) * usdahd_irradz_directional(p);\n}\n",
  sh_l1: "// L1 SH (GLSL), variants linear / nonlinear (float16 coefficients0..3) and 8bit (Enlighten's\n// compressed L1: one RGBA UNORM8 texture per colour). c[k] = radiance SH l_k (Y00, Y1-1, Y10,\n// Y11) x RGB, tangent space.\n\nstruct UsdahdShL1 {\n    vec3 c[4];\n};\n\nUsdahdShL1 usdahd_sh_l1_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, float coefficients_scale) {\n    float s = coefficients_scale;\n    UsdahdShL1 p;\n    p.c[0] = c0 * s;\n    p.c[1] = c1 * s;\n    p.c[2] = c2 * s;\n    p.c[3] = c3 * s;\n    return p;\n}\n\n// 8bit: r, g, b = the RGBA samples of coefficients0, 1, 2 (codes L0, L1x, L1y, L1z per colour).\nUsdahdShL1 usdahd_sh_l1_decode_8bit(vec4 r, vec4 g, vec4 b, float l0_scale) {\n    vec3 t0 = vec3(r.x, g.x, b.x);\n    vec3 l0 = l0_scale * t0 * t0; // L0 = l0Scale (q/255)^2\n    vec3 k = l0 / 127.0;\n    vec3 l1x = (255.0 * vec3(r.y, g.y, b.y) - 127.0) * k; // L1_i = (q - 127)/127 L0\n    vec3 l1y = (255.0 * vec3(r.z, g.z, b.z) - 127.0) * k;\n    vec3 l1z = (255.0 * vec3(r.w, g.w, b.w) - 127.0) * k;\n    float s = 6.1399602477; // 2 sqrt(3 pi): Enlighten L1 -> our band-1 SH\n    UsdahdShL1 p;\n    p.c[0] = l0 / USDAHD_SH_C0;\n    p.c[1] = -s * l1y;\n    p.c[2] = s * l1z;\n    p.c[3] = -s * l1x;\n    return p;\n}\n\n// Linear: I = sum_k A_k l_k Y_k(n), A = (1, 2/3).\nvec3 usdahd_sh_l1_evaluate(UsdahdShL1 p, vec3 n) {\n    float a1 = USDAHD_SH_C1 * (2.0 / 3.0);\n    return USDAHD_SH_C0 * p.c[0] + a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);\n}\n\n// Geomerics' non-linear reconstruction of one colour channel (Enlighten).\nfloat usdahd_nonlinear_l1(float l0, vec3 l1, vec3 n) {\n    if (l0 <= 0.0) {\n        return 0.0;\n    }\n    float m = length(l1);\n    if (m <= 0.0) {\n        return l0;\n    }\n    float r = m / l0;\n    float q = clamp(0.5 + 0.5 * dot(n, l1) / m, 0.0, 1.0);\n    float pw = 1.0 + 2.0 * r;\n    float a = (1.0 - r) / (1.0 + r);\n    return max(l0 * ((1.0 - a) * (1.0 + pw) * pow(q, pw) + a), 0.0);\n}\n\nvec3 usdahd_sh_l1_evaluate_nonlinear(UsdahdShL1 p, vec3 n) {\n    vec3 l0 = USDAHD_SH_C0 * p.c[0]; // L0 = l_0 / (2 sqrt(pi))\n    float s = 0.1628675040; // 1 / (2 sqrt(3 pi))\n    vec3 lx = -s * p.c[3];\n    vec3 ly = -s * p.c[1];\n    vec3 lz = s * p.c[2];\n    return vec3(usdahd_nonlinear_l1(l0.x, vec3(lx.x, ly.x, lz.x), n),\n                usdahd_nonlinear_l1(l0.y, vec3(lx.y, ly.y, lz.y), n),\n                usdahd_nonlinear_l1(l0.z, vec3(lx.z, ly.z, lz.z), n));\n}\n",
  sh_l2: "// L2 SH (GLSL): coefficients0..8 -> radiance SH l_k (Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21,\n// Y22) x RGB -> I(n) = sum_k A_k l_k Y_k(n), A = (1, 2/3, 1/4).\n\nstruct UsdahdShL2 {\n    vec3 c[9];\n};\n\nUsdahdShL2 usdahd_sh_l2_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 c4, vec3 c5, vec3 c6,\n                               vec3 c7, vec3 c8, float coefficients_scale) {\n    float s = coefficients_scale;\n    UsdahdShL2 p;\n    p.c[0] = c0 * s;\n    p.c[1] = c1 * s;\n    p.c[2] = c2 * s;\n    p.c[3] = c3 * s;\n    p.c[4] = c4 * s;\n    p.c[5] = c5 * s;\n    p.c[6] = c6 * s;\n    p.c[7] = c7 * s;\n    p.c[8] = c8 * s;\n    return p;\n}\n\nvec3 usdahd_sh_l2_evaluate(UsdahdShL2 p, vec3 n) {\n    float a1 = USDAHD_SH_C1 * (2.0 / 3.0);\n    float a2 = 0.25;\n    vec3 e = USDAHD_SH_C0 * p.c[0];\n    e += a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);\n    e += (a2 * USDAHD_SH_C2) * (p.c[4] * (n.x * n.y) - p.c[5] * (n.y * n.z) - p.c[7] * (n.x * n.z));\n    e += (a2 * USDAHD_SH_C20) * p.c[6] * (3.0 * n.z * n.z - 1.0);\n    e += (a2 * USDAHD_SH_C22) * p.c[8] * (n.x * n.x - n.y * n.y);\n    return e;\n}\n",
};
// END generated
