// L1 SH (HLSL), variants linear / nonlinear (float16 coefficients0..3) and 8bit (Enlighten's
// compressed L1: one RGBA UNORM8 texture per colour). c[k] = radiance SH l_k (Y00, Y1-1, Y10,
// Y11) x RGB, tangent space.

struct UsdahdShL1 {
    float3 c[4];
};

UsdahdShL1 usdahd_sh_l1_decode(float3 c0, float3 c1, float3 c2, float3 c3,
                               float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdShL1 p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    p.c[3] = c3 * s;
    return p;
}

// 8bit: r, g, b = the RGBA samples of coefficients0, 1, 2 (codes L0, L1x, L1y, L1z per colour).
UsdahdShL1 usdahd_sh_l1_decode_8bit(float4 r, float4 g, float4 b, float l0_scale) {
    float3 t0 = float3(r.x, g.x, b.x);
    float3 l0 = l0_scale * t0 * t0; // L0 = l0Scale (q/255)^2
    float3 k = l0 / 127.0;
    float3 l1x = (255.0 * float3(r.y, g.y, b.y) - 127.0) * k; // L1_i = (q - 127)/127 L0
    float3 l1y = (255.0 * float3(r.z, g.z, b.z) - 127.0) * k;
    float3 l1z = (255.0 * float3(r.w, g.w, b.w) - 127.0) * k;
    float s = 6.1399602477; // 2 sqrt(3 pi): Enlighten L1 -> our band-1 SH
    UsdahdShL1 p;
    p.c[0] = l0 / USDAHD_SH_C0;
    p.c[1] = -s * l1y;
    p.c[2] = s * l1z;
    p.c[3] = -s * l1x;
    return p;
}

// Linear: I = sum_k A_k l_k Y_k(n), A = (1, 2/3).
float3 usdahd_sh_l1_evaluate(UsdahdShL1 p, float3 n) {
    float a1 = USDAHD_SH_C1 * (2.0 / 3.0);
    return USDAHD_SH_C0 * p.c[0] + a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);
}

// Geomerics' non-linear reconstruction of one colour channel (Enlighten).
float usdahd_nonlinear_l1(float l0, float3 l1, float3 n) {
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

float3 usdahd_sh_l1_evaluate_nonlinear(UsdahdShL1 p, float3 n) {
    float3 l0 = USDAHD_SH_C0 * p.c[0]; // L0 = l_0 / (2 sqrt(pi))
    float s = 0.1628675040; // 1 / (2 sqrt(3 pi))
    float3 lx = -s * p.c[3];
    float3 ly = -s * p.c[1];
    float3 lz = s * p.c[2];
    return float3(usdahd_nonlinear_l1(l0.x, float3(lx.x, ly.x, lz.x), n),
                  usdahd_nonlinear_l1(l0.y, float3(lx.y, ly.y, lz.y), n),
                  usdahd_nonlinear_l1(l0.z, float3(lx.z, ly.z, lz.z), n));
}
