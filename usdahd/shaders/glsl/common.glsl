// usdahd reference decoders (GLSL), common part: channel codes, hemi-octahedral directions,
// the lightmap tangent frame, normal maps and self-bounce. Format version 2: docs/schema.md.
// Texture samples are what the GPU returns: EXR half textures as floats, 8-bit PNG textures as
// UNORM8 (t = q / 255). Filter the stored channels first, then decode. No #version, bindings
// or entry point: paste (or #include) this before the model's file.

const float USDAHD_DZ_MIN = 0.007874016; // 1/127: the smallest d_z an 8-bit direction decodes to
const float USDAHD_SH_C0 = 0.2820947918; // 1 / (2 sqrt(pi))
const float USDAHD_SH_C1 = 0.4886025119; // sqrt(3 / (4 pi))
const float USDAHD_SH_C2 = 1.0925484306; // sqrt(15 / (4 pi))
const float USDAHD_SH_C20 = 0.3153915653; // sqrt(5 / (16 pi))
const float USDAHD_SH_C22 = 0.5462742153; // sqrt(15 / (16 pi))

// Lightmap UV (st of ahdLightmap:baked:uvPrimvar) -> texture coordinate: row 0 is v = 1.
vec2 usdahd_lightmap_texcoord(vec2 st) {
    return vec2(st.x, 1.0 - st.y);
}

// Atlas page: a record's lightmap UV st -> texture coordinate in its page. scale_offset is
// ahdLightmap:atlas:scaleOffset (sx, sy, ox, oy): uv_page = st * (sx, sy) + (ox, oy) in USD's
// v-up convention, (1, 1, 0, 0) without an atlas (then this is usdahd_lightmap_texcoord).
vec2 usdahd_page_texcoord(vec2 st, vec4 scale_offset) {
    return usdahd_lightmap_texcoord(st * scale_offset.xy + scale_offset.zw);
}

// The same for pages bound as one texture array (layer = ahdLightmap:atlas:page):
// texture(sampler2DArray, usdahd_page_texcoord_array(st, scale_offset, page)).
vec3 usdahd_page_texcoord_array(vec2 st, vec4 scale_offset, int page) {
    return vec3(usdahd_page_texcoord(st, scale_offset), float(page));
}

// snorm8b: signed value biased into UNORM8, (q - 128) / 127 from the sample t = q / 255.
float usdahd_snorm8b(float t) {
    return max((255.0 * t - 128.0) / 127.0, -1.0);
}

vec3 usdahd_snorm8b3(vec3 t) {
    return max((255.0 * t - 128.0) / 127.0, vec3(-1.0));
}

// Hemi-octahedral direction (tangent space, d_z > 0) from the R, G samples of `direction`.
vec3 usdahd_hemioct_decode(vec2 rg) {
    float u = usdahd_snorm8b(rg.x);
    float v = usdahd_snorm8b(rg.y);
    float px = 0.5 * (u + v);
    float py = 0.5 * (u - v);
    return normalize(vec3(px, py, 1.0 - abs(px) - abs(py)));
}

// Tangent frame (rows t, b, n) of tangentFrame = "mikktspace_uv": n the interpolated shading
// normal, tangent.xyz the interpolated MikkTSpace tangent of the lightmap UV set, tangent.w its
// sign. Gram-Schmidt, then b = sign * cross(n, t).
struct UsdahdFrame {
    vec3 t;
    vec3 b;
    vec3 n;
};

UsdahdFrame usdahd_tangent_frame(vec3 normal, vec4 tangent) {
    vec3 n = normalize(normal);
    vec3 t = normalize(tangent.xyz - n * dot(n, tangent.xyz));
    return UsdahdFrame(t, tangent.w * cross(n, t), n);
}

// A vector (e.g. the world-space shading normal) in the frame: (v.t, v.b, v.n).
vec3 usdahd_to_tangent(UsdahdFrame f, vec3 v) {
    return vec3(dot(v, f.t), dot(v, f.b), dot(v, f.n));
}

// A tangent-space normal map texel (UNORM RGB, 2 t - 1) in the *material's* tangent frame
// (its own UV set) -> unit shading normal in the space of that frame.
vec3 usdahd_apply_normal_map(vec3 texel, UsdahdFrame material) {
    vec3 m = 2.0 * texel - 1.0;
    return normalize(m.x * material.t + m.y * material.b + m.z * material.n);
}

// Self-bounce of 2024 App. A: albedo * I_z * (1 - n_z) / 2 (I_z: the model's I at n = z).
vec3 usdahd_self_bounce(vec3 iz, vec3 n, vec3 albedo) {
    return albedo * iz * (0.5 * (1.0 - n.z));
}
