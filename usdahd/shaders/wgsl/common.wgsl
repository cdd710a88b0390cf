// usdahd reference decoders (WGSL), common part: channel codes, hemi-octahedral directions,
// the lightmap tangent frame, normal maps and self-bounce. Format version 2: docs/schema.md.
// Texture samples are what the GPU returns: EXR half textures as floats, 8-bit PNG textures as
// UNORM8 (t = q / 255). Filter the stored channels first, then decode.

const USDAHD_DZ_MIN: f32 = 0.007874016; // 1/127: the smallest d_z an 8-bit direction decodes to
const USDAHD_SH_C0: f32 = 0.2820947918; // 1 / (2 sqrt(pi))
const USDAHD_SH_C1: f32 = 0.4886025119; // sqrt(3 / (4 pi))
const USDAHD_SH_C2: f32 = 1.0925484306; // sqrt(15 / (4 pi))
const USDAHD_SH_C20: f32 = 0.3153915653; // sqrt(5 / (16 pi))
const USDAHD_SH_C22: f32 = 0.5462742153; // sqrt(15 / (16 pi))

// Lightmap UV (st of ahdLightmap:baked:uvPrimvar) -> texture coordinate: row 0 is v = 1.
fn usdahd_lightmap_texcoord(st: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(st.x, 1.0 - st.y);
}

// Atlas page: a record's lightmap UV st -> texture coordinate in its page. scale_offset is
// ahdLightmap:atlas:scaleOffset (sx, sy, ox, oy): uv_page = st * (sx, sy) + (ox, oy) in USD's
// v-up convention, (1, 1, 0, 0) without an atlas (then this is usdahd_lightmap_texcoord).
fn usdahd_page_texcoord(st: vec2<f32>, scale_offset: vec4<f32>) -> vec2<f32> {
    return usdahd_lightmap_texcoord(st * scale_offset.xy + scale_offset.zw);
}

// The same for pages bound as one texture_2d_array (layer = ahdLightmap:atlas:page), as
// (u, v, layer): textureSample(pages, s, c.xy, i32(c.z)).
fn usdahd_page_texcoord_array(st: vec2<f32>, scale_offset: vec4<f32>, page: i32) -> vec3<f32> {
    return vec3<f32>(usdahd_page_texcoord(st, scale_offset), f32(page));
}

// snorm8b: signed value biased into UNORM8, (q - 128) / 127 from the sample t = q / 255.
fn usdahd_snorm8b(t: f32) -> f32 {
    return max((255.0 * t - 128.0) / 127.0, -1.0);
}

fn usdahd_snorm8b3(t: vec3<f32>) -> vec3<f32> {
    return max((255.0 * t - 128.0) / 127.0, vec3<f32>(-1.0));
}

// Hemi-octahedral direction (tangent space, d_z > 0) from the R, G samples of `direction`.
fn usdahd_hemioct_decode(rg: vec2<f32>) -> vec3<f32> {
    let u = usdahd_snorm8b(rg.x);
    let v = usdahd_snorm8b(rg.y);
    let px = 0.5 * (u + v);
    let py = 0.5 * (u - v);
    return normalize(vec3<f32>(px, py, 1.0 - abs(px) - abs(py)));
}

// Tangent frame (rows t, b, n) of tangentFrame = "mikktspace_uv": n the interpolated shading
// normal, tangent.xyz the interpolated MikkTSpace tangent of the lightmap UV set, tangent.w its
// sign. Gram-Schmidt, then b = sign * cross(n, t).
struct UsdahdFrame {
    t: vec3<f32>,
    b: vec3<f32>,
    n: vec3<f32>,
}

fn usdahd_tangent_frame(normal: vec3<f32>, tangent: vec4<f32>) -> UsdahdFrame {
    let n = normalize(normal);
    let t = normalize(tangent.xyz - n * dot(n, tangent.xyz));
    return UsdahdFrame(t, tangent.w * cross(n, t), n);
}

// A vector (e.g. the world-space shading normal) in the frame: (v.t, v.b, v.n).
fn usdahd_to_tangent(f: UsdahdFrame, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, f.t), dot(v, f.b), dot(v, f.n));
}

// A tangent-space normal map texel (UNORM RGB, 2 t - 1) in the *material's* tangent frame
// (its own UV set) -> unit shading normal in the space of that frame.
fn usdahd_apply_normal_map(texel: vec3<f32>, material: UsdahdFrame) -> vec3<f32> {
    let m = 2.0 * texel - 1.0;
    return normalize(m.x * material.t + m.y * material.b + m.z * material.n);
}

// Self-bounce of 2024 App. A: albedo * I_z * (1 - n_z) / 2 (I_z: the model's I at n = z).
fn usdahd_self_bounce(iz: vec3<f32>, n: vec3<f32>, albedo: vec3<f32>) -> vec3<f32> {
    return albedo * iz * (0.5 * (1.0 - n.z));
}
