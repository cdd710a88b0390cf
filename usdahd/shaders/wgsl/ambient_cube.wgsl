// Ambient cube (WGSL): coefficients0..5 = faces +x, -x, +y, -y, +z, -z ->
// I(n) = n_x^2 c[x face] + n_y^2 c[y face] + n_z^2 c[z face] (the -face for a negative component).

struct UsdahdAmbientCube {
    c: array<vec3<f32>, 6>,
}

fn usdahd_ambient_cube_decode(c0: vec3<f32>, c1: vec3<f32>, c2: vec3<f32>, c3: vec3<f32>,
                              c4: vec3<f32>, c5: vec3<f32>, coefficients_scale: f32)
    -> UsdahdAmbientCube {
    let s = coefficients_scale;
    return UsdahdAmbientCube(array<vec3<f32>, 6>(c0 * s, c1 * s, c2 * s, c3 * s, c4 * s, c5 * s));
}

fn usdahd_ambient_cube_evaluate(p: UsdahdAmbientCube, n: vec3<f32>) -> vec3<f32> {
    let n2 = n * n;
    let cx = select(p.c[0], p.c[1], n.x < 0.0);
    let cy = select(p.c[2], p.c[3], n.y < 0.0);
    let cz = select(p.c[4], p.c[5], n.z < 0.0);
    return n2.x * cx + n2.y * cy + n2.z * cz;
}
