// Ambient cube (HLSL): coefficients0..5 = faces +x, -x, +y, -y, +z, -z ->
// I(n) = n_x^2 c[x face] + n_y^2 c[y face] + n_z^2 c[z face] (the -face for a negative component).

struct UsdahdAmbientCube {
    float3 c[6];
};

UsdahdAmbientCube usdahd_ambient_cube_decode(float3 c0, float3 c1, float3 c2, float3 c3,
                                             float3 c4, float3 c5, float coefficients_scale) {
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

float3 usdahd_ambient_cube_evaluate(UsdahdAmbientCube p, float3 n) {
    float3 n2 = n * n;
    float3 cx = n.x < 0.0 ? p.c[1] : p.c[0];
    float3 cy = n.y < 0.0 ? p.c[3] : p.c[2];
    float3 cz = n.z < 0.0 ? p.c[5] : p.c[4];
    return n2.x * cx + n2.y * cy + n2.z * cz;
}
