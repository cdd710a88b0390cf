// IrradZ models ahd, hhd, hlsh (WGSL): textures iz, direction[, ratio] -> (I_z, d, w_a) -> I(n).
// rgb_ratio: ahdLightmap:baked:ratio is "rgb" (w_a from the ratio texture; else direction.B).

struct UsdahdIrradZ {
    iz: vec3<f32>, // I_z, RGB
    d: vec3<f32>, // unit direction, tangent space
    wa: vec3<f32>, // ambient ratio w_a per channel (one value thrice for "luminance")
}

fn usdahd_irradz_decode(
    iz: vec3<f32>, direction: vec3<f32>, ratio: vec3<f32>, iz_scale: f32, ratio_scale: f32,
    rgb_ratio: bool, signed_ratio: bool
) -> UsdahdIrradZ {
    var q = vec3<f32>(direction.z);
    if rgb_ratio {
        q = ratio;
    }
    var wa = q; // unorm8
    if signed_ratio {
        wa = usdahd_snorm8b3(q) * ratio_scale;
    }
    return UsdahdIrradZ(iz * iz_scale, usdahd_hemioct_decode(direction.xy), wa);
}

fn usdahd_ahd_decode(iz: vec3<f32>, direction: vec3<f32>, ratio: vec3<f32>, iz_scale: f32,
                     rgb_ratio: bool) -> UsdahdIrradZ {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);
}

fn usdahd_hhd_decode(iz: vec3<f32>, direction: vec3<f32>, ratio: vec3<f32>, iz_scale: f32,
                     rgb_ratio: bool) -> UsdahdIrradZ {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);
}

fn usdahd_hlsh_decode(iz: vec3<f32>, direction: vec3<f32>, ratio: vec3<f32>, iz_scale: f32,
                      ratio_scale: f32, rgb_ratio: bool) -> UsdahdIrradZ {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, ratio_scale, rgb_ratio, true);
}

// C_a = w_a I_z, C_d = I_z (1 - w_a) / d_z.
fn usdahd_irradz_ambient(p: UsdahdIrradZ) -> vec3<f32> {
    return p.wa * p.iz;
}

fn usdahd_irradz_directional(p: UsdahdIrradZ) -> vec3<f32> {
    return p.iz * (1.0 - p.wa) / max(p.d.z, USDAHD_DZ_MIN);
}

fn usdahd_ahd_evaluate(p: UsdahdIrradZ, n: vec3<f32>) -> vec3<f32> {
    return usdahd_irradz_ambient(p) + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);
}

fn usdahd_hhd_evaluate(p: UsdahdIrradZ, n: vec3<f32>) -> vec3<f32> {
    return 0.5 * (1.0 + n.z) * usdahd_irradz_ambient(p)
        + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);
}

fn usdahd_hlsh_evaluate(p: UsdahdIrradZ, n: vec3<f32>) -> vec3<f32> {
    return usdahd_irradz_ambient(p) + dot(n, p.d) * usdahd_irradz_directional(p);
}
