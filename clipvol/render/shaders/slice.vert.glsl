#version 330
// One tile of a cutting plane: the plane's polygon inside one node box, in normalised device
// coordinates (see clipvol/render/slice_action.py for the technique).
in vec2 in_ndc;

void main() {
    gl_Position = vec4(in_ndc, 0.0, 1.0);
}
