// Classic AHD (GLSL): textures ambient, direction, directional -> (C_a, d, C_d) -> I(n).

struct UsdahdAhdClassic {
    vec3 ca;
    vec3 d;
    vec3 cd;
};

UsdahdAhdClassic usdahd_ahd_classic_decode(vec3 ambient, vec3 direction, vec3 directional,
                                           float ambient_scale, float directional_scale) {
    return UsdahdAhdClassic(ambient * ambient_scale, usdahd_hemioct_decode(direction.xy),
                            directional * directional_scale);
}

vec3 usdahd_ahd_classic_evaluate(UsdahdAhdClassic p, vec3 n) {
    return p.ca + max(dot(n, p.d), 0.0) * p.cd;
}

// The naive engine import of an AHD bake (2018 Sec. 2, Fig. 2; `usdahd preview --ahd-classic`):
// C_a, d (unit vector, tangent space) and C_d stored as float textures at the texel centres and
// filtered by the sampler independently; d is renormalised after the interpolation.
UsdahdAhdClassic usdahd_ahd_classic_filtered(vec3 ca, vec3 d, vec3 cd) {
    return UsdahdAhdClassic(ca, d * inversesqrt(max(dot(d, d), 1e-30)), cd);
}

// The same parameters shaded with HHD's hemispherical ambient (an hhd bake imported that way).
vec3 usdahd_hhd_classic_evaluate(UsdahdAhdClassic p, vec3 n) {
    return 0.5 * (1.0 + n.z) * p.ca + max(dot(n, p.d), 0.0) * p.cd;
}
