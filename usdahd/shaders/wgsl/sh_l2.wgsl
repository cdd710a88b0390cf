// L2 SH (WGSL): coefficients0..8 -> radiance SH l_k (Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21,
// Y22) x RGB -> I(n) = sum_k A_k l_k Y_k(n), A = (1, 2/3, 1/4).

struct UsdahdShL2 {
    c: array<vec3<f32>, 9>,
}

fn usdahd_sh_l2_decode(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, c3: vec3<f32>,
                       c4: vec3<f32>, c5: vec3<f32>, c6: vec3<f32>, c7: vec3<f32>,
                       c8: vec3<f32>, coefficients_scale: f32) -> UsdahdShL2 {
    let s = coefficients_scale;
    return UsdahdShL2(array<vec3<f32>, 9>(c0 * s, c1 * s, c2 * s, c3 * s, c4 * s, c5 * s,
                                          c6 * s, c7 * s, c8 * s));
}

fn usdahd_sh_l2_evaluate(p: UsdahdShL2, n: vec3<f32>) -> vec3<f32> {
    let a1 = USDAHD_SH_C1 * (2.0 / 3.0);
    let a2 = 0.25;
    var e = USDAHD_SH_C0 * p.c[0];
    e += a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);
    e += (a2 * USDAHD_SH_C2) * (p.c[4] * (n.x * n.y) - p.c[5] * (n.y * n.z) - p.c[7] * (n.x * n.z));
    e += (a2 * USDAHD_SH_C20) * p.c[6] * (3.0 * n.z * n.z - 1.0);
    e += (a2 * USDAHD_SH_C22) * p.c[8] * (n.x * n.x - n.y * n.y);
    return e;
}
