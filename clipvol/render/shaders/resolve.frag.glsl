#version 330
// The last pass of a volume frame: the premultiplied float target -> straight 8-bit RGBA, the same
// arithmetic as clipvol.render.paths.setup.premultiplied_to_uint8 (the numpy form, and the tests'
// reference): the background goes under (u_bg premultiplied; zero when nothing goes under), colour is
// un-premultiplied where the 8-bit alpha is not 0 (else black: a reader that ignores alpha sees
// nothing where nothing is), both clamped to [0, 1] and rounded half to even.
uniform sampler2D u_src;
uniform vec4 u_bg;
out uvec4 f_color;

void main() {
    vec4 p = texelFetch(u_src, ivec2(gl_FragCoord.xy), 0);
    p += (1.0 - p.a) * u_bg;
    float a = clamp(p.a, 0.0, 1.0);
    vec3 rgb = roundEven(a * 255.0) > 0.0 ? p.rgb / max(a, 1e-30) : vec3(0.0);
    f_color = uvec4(roundEven(clamp(vec4(rgb, a), 0.0, 1.0) * 255.0));
}
