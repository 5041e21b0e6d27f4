#version 460
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_scalar_block_layout : require
// Chapter 10: moves a sphere's vertices in place, in the buffer GL draws and the BLAS is built
// from, and recomputes their normals.

// 64 invocations a workgroup: a whole number of NVIDIA's 32-wide warps and AMD's 64-wide waves,
// so every lane of the SIMD units the workgroup occupies has a vertex to move.
layout(local_size_x = 64) in;

// common::scene::Vertex, 24 bytes: read as plain floats (scalar layout, no vec3 padding).
layout(buffer_reference, scalar) buffer Vertices { float v[]; };
// The unit direction of every vertex from the sphere's centre, as the mesh was made.
layout(buffer_reference, scalar) readonly buffer Directions { vec4 d[]; }; // xyz; w unused

// chapters/10-vertex-animation/sphere.rs: Wave, byte for byte (its unit test checks the offsets).
layout(push_constant, scalar) uniform Wave {
    Vertices vertices;
    Directions directions;
    vec3 axis;        // unit vector the wave travels along
    uint count;       // vertices
    float time;       // seconds
    float amplitude;  // of the radius, as a fraction of it
    float frequency;  // crests from pole to pole of the axis
    float speed;      // radians per second
} wave;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= wave.count) {
        return; // the last workgroup's spare invocations
    }
    vec3 d = wave.directions.d[i].xyz;
    // The radius along d: r(d) = 1 + a sin(k (d . w) + s t).
    float phase = wave.frequency * dot(d, wave.axis) + wave.speed * wave.time;
    float r = 1.0 + wave.amplitude * sin(phase);
    vec3 p = r * d;
    // The normal of the surface p(d) = r(d) d: n ~ d - grad r / r, where grad r, the gradient of
    // r over the unit sphere, is dr/d(d . w) times w's part tangent to the sphere at d.
    vec3 tangent_axis = wave.axis - dot(d, wave.axis) * d;
    vec3 grad = wave.amplitude * wave.frequency * cos(phase) * tangent_axis;
    vec3 n = normalize(d - grad / r);
    uint o = 6u * i;
    wave.vertices.v[o + 0u] = p.x;
    wave.vertices.v[o + 1u] = p.y;
    wave.vertices.v[o + 2u] = p.z;
    wave.vertices.v[o + 3u] = n.x;
    wave.vertices.v[o + 4u] = n.y;
    wave.vertices.v[o + 5u] = n.z;
}
