// Splat fragment shader: a Gaussian footprint of one point, premultiplied colour.
// Composite: the footprint w(r) = (2 / pi) exp(-r^2 / (2 sigma^2)) (sigma = h / 2) integrates to
// h^2 over the image plane, so a layer of splats on a lattice of spacing h sums to about 1; each
// fragment's opacity is the transfer function's opacity corrected for a path of w(r) * h / unit:
// alpha = 1 - (1 - a)^(w h / unit), so overlapping splats of one layer multiply to the opacity of a
// path of length h. Blended back to front with (ONE, ONE_MINUS_SRC_ALPHA).
// Lighting (u_shading): the colour becomes min(rgb (ambient + diffuse d) + specular d^shininess, 1),
// d = |g . v| / |g| from the point's gradient (Meredith & Ma section 3.2, estimated by weighted least
// squares over its node's points), as the volume's SHADING variant; opacity is unchanged.
// MIP: the splat's core (r <= 1.5 sigma) writes its normalised value with the MAX blend equation.
#version 330

in float v_t;
in float v_sigma_px;
in float v_size_px;
in float v_h;
in float v_d;

uniform sampler2D u_tf;      // (n, 1) RGBA transfer function, GL_LINEAR, texel centres at (i + 0.5) / n
uniform float u_unit;        // world length the transfer function's opacity is defined for
uniform int u_mip;
uniform int u_shading;
uniform vec4 u_light;        // ambient, diffuse, specular, shininess

out vec4 frag;

float expm1_approx(float x) {  // exp(x) - 1, accurate near x = 0
    return (abs(x) < 1e-4) ? (x + 0.5 * x * x) : (exp(x) - 1.0);
}

float log1m(float a) {  // log(1 - a), accurate near a = 0
    return (a < 1e-4) ? (-a - 0.5 * a * a) : log(max(1.0 - a, 1e-30));
}

void main() {
    vec2 d = (gl_PointCoord - 0.5) * v_size_px;
    float r2 = dot(d, d) / (v_sigma_px * v_sigma_px);
    if (r2 > 9.0) discard;
    if (u_mip == 1) {
        if (r2 > 2.25) discard;  // the core, r <= 1.5 sigma = 0.75 h: covers a lattice of spacing h without gaps
        frag = vec4(clamp(v_t, 0.0, 1.0), 0.0, 0.0, 1.0);
        return;
    }
    vec4 c = texture(u_tf, vec2(clamp(v_t, 0.0, 1.0), 0.5));
    if (u_shading == 1) {
        c.rgb = min(c.rgb * (u_light.x + u_light.y * v_d) + u_light.z * pow(v_d, u_light.w), vec3(1.0));
    }
    float w = 0.63661977 * exp(-0.5 * r2) / 0.98889;  // 2 / pi, renormalised for the cut at 3 sigma
    float alpha = (c.a >= 1.0) ? 1.0 : -expm1_approx(w * v_h / u_unit * log1m(c.a));
    frag = vec4(c.rgb * alpha, alpha);
}
