#version 330
// One tile of a cutting plane: the plane's polygon inside one node box, in clip coordinates
// (the slice's own pixel grid, or a 3D view's camera; see clipvol/render/slice_action.py).
in vec4 in_clip;

void main() {
    gl_Position = in_clip;
}
