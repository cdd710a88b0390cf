// Hemisphere (GLSL): texture ambient -> C -> I(n) = C (1 + n_z) / 2.

struct UsdahdHemisphere {
    vec3 c;
};

UsdahdHemisphere usdahd_hemisphere_decode(vec3 ambient, float ambient_scale) {
    return UsdahdHemisphere(ambient * ambient_scale);
}

vec3 usdahd_hemisphere_evaluate(UsdahdHemisphere p, vec3 n) {
    return p.c * (0.5 * (1.0 + n.z));
}
