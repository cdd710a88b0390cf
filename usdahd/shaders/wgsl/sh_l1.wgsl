// L1 SH (WGSL), variants linear / nonlinear (float16 coefficients0..3) and 8bit (Enlighten's
// compressed L1: one RGBA UNORM8 texture per colour). c[k] = radiance SH l_k (Y00, Y1-1, Y10,
// Y11) x RGB, tangent space.

struct UsdahdShL1 {
    c: array<vec3<f32>, 4>,
}

fn usdahd_sh_l1_decode(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, c3: vec3<f32>,
                       coefficients_scale: f32) -> UsdahdShL1 {
    let s = coefficients_scale;
    return UsdahdShL1(array<vec3<f32>, 4>(c0 * s, c1 * s, c2 * s, c3 * s));
}

// 8bit: r, g, b = the RGBA samples of coefficients0, 1, 2 (codes L0, L1x, L1y, L1z per colour).
fn usdahd_sh_l1_decode_8bit(r: vec4<f32>, g: vec4<f32>, b: vec4<f32>, l0_scale: f32)
    -> UsdahdShL1 {
    let t0 = vec3<f32>(r.x, g.x, b.x);
    let l0 = l0_scale * t0 * t0; // L0 = l0Scale (q/255)^2
    let k = l0 / 127.0;
    let l1x = (255.0 * vec3<f32>(r.y, g.y, b.y) - 127.0) * k; // L1_i = (q - 127)/127 L0
    let l1y = (255.0 * vec3<f32>(r.z, g.z, b.z) - 127.0) * k;
    let l1z = (255.0 * vec3<f32>(r.w, g.w, b.w) - 127.0) * k;
    let s = 6.1399602477; // 2 sqrt(3 pi): Enlighten L1 -> our band-1 SH
    return UsdahdShL1(array<vec3<f32>, 4>(l0 / USDAHD_SH_C0, -s * l1y, s * l1z, -s * l1x));
}

// Linear: I = sum_k A_k l_k Y_k(n), A = (1, 2/3).
fn usdahd_sh_l1_evaluate(p: UsdahdShL1, n: vec3<f32>) -> vec3<f32> {
    let a1 = USDAHD_SH_C1 * (2.0 / 3.0);
    return USDAHD_SH_C0 * p.c[0] + a1 * (p.c[2] * n.z - p.c[1] * n.y - p.c[3] * n.x);
}

// Geomerics' non-linear reconstruction of one colour channel (Enlighten).
fn usdahd_nonlinear_l1(l0: f32, l1: vec3<f32>, n: vec3<f32>) -> f32 {
    if l0 <= 0.0 {
        return 0.0;
    }
    let m = length(l1);
    if m <= 0.0 {
        return l0;
    }
    let r = m / l0;
    let q = clamp(0.5 + 0.5 * dot(n, l1) / m, 0.0, 1.0);
    let pw = 1.0 + 2.0 * r;
    let a = (1.0 - r) / (1.0 + r);
    return max(l0 * ((1.0 - a) * (1.0 + pw) * pow(q, pw) + a), 0.0);
}

fn usdahd_sh_l1_evaluate_nonlinear(p: UsdahdShL1, n: vec3<f32>) -> vec3<f32> {
    let l0 = USDAHD_SH_C0 * p.c[0]; // L0 = l_0 / (2 sqrt(pi))
    let s = 0.1628675040; // 1 / (2 sqrt(3 pi))
    let lx = -s * p.c[3];
    let ly = -s * p.c[1];
    let lz = s * p.c[2];
    return vec3<f32>(
        usdahd_nonlinear_l1(l0.x, vec3<f32>(lx.x, ly.x, lz.x), n),
        usdahd_nonlinear_l1(l0.y, vec3<f32>(lx.y, ly.y, lz.y), n),
        usdahd_nonlinear_l1(l0.z, vec3<f32>(lx.z, ly.z, lz.z), n),
    );
}
