// Splat vertex shader: one GL point per data point (clipvol.render.splat).
// Positions arrive relative to the eye (float64 -> float32 on the CPU), so precision does not
// depend on where the data sit. The point covers +-3 sigma of the footprint, sigma = h / 2, with
// h the splat size in world units (node edge / cbrt(points in the node), Meredith & Ma 2001).
#version 330

in vec3 in_pos;     // point - eye, world units
in float in_value;  // raw value
in float in_h;      // splat size (world units)
in vec3 in_grad;    // the value's gradient at the point (world units; zero: unlit or none)

uniform mat4 u_vp;           // projection * rotation of the view (no translation)
uniform float u_px_per_unit; // pixels per world unit at depth 1 (perspective) or everywhere (ortho)
uniform int u_ortho;
uniform vec2 u_window;       // transfer-function window (lo, hi)
uniform float u_max_size;    // largest point size the driver draws

out float v_t;
out float v_sigma_px;
out float v_size_px;
out float v_h;
out float v_d;      // |g . view| / |g|: the lighting term (Blinn-Phong with the light at the eye)

void main() {
    vec4 clip = u_vp * vec4(in_pos, 1.0);
    gl_Position = clip;
    float depth = (u_ortho == 1) ? 1.0 : max(clip.w, 1e-6);
    float sigma_px = 0.5 * in_h * u_px_per_unit / depth;
    float size = clamp(6.0 * sigma_px, 1.0, u_max_size);
    gl_PointSize = size;
    v_size_px = size;
    v_sigma_px = max(sigma_px, 1e-3);
    float span = u_window.y - u_window.x;
    v_t = (span > 0.0) ? (in_value - u_window.x) / span : 0.5;
    v_h = in_h;
    float glen = length(in_grad);
    float pl = length(in_pos);
    v_d = (glen > 0.0 && pl > 0.0) ? abs(dot(in_grad, in_pos)) / (glen * pl) : 0.0;
}
