// Half-Life 2 basis (GLSL): coefficients0..2 along b_0, b_1, b_2 ->
// I(n) = sum_k w_k c_k / sum_k w_k, w_k = saturate(n . b_k)^2.

struct UsdahdHl2 {
    vec3 c[3];
};

UsdahdHl2 usdahd_hl2_decode(vec3 c0, vec3 c1, vec3 c2, float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdHl2 p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    return p;
}

vec3 usdahd_hl2_evaluate(UsdahdHl2 p, vec3 n) {
    const vec3 b0 = vec3(0.8164965809, 0.0, 0.5773502692);
    const vec3 b1 = vec3(-0.4082482905, 0.7071067812, 0.5773502692);
    const vec3 b2 = vec3(-0.4082482905, -0.7071067812, 0.5773502692);
    vec3 w = clamp(vec3(dot(n, b0), dot(n, b1), dot(n, b2)), 0.0, 1.0);
    w = w * w;
    float sw = w.x + w.y + w.z;
    if (sw <= 0.0) {
        return vec3(0.0);
    }
    return (w.x * p.c[0] + w.y * p.c[1] + w.z * p.c[2]) / sw;
}
