// Classic AHD (WGSL): textures ambient, direction, directional -> (C_a, d, C_d) -> I(n).

struct UsdahdAhdClassic {
    ca: vec3<f32>,
    d: vec3<f32>,
    cd: vec3<f32>,
}

fn usdahd_ahd_classic_decode(ambient: vec3<f32>, direction: vec3<f32>, directional: vec3<f32>,
                             ambient_scale: f32, directional_scale: f32) -> UsdahdAhdClassic {
    return UsdahdAhdClassic(ambient * ambient_scale, usdahd_hemioct_decode(direction.xy),
                            directional * directional_scale);
}

fn usdahd_ahd_classic_evaluate(p: UsdahdAhdClassic, n: vec3<f32>) -> vec3<f32> {
    return p.ca + max(dot(n, p.d), 0.0) * p.cd;
}

// The naive engine import of an AHD bake (2018 Sec. 2, Fig. 2; `usdahd preview --ahd-classic`):
// C_a, d (unit vector, tangent space) and C_d stored as float textures at the texel centres and
// filtered by the sampler independently; d is renormalised after the interpolation.
fn usdahd_ahd_classic_filtered(ca: vec3<f32>, d: vec3<f32>, cd: vec3<f32>) -> UsdahdAhdClassic {
    return UsdahdAhdClassic(ca, d * inverseSqrt(max(dot(d, d), 1e-30)), cd);
}

// The same parameters shaded with HHD's hemispherical ambient (an hhd bake imported that way).
fn usdahd_hhd_classic_evaluate(p: UsdahdAhdClassic, n: vec3<f32>) -> vec3<f32> {
    return 0.5 * (1.0 + n.z) * p.ca + max(dot(n, p.d), 0.0) * p.cd;
}
