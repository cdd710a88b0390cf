// Hemisphere (WGSL): texture ambient -> C -> I(n) = C (1 + n_z) / 2.

struct UsdahdHemisphere {
    c: vec3<f32>,
}

fn usdahd_hemisphere_decode(ambient: vec3<f32>, ambient_scale: f32) -> UsdahdHemisphere {
    return UsdahdHemisphere(ambient * ambient_scale);
}

fn usdahd_hemisphere_evaluate(p: UsdahdHemisphere, n: vec3<f32>) -> vec3<f32> {
    return p.c * (0.5 * (1.0 + n.z));
}
