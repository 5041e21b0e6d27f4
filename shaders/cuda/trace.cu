// Chapter 11: a small analytic ray tracer (spheres on a checkered ground square) in CUDA C++.
//
// One thread per pixel writes the pixel's colour (RGBA8, red in the lowest byte) and the ray's
// hit distance (0 where the ray hits nothing) into one buffer: all colours, then all distances.
// chapters/11-cuda-depth-composite/scene.rs is the same tracer on the CPU, line for line: keep
// them in step. It is compiled without fused multiply-adds (--fmad=false), so that each float
// operation rounds as Rust's does and the two tracers agree to the bit almost everywhere.
//
// Rebuild the PTX beside it with `cargo run -p xtask -- cuda` (shaders/cuda/ptx.lock pins it).

#define MAX_SPHERES 8

struct Sphere {
    float x, y, z, radius;
    float red, green, blue, _pad;
};

// The kernel's one parameter block, passed by value. Same layout as `TraceParams` in scene.rs
// (a test checks its size and offsets there).
struct Params {
    unsigned int width, height, sphere_count, _pad0;
    // The camera: a pixel's ray points along forward + x * right + y * up, x and y in -1..1.
    float eye[4], forward[4], right[4], up[4];
    // Unit vector towards the light.
    float light[4];
    // The ground square: y = ground[1], |x| and |z| up to ground[0].
    float ground[4];
    Sphere spheres[MAX_SPHERES];
};

struct Hit {
    float t;
    float normal[3];
    float albedo[3];
};

__device__ float dot3(const float a[3], const float b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// The nearest sphere or ground hit along origin + t * dir with t > t_min (t = 0: none).
__device__ Hit nearest(const Params& p, const float origin[3], const float dir[3], float t_min) {
    Hit hit = {0.0f, {0.0f, 0.0f, 0.0f}, {0.0f, 0.0f, 0.0f}};
    for (unsigned int i = 0; i < p.sphere_count; ++i) {
        const Sphere& s = p.spheres[i];
        float oc[3] = {origin[0] - s.x, origin[1] - s.y, origin[2] - s.z};
        float b = dot3(oc, dir);
        float c = dot3(oc, oc) - s.radius * s.radius;
        float disc = b * b - c;
        if (disc < 0.0f) continue;
        float root = sqrtf(disc);
        float t = -b - root;
        if (t <= t_min) t = -b + root;
        if (t <= t_min || (hit.t > 0.0f && t >= hit.t)) continue;
        hit.t = t;
        for (int k = 0; k < 3; ++k) {
            float point = origin[k] + t * dir[k];
            float centre = k == 0 ? s.x : (k == 1 ? s.y : s.z);
            hit.normal[k] = (point - centre) / s.radius;
        }
        hit.albedo[0] = s.red;
        hit.albedo[1] = s.green;
        hit.albedo[2] = s.blue;
    }
    if (dir[1] != 0.0f) {
        float t = (p.ground[1] - origin[1]) / dir[1];
        float x = origin[0] + t * dir[0];
        float z = origin[2] + t * dir[2];
        bool inside = fabsf(x) <= p.ground[0] && fabsf(z) <= p.ground[0];
        if (t > t_min && inside && (hit.t == 0.0f || t < hit.t)) {
            hit.t = t;
            hit.normal[0] = 0.0f;
            hit.normal[1] = 1.0f;
            hit.normal[2] = 0.0f;
            // A checkerboard of unit squares.
            bool light_square = (((int)floorf(x) + (int)floorf(z)) & 1) == 0;
            float grey = light_square ? 0.8f : 0.5f;
            hit.albedo[0] = grey;
            hit.albedo[1] = grey;
            hit.albedo[2] = grey;
        }
    }
    return hit;
}

__device__ unsigned int to_byte(float value) {
    return (unsigned int)(fminf(fmaxf(value, 0.0f), 1.0f) * 255.0f + 0.5f);
}

// ANCHOR: kernel
extern "C" __global__ void trace(unsigned int* traced, Params p) {
    unsigned int x = blockIdx.x * blockDim.x + threadIdx.x;
    unsigned int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= p.width || y >= p.height) return;
    // Pixel centres in -1..1, row 0 at the bottom: GL's memory order, so GL uploads it as it is.
    float sx = ((float)x + 0.5f) / (float)p.width * 2.0f - 1.0f;
    float sy = ((float)y + 0.5f) / (float)p.height * 2.0f - 1.0f;
    float dir[3];
    for (int k = 0; k < 3; ++k) dir[k] = p.forward[k] + sx * p.right[k] + sy * p.up[k];
    float length = sqrtf(dot3(dir, dir));
    for (int k = 0; k < 3; ++k) dir[k] = dir[k] / length;

    Hit hit = nearest(p, p.eye, dir, 0.0f);
    float rgb[3];
    if (hit.t == 0.0f) {
        // The sky: a vertical gradient.
        float up = fminf(fmaxf(dir[1] * 0.5f + 0.5f, 0.0f), 1.0f);
        rgb[0] = 0.75f - 0.35f * up;
        rgb[1] = 0.82f - 0.25f * up;
        rgb[2] = 0.9f;
    } else {
        // Lambert with a hard shadow: one ray from just above the surface towards the light.
        float lambert = fmaxf(dot3(hit.normal, p.light), 0.0f);
        if (lambert > 0.0f) {
            float start[3];
            for (int k = 0; k < 3; ++k) start[k] = p.eye[k] + hit.t * dir[k] + 1e-3f * hit.normal[k];
            if (nearest(p, start, p.light, 0.0f).t > 0.0f) lambert = 0.0f;
        }
        for (int k = 0; k < 3; ++k) rgb[k] = hit.albedo[k] * (0.25f + 0.75f * lambert);
    }
    unsigned int i = y * p.width + x;
    traced[i] = to_byte(rgb[0]) | to_byte(rgb[1]) << 8 | to_byte(rgb[2]) << 16 | 255u << 24;
    traced[p.width * p.height + i] = __float_as_uint(hit.t);
}
// ANCHOR_END: kernel
