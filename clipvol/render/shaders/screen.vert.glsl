#version 330
// One triangle that covers the whole viewport (NDC corners (-1,-1), (3,-1), (-1,3)). The volume
// shaders find each pixel's ray and box interval themselves from per-frame uniforms, so the
// geometry only has to reach the pixels a box may cover: the action restricts this triangle to the
// box's screen rectangle with the scissor test. One triangle has no inner edges; a rasterised box
// has up to nine, and the pixels along them are shaded twice by a software rasteriser that works on
// blocks of pixels (Mesa llvmpipe: 7-12 % of a full-resolution frame).
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2) * 2.0 - 1.0;
    gl_Position = vec4(p, 0.0, 1.0);
}
