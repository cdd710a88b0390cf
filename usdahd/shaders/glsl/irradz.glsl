// IrradZ models ahd, hhd, hlsh (GLSL): textures iz, direction[, ratio] -> (I_z, d, w_a) -> I(n).
// rgb_ratio: ahdLightmap:baked:ratio is "rgb" (w_a from the ratio texture; else direction.B).

struct UsdahdIrradZ {
    vec3 iz; // I_z, RGB
    vec3 d; // unit direction, tangent space
    vec3 wa; // ambient ratio w_a per channel (one value thrice for "luminance")
};

UsdahdIrradZ usdahd_irradz_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,
                                  float ratio_scale, bool rgb_ratio, bool signed_ratio) {
    vec3 q = rgb_ratio ? ratio : vec3(direction.z);
    vec3 wa = signed_ratio ? usdahd_snorm8b3(q) * ratio_scale : q; // snorm8b or unorm8
    return UsdahdIrradZ(iz * iz_scale, usdahd_hemioct_decode(direction.xy), wa);
}

UsdahdIrradZ usdahd_ahd_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,
                               bool rgb_ratio) {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);
}

UsdahdIrradZ usdahd_hhd_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,
                               bool rgb_ratio) {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, 1.0, rgb_ratio, false);
}

UsdahdIrradZ usdahd_hlsh_decode(vec3 iz, vec3 direction, vec3 ratio, float iz_scale,
                                float ratio_scale, bool rgb_ratio) {
    return usdahd_irradz_decode(iz, direction, ratio, iz_scale, ratio_scale, rgb_ratio, true);
}

// C_a = w_a I_z, C_d = I_z (1 - w_a) / d_z.
vec3 usdahd_irradz_ambient(UsdahdIrradZ p) {
    return p.wa * p.iz;
}

vec3 usdahd_irradz_directional(UsdahdIrradZ p) {
    return p.iz * (1.0 - p.wa) / max(p.d.z, USDAHD_DZ_MIN);
}

vec3 usdahd_ahd_evaluate(UsdahdIrradZ p, vec3 n) {
    return usdahd_irradz_ambient(p) + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);
}

vec3 usdahd_hhd_evaluate(UsdahdIrradZ p, vec3 n) {
    return 0.5 * (1.0 + n.z) * usdahd_irradz_ambient(p)
        + max(dot(n, p.d), 0.0) * usdahd_irradz_directional(p);
}

vec3 usdahd_hlsh_evaluate(UsdahdIrradZ p, vec3 n) {
    return usdahd_irradz_ambient(p) + dot(n, p.d) * usdahd_irradz_directional(p);
}
