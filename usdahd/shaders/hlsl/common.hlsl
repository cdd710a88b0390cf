// usdahd reference decoders (HLSL), common part: channel codes, hemi-octahedral directions,
// the lightmap tangent frame, normal maps and self-bounce. Format version 2: docs/schema.md.
// Texture samples are what the GPU returns: EXR half textures as floats, 8-bit PNG textures as
// UNORM8 (t = q / 255). Filter the stored channels first, then decode. No bindings or entry
// point: #include this before the model's file.

static const float USDAHD_DZ_MIN = 0.007874016; // 1/127: the smallest d_z a direction decodes to
static const float USDAHD_SH_C0 = 0.2820947918; // 1 / (2 sqrt(pi))
static const float USDAHD_SH_C1 = 0.4886025119; // sqrt(3 / (4 pi))
static const float USDAHD_SH_C2 = 1.0925484306; // sqrt(15 / (4 pi))
static const float USDAHD_SH_C20 = 0.3153915653; // sqrt(5 / (16 pi))
static const float USDAHD_SH_C22 = 0.5462742153; // sqrt(15 / (16 pi))

// Lightmap UV (st of ahdLightmap:baked:uvPrimvar) -> texture coordinate: row 0 is v = 1.
float2 usdahd_lightmap_texcoord(float2 st) {
    return float2(st.x, 1.0 - st.y);
}

// Atlas page: a record's lightmap UV st -> texture coordinate in its page. scale_offset is
// ahdLightmap:atlas:scaleOffset (sx, sy, ox, oy): uv_page = st * (sx, sy) + (ox, oy) in USD's
// v-up convention, (1, 1, 0, 0) without an atlas (then this is usdahd_lightmap_texcoord).
float2 usdahd_page_texcoord(float2 st, float4 scale_offset) {
    return usdahd_lightmap_texcoord(st * scale_offset.xy + scale_offset.zw);
}

// The same for pages bound as one Texture2DArray (slice = ahdLightmap:atlas:page):
// pages.Sample(s, usdahd_page_texcoord_array(st, scale_offset, page)).
float3 usdahd_page_texcoord_array(float2 st, float4 scale_offset, int page) {
    return float3(usdahd_page_texcoord(st, scale_offset), (float)page);
}

// snorm8b: signed value biased into UNORM8, (q - 128) / 127 from the sample t = q / 255.
float usdahd_snorm8b(float t) {
    return max((255.0 * t - 128.0) / 127.0, -1.0);
}

float3 usdahd_snorm8b3(float3 t) {
    return max((255.0 * t - 128.0) / 127.0, float3(-1.0, -1.0, -1.0));
}

// Hemi-octahedral direction (tangent space, d_z > 0) from the R, G samples of `direction`.
float3 usdahd_hemioct_decode(float2 rg) {
    float u = usdahd_snorm8b(rg.x);
    float v = usdahd_snorm8b(rg.y);
    float px = 0.5 * (u + v);
    float py = 0.5 * (u - v);
    return normalize(float3(px, py, 1.0 - abs(px) - abs(py)));
}

// Tangent frame (rows t, b, n) of tangentFrame = "mikktspace_uv": n the interpolated shading
// normal, tangent.xyz the interpolated MikkTSpace tangent of the lightmap UV set, tangent.w its
// sign. Gram-Schmidt, then b = sign * cross(n, t).
struct UsdahdFrame {
    float3 t;
    float3 b;
    float3 n;
};

UsdahdFrame usdahd_tangent_frame(float3 normal, float4 tangent) {
    UsdahdFrame f;
    f.n = normalize(normal);
    f.t = normalize(tangent.xyz - f.n * dot(f.n, tangent.xyz));
    f.b = tangent.w * cross(f.n, f.t);
    return f;
}

// A vector (e.g. the world-space shading normal) in the frame: (v.t, v.b, v.n).
float3 usdahd_to_tangent(UsdahdFrame f, float3 v) {
    return float3(dot(v, f.t), dot(v, f.b), dot(v, f.n));
}

// A tangent-space normal map texel (UNORM RGB, 2 t - 1) in the *material's* tangent frame
// (its own UV set) -> unit shading normal in the space of that frame.
float3 usdahd_apply_normal_map(float3 texel, UsdahdFrame material) {
    float3 m = 2.0 * texel - 1.0;
    return normalize(m.x * material.t + m.y * material.b + m.z * material.n);
}

// Self-bounce of 2024 App. A: albedo * I_z * (1 - n_z) / 2 (I_z: the model's I at n = z).
float3 usdahd_self_bounce(float3 iz, float3 n, float3 albedo) {
    return albedo * iz * (0.5 * (1.0 - n.z));
}
