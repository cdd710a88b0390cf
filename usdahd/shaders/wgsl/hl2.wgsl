// Half-Life 2 basis (WGSL): coefficients0..2 along b_0, b_1, b_2 ->
// I(n) = sum_k w_k c_k / sum_k w_k, w_k = saturate(n . b_k)^2.

struct UsdahdHl2 {
    c: array<vec3<f32>, 3>,
}

fn usdahd_hl2_decode(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, coefficients_scale: f32)
    -> UsdahdHl2 {
    let s = coefficients_scale;
    return UsdahdHl2(array<vec3<f32>, 3>(c0 * s, c1 * s, c2 * s));
}

fn usdahd_hl2_evaluate(p: UsdahdHl2, n: vec3<f32>) -> vec3<f32> {
    let b0 = vec3<f32>(0.8164965809, 0.0, 0.5773502692);
    let b1 = vec3<f32>(-0.4082482905, 0.7071067812, 0.5773502692);
    let b2 = vec3<f32>(-0.4082482905, -0.7071067812, 0.5773502692);
    var w = clamp(vec3<f32>(dot(n, b0), dot(n, b1), dot(n, b2)), vec3<f32>(0.0), vec3<f32>(1.0));
    w = w * w;
    let sw = w.x + w.y + w.z;
    if sw <= 0.0 {
        return vec3<f32>(0.0);
    }
    return (w.x * p.c[0] + w.y * p.c[1] + w.z * p.c[2]) / sw;
}
