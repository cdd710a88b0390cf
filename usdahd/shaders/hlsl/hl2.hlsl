// Half-Life 2 basis (HLSL): coefficients0..2 along b_0, b_1, b_2 ->
// I(n) = sum_k w_k c_k / sum_k w_k, w_k = saturate(n . b_k)^2.

struct UsdahdHl2 {
    float3 c[3];
};

UsdahdHl2 usdahd_hl2_decode(float3 c0, float3 c1, float3 c2, float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdHl2 p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    return p;
}

float3 usdahd_hl2_evaluate(UsdahdHl2 p, float3 n) {
    const float3 b0 = float3(0.8164965809, 0.0, 0.5773502692);
    const float3 b1 = float3(-0.4082482905, 0.7071067812, 0.5773502692);
    const float3 b2 = float3(-0.4082482905, -0.7071067812, 0.5773502692);
    float3 w = saturate(float3(dot(n, b0), dot(n, b1), dot(n, b2)));
    w = w * w;
    float sw = w.x + w.y + w.z;
    if (sw <= 0.0) {
        return float3(0.0, 0.0, 0.0);
    }
    return (w.x * p.c[0] + w.y * p.c[1] + w.z * p.c[2]) / sw;
}
