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
