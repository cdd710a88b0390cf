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
