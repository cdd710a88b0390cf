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
