// L1 SH (GLSL), variants linear / nonlinear (float16 coefficients0..3) and 8bit (Enlighten's
// compressed L1: one RGBA UNORM8 texture per colour). c[k] = radiance SH l_k (Y00, Y1-1, Y10,
// Y11) x RGB, tangent space.

struct UsdahdShL1 {
    vec3 c[4];
};

UsdahdShL1 usdahd_sh_l1_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdShL1 p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    p.c[3] = c3 * s;
    return p;
}

// 8bit: r, g, b = the RGBA samples of coefficients0, 1, 2 (codes L0, L1x, L1y, L1z per colour).
UsdahdShL1 usdahd_sh_l1_decode_8bit(vec4 r, vec4 g, vec4 b, float l0_scale) {
    vec3 t0 = vec3(r.x, g.x, b.x);
    vec3 l0 = l0_scale * t0 * t0; // L0 = l0Scale (q/255)^2
    vec3 k = l0 / 127.0;
    vec3 l1x = (255.0 * vec3(r.y, g.y, b.y) - 127.0) * k; // L1_i = (q - 127)/127 L0
    vec3 l1y = (255.0 * vec3(r.z, g.z, b.z) - 127.0) * k;
    vec3 l1z = (255.0 * vec3(r.w, g.w, b.w) - 127.0) * k;
    float s = 6.1399602477; // 2 sqrt(3 pi): Enlighten L1 -> our band-1 SH
    UsdahdShL1 p;
    p.c[0] = l0 / USDAHD_SH_C0;
    p.c[1] = -s * l1y;
    p.c[2] = s * l1z;
    p.c[3] = -s * l1x;
    return p;
}

// Linear: I = sum_k A_k l_k Y_k(n), A = (1, 2/3).
vec3 usdahd_sh_l1_evaluate(UsdahdShL1 p, vec3 n) {
    float a1 = USDAHD_SH_C1 * (2.0 / 3.0);
    return USDAHD_SH_C0 * p.c[0] + a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);
}

// Geomerics' non-linear reconstruction of one colour channel (Enlighten).
float usdahd_nonlinear_l1(float l0, vec3 l1, vec3 n) {
    if (l0 <= 0.0) {
        return 0.0;
    }
    float m = length(l1);
    if (m <= 0.0) {
        return l0;
    }
    float r = m / l0;
    float q = clamp(0.5 + 0.5 * dot(n, l1) / m, 0.0, 1.0);
    float pw = 1.0 + 2.0 * r;
    float a = (1.0 - r) / (1.0 + r);
    return max(l0 * ((1.0 - a) * (1.0 + pw) * pow(q, pw) + a), 0.0);
}

vec3 usdahd_sh_l1_evaluate_nonlinear(UsdahdShL1 p, vec3 n) {
    vec3 l0 = USDAHD_SH_C0 * p.c[0]; // L0 = l_0 / (2 sqrt(pi))
    float s = 0.1628675040; // 1 / (2 sqrt(3 pi))
    vec3 lx = -s * p.c[3];
    vec3 ly = -s * p.c[1];
    vec3 lz = s * p.c[2];
    return vec3(usdahd_nonlinear_l1(l0.x, vec3(lx.x, ly.x, lz.x), n),
                usdahd_nonlinear_l1(l0.y, vec3(lx.y, ly.y, lz.y), n),
                usdahd_nonlinear_l1(l0.z, vec3(lx.z, ly.z, lz.z), n));
}
