// Hemisphere (HLSL): texture ambient -> C -> I(n) = C (1 + n_z) / 2.

struct UsdahdHemisphere {
    float3 c;
};

UsdahdHemisphere usdahd_hemisphere_decode(float3 ambient, float ambient_scale) {
    UsdahdHemisphere p;
    p.c = ambient * ambient_scale;
    return p;
}

float3 usdahd_hemisphere_evaluate(UsdahdHemisphere p, float3 n) {
    return p.c * (0.5 * (1.0 + n.z));
}
