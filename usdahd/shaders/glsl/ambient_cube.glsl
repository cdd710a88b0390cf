// Ambient cube (GLSL): coefficients0..5 = faces +x, -x, +y, -y, +z, -z ->
// I(n) = n_x^2 c[x face] + n_y^2 c[y face] + n_z^2 c[z face] (the -face for a negative component).

struct UsdahdAmbientCube {
    vec3 c[6];
};

UsdahdAmbientCube usdahd_ambient_cube_decode(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 c4,
                                             vec3 c5, float coefficients_scale) {
    float s = coefficients_scale;
    UsdahdAmbientCube p;
    p.c[0] = c0 * s;
    p.c[1] = c1 * s;
    p.c[2] = c2 * s;
    p.c[3] = c3 * s;
    p.c[4] = c4 * s;
    p.c[5] = c5 * s;
    return p;
}

vec3 usdahd_ambient_cube_evaluate(UsdahdAmbientCube p, vec3 n) {
    vec3 n2 = n * n;
    vec3 cx = n.x < 0.0 ? p.c[1] : p.c[0];
    vec3 cy = n.y < 0.0 ? p.c[3] : p.c[2];
    vec3 cz = n.z < 0.0 ? p.c[5] : p.c[4];
    return n2.x * cx + n2.y * cy + n2.z * cz;
}
