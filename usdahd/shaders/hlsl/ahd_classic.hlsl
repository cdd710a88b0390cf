// Classic AHD (HLSL): textures ambient, direction, directional -> (C_a, d, C_d) -> I(n).

struct UsdahdAhdClassic {
    float3 ca;
    float3 d;
    float3 cd;
};

UsdahdAhdClassic usdahd_ahd_classic_decode(float3 ambient, float3 direction, float3 directional,
                                           float ambient_scale, float directional_scale) {
    UsdahdAhdClassic p;
    p.ca = ambient * ambient_scale;
    p.d = usdahd_hemioct_decode(direction.xy);
    p.cd = directional * directional_scale;
    return p;
}

float3 usdahd_ahd_classic_evaluate(UsdahdAhdClassic p, float3 n) {
    return p.ca + max(dot(n, p.d), 0.0) * p.cd;
}

// The naive engine import of an AHD bake (2018 Sec. 2, Fig. 2; `usdahd preview --ahd-classic`):
// C_a, d (unit vector, tangent space) and C_d stored as float textures at the texel centres and
// filtered by the sampler independently; d is renormalised after the interpolation.
UsdahdAhdClassic usdahd_ahd_classic_filtered(float3 ca, float3 d, float3 cd) {
    UsdahdAhdClassic p;
    p.ca = ca;
    p.d = d * rsqrt(max(dot(d, d), 1e-30));
    p.cd = cd;
    return p;
}

// The same parameters shaded with HHD's hemispherical ambient (an hhd bake imported that way).
float3 usdahd_hhd_classic_evaluate(UsdahdAhdClassic p, float3 n) {
    return 0.5 * (1.0 + n.z) * p.ca + max(dot(n, p.d), 0.0) * p.cd;
}
