#version 330
// One proxy box per draw item. Coordinates are relative to a per-frame origin O near the camera
// (computed in float64 on the CPU), so float32 keeps precision in huge virtual volumes.
in vec3 in_corner;          // unit-cube corner, components 0 or 1
uniform vec3 u_box_lo;      // item box, relative to O
uniform vec3 u_box_hi;
uniform mat4 u_mvp;         // projection * rotation (no translation: positions are O-relative)
uniform bool u_ortho;
uniform float u_near;       // perspective: clip only in front of this depth, never at a far plane

void main() {
    vec3 p = mix(u_box_lo, u_box_hi, in_corner);
    gl_Position = u_mvp * vec4(p, 1.0);
    // Depth is not used (boxes are ordered on the CPU): clip only in front of the eye (w > u_near),
    // never at a far plane.
    gl_Position.z = u_ortho ? 0.0 : gl_Position.w - 2.0 * u_near;
}
