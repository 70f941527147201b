#version 330
// The scatter of a compacted pass: the colour its pixel's ray left, written as it is (no blending).
flat in vec4 v_color;
out vec4 f_color;

void main() {
    f_color = v_color;
}
