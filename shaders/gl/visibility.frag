// ANCHOR: all
#version 450 core
// Chapter 12: the visibility buffer. One 32-bit id per pixel and nothing else: which triangle of
// which instance is nearest. 0 is the background, so the ids start at 1.

flat in uint instance_first_id;

layout(location = 0) out uint id;

void main() {
    // gl_PrimitiveID counts the triangles of the draw from 0, again for every instance.
    id = instance_first_id + uint(gl_PrimitiveID) + 1u;
}
// ANCHOR_END: all
