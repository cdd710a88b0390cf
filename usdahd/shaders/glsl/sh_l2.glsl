// L2 SH (GLSL): coefficients0..8 -> radiance SH l_k (Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21,
// Y22) x RGB -> I(n) = sum_k A_k l_k Y_k(n), A = (1, 2/3, 1/4).

struct UsdahdShL2 {
    vec3 c[9];
};

UsdahdShL2 usdahd_sh_l2_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 c4, vec3 c5, vec3 c6,
                               vec3 c7, vec3 c8, float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdShL2 p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    p.c[3] = c3 * s;
    p.c[4] = c4 * s;
    p.c[5] = c5 * s;
    p.c[6] = c6 * s;
    p.c[7] = c7 * s;
    p.c[8] = c8 * s;
    return p;
}

vec3 usdahd_sh_l2_evaluate(UsdahdShL2 p, vec3 n) {
    float a1 = USDAHD_SH_C1 * (2.0 / 3.0);
    float a2 = 0.25;
    vec3 e = USDAHD_SH_C0 * p.c[0];
    e += a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);
    e += (a2 * USDAHD_SH_C2) * (p.c[4] * (n.x * n.y) - p.c[5] * (n.y * n.z) - p.c[7] * (n.x * n.z));
    e += (a2 * USDAHD_SH_C20) * p.c[6] * (3.0 * n.z * n.z - 1.0);
    e += (a2 * USDAHD_SH_C22) * p.c[8] * (n.x * n.x - n.y * n.y);
    return e;
}
