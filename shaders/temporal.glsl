// Chapter 13: what both of its shaders share. temporal_list.comp rebuilds, reprojects and
// budgets every pixel and lists those that trace; temporal_ao.rgen traces them (or, with
// `--passes packed` and `inline`, does all of it itself). Each defines FIRST_IMAGE, the binding
// of its first image (the ray tracing shader's binding 0 is the scene), and includes
// surface_hit.glsl, before including this.

layout(set = 0, binding = FIRST_IMAGE, r32ui) uniform readonly uimage2D visibility; // 0: background
// What chapter 12's composite reads: x visibility, y view depth (0: background), z packed
// normal, w albedo as 0xBBGGRR.
layout(set = 0, binding = FIRST_IMAGE + 1, rgba32f) uniform image2D surface;
// ANCHOR: history_texel
// The history, one image read (the previous frame's) and one written (this frame's), swapped
// every frame. Per pixel: x the mean visibility (16 bits) and how many rays it holds (16 bits),
// y the view depth as float bits, z the normal (pack_normal's 24 bits), w the instance + 1
// (0: background, nothing remembered).
layout(set = 0, binding = FIRST_IMAGE + 2, rgba32ui) uniform readonly uimage2D history_in;
layout(set = 0, binding = FIRST_IMAGE + 3, rgba32ui) uniform uimage2D history_out;
// ANCHOR_END: history_texel

// chapter 13's `Cameras`: this frame's camera and the previous frame's, 256 bytes.
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Cameras {
    mat4 inverse_view_projection;
    mat4 previous_view_projection;
    mat4 previous_inverse_view_projection;
    vec4 eye;              // xyz
    vec4 forward;          // xyz: the unit view direction
    vec4 previous_eye;
    vec4 previous_forward;
};

// ANCHOR: list
// A pixel whose rays a later launch traces, as the pass before lists it: where it is (x | y <<
// 16: no picture is 65,536 pixels wide), its tally (rays done << 16 | rays that hit), what it
// remembers (mean, rays) and its point and normal, so that the launch rebuilds nothing. 40 bytes.
struct Listed {
    uint pixel;
    uint tally; // 0 when listed
    float mean;
    float count;
    float point[3];
    float normal[3];
};

// The list: two counts, then room for one pixel per pixel of the picture. The pixels with
// nothing remembered, which trace `fresh` rays, fill it from the front; those that trace
// `samples` rays, from the back. No pixel is both, so the two never meet. Written and read by the
// GPU alone.
layout(buffer_reference, std430, buffer_reference_align = 8) buffer List {
    uint counts[2]; // [0] the front's, [1] the back's: 0 before each frame (vkCmdFillBuffer)
    Listed pixels[];
};
const uint FRONT = 0u;
const uint BACK = 1u;
// ANCHOR_END: list

// The tests a remembered texel must pass (`accept`), and whether there is a history at all.
const uint HAS_HISTORY = 1u;  // history_in holds the previous frame (not so on the first)
const uint SAME_INSTANCE = 2u;
const uint SAME_PLANE = 4u;
const uint SAME_NORMAL = 8u;

// Which launch of temporal_ao.rgen this is (`pass`). INLINE: the only one, every pixel traces
// its own rays. LISTING: the first of `--passes packed`, which traces every pixel that remembers
// something and lists those that don't. LISTED: the last launch of `packed` and `listed`, which
// traces the listed pixels' rays, one ray per invocation.
const uint INLINE = 0u;
const uint LISTING = 1u;
const uint LISTED = 2u;

// ANCHOR: push
// chapter 13's `TemporalRays`, byte for byte (112 bytes).
layout(push_constant) uniform TemporalRays {
    uvec2 cameras;            // device address of Cameras
    uvec2 meshes;             // of MeshIds[mesh_count] (chapter 12's table)
    uvec2 instances;          // of this frame's copy of the instance buffer: its transforms
    uvec2 previous_instances; // of the previous frame's copy
    float radius;
    float scene_scale;
    uint mesh_count;
    uint samples;       // rays for a pixel whose history is still filling
    uint fresh;         // rays for a pixel with no history (just uncovered)
    uint cap;           // the most rays the mean weighs: new rays weigh at least 1 / (cap + samples)
    uint settled_every; // a pixel whose history is full traces `samples` rays one frame in this many
    uint frame;         // which frame this is, for the settled pixels' turns
    uint accept;        // HAS_HISTORY | the tests in force
    float plane_tolerance;  // relative to view depth
    float normal_tolerance; // least cosine between the normals
    uint per_pixel;     // 1: a rotation per pixel (chapter 07's); 0: chapter 12's 4x4 blocks
    vec4 moved;         // xyz, w: a sphere holding all that moved since the previous frame, grown
                        // by the radius (w = 0: nothing moved)
    uint near_motion_cap; // the most rays remembered inside `moved` (0: no limit but `cap`)
    uint pass;            // INLINE, LISTING or LISTED (temporal_list.comp reads none)
    uvec2 list;           // device address of List
} rays;
// ANCHOR_END: push

// ANCHOR: reproject
// The previous frame's mean and ray count at `point` (where the previous frame had this pixel's
// point, with its normal then), blended from the 2x2 texels around where it lands, each only if
// it saw the same surface. A count of 0: nothing remembered.
vec2 remembered(Cameras c, vec3 point, vec3 normal, uint instance, ivec2 size) {
    if ((rays.accept & HAS_HISTORY) == 0u) {
        return vec2(0.0);
    }
    vec4 clip = c.previous_view_projection * vec4(point, 1.0);
    if (clip.w <= 0.0) {
        return vec2(0.0); // behind the previous camera
    }
    vec2 at = (clip.xy / clip.w * 0.5 + 0.5) * vec2(size) - 0.5; // in texel centres
    ivec2 base = ivec2(floor(at));
    vec2 f = at - vec2(base);
    float depth_then = dot(point - c.previous_eye.xyz, c.previous_forward.xyz);
    float weights = 0.0, mean = 0.0, count = 0.0;
    for (int k = 0; k < 4; k++) {
        ivec2 tap = base + ivec2(k & 1, k >> 1);
        float w = ((k & 1) != 0 ? f.x : 1.0 - f.x) * ((k >> 1) != 0 ? f.y : 1.0 - f.y);
        if (w <= 0.0 || any(lessThan(tap, ivec2(0))) || any(greaterThanEqual(tap, size))) {
            continue;
        }
        uvec4 texel = imageLoad(history_in, tap);
        if (texel.w == 0u) {
            continue; // the background: nothing there to remember
        }
        // Another object now covers the place: an instance that moved in front, or one that
        // moved away. Depth and normal alone would pass a different object at the same depth.
        if ((rays.accept & SAME_INSTANCE) != 0u && texel.w != instance + 1u) {
            continue;
        }
        // The point the texel saw, back on the previous camera's ray through its centre. Not on
        // this point's plane: a surface in front (this point was hidden) or behind (this point is
        // a new edge). A plane, not a depth: on a surface seen edge-on, the depth changes by far
        // more from one texel to the next than the tolerance, but the plane does not.
        vec2 ndc = (vec2(tap) + 0.5) / vec2(size) * 2.0 - 1.0;
        vec4 far = c.previous_inverse_view_projection * vec4(ndc, 1.0, 1.0);
        vec3 ray = normalize(far.xyz / far.w - c.previous_eye.xyz);
        vec3 seen = c.previous_eye.xyz + ray * (uintBitsToFloat(texel.y) / dot(ray, c.previous_forward.xyz));
        if ((rays.accept & SAME_PLANE) != 0u && abs(dot(seen - point, normal)) > rays.plane_tolerance * depth_then) {
            continue;
        }
        // The same plane, turned: a crease of the same instance, or its other side (a thin
        // surface seen from behind now). Occlusion depends on the normal.
        if ((rays.accept & SAME_NORMAL) != 0u && dot(unpack_normal(texel.z), normal) < rays.normal_tolerance) {
            continue;
        }
        weights += w;
        mean += w * float(texel.x >> 16u) / 65535.0;
        count += w * float(texel.x & 0xFFFFu);
    }
    return weights > 1e-3 ? vec2(mean, count) / weights : vec2(0.0);
}
// ANCHOR_END: reproject

// ANCHOR: sequence
// Which points of the sequence a pixel's rays take, and its rotation of the sequence. Chapter
// 12's 4x4 blocks, carried on through time: one rotation per 8x8 tile, and the 16 pixels of a
// block take consecutive points of it, frame after frame. A pixel whose history holds `count`
// rays takes the points from 16 * count on, its place in the block choosing which of them: a
// block that keeps its history fills one low-discrepancy run, 16 points for every ray each
// pixel traces, which the blur averages. (`--pattern per-pixel`: chapter 07's rotation per
// pixel, its own run from `count` on, so that a still camera traces exactly chapter 08's rays.)
uint first_point(ivec2 pixel, uint count, uint samples, out uvec2 rotation) {
    uvec2 key = rays.per_pixel != 0u ? uvec2(pixel) : uvec2(pixel) / 8u;
    rotation = uvec2(pcg(key.x + 65536u * key.y), pcg(key.y * 7919u + key.x));
    uvec2 in_block = uvec2(pixel) % 4u;
    return rays.per_pixel != 0u ? count : 16u * count + (in_block.x + 4u * in_block.y) * samples;
}
// ANCHOR_END: sequence

// Where a point's rays start: off its surface, along its normal.
vec3 ray_origin(vec3 point, vec3 n) {
    return point + n * ray_offset(point, rays.scene_scale, rays.radius);
}

// A history texel's x: the mean (16 bits) and the rays it holds (16 bits).
uint mean_and_count(float mean, float count) {
    return (uint(round(mean * 65535.0)) << 16u) | uint(round(count));
}

// Both texels of a pixel: the history (its mean and rays, what the next frame tests) and the
// surface chapter 12's composite reads.
void store(ivec2 pixel, Cameras c, PixelHit h, float mean, float count) {
    float view_depth = dot(h.position - c.eye.xyz, c.forward.xyz);
    uint albedo = floatBitsToUint(Floats(rays.instances).f[16u * h.instance + 12u]) & 0xFFFFFFu;
    uint packed = uint(pack_normal(h.n));
    imageStore(history_out, pixel, uvec4(mean_and_count(mean, count), floatBitsToUint(view_depth), packed, h.instance + 1u));
    imageStore(surface, pixel, vec4(mean, view_depth, float(packed), float(albedo)));
}

// The background's two texels: no rays, nothing kept.
void store_background(ivec2 pixel) {
    imageStore(surface, pixel, vec4(1.0, 0.0, 0.0, 0.0));
    imageStore(history_out, pixel, uvec4(0u));
}

// Chapter 12's rebuild (surface_hit.glsl) with this frame's camera; false, and the background's
// texels stored, where the pixel shows no surface.
bool hit_at(Cameras c, ivec2 pixel, ivec2 size, out PixelHit h) {
    uint id = imageLoad(visibility, pixel).r; // 0: the background
    if (id != 0u) {
        h = rebuild_hit(Meshes(rays.meshes), rays.mesh_count, rays.instances, id, pixel, size, c.eye.xyz,
                        c.inverse_view_projection);
        if (h.n != vec3(0.0)) {
            return true;
        }
    }
    store_background(pixel);
    return false;
}

// ANCHOR: blend
// The running mean, as chapter 07's, but over at most `cap` remembered rays: new rays always
// weigh at least samples / (cap + samples), so the mean forgets what no longer holds. Clamped:
// a GPU may divide by multiplying with a rounded reciprocal, and 14 * (1 / 14) is then a little
// over 1 (the H100 stores -4.5e-8 for 14 hits of 14 without the clamp).
float blend(vec2 kept, uint hits, uint samples) {
    float visibility_now = samples == 0u ? 1.0 : 1.0 - float(hits) / float(samples);
    float weight = samples == 0u ? 0.0 : float(samples) / (min(kept.y, float(rays.cap)) + float(samples));
    return clamp(mix(kept.x, visibility_now, weight), 0.0, 1.0);
}
// ANCHOR_END: blend

// What pixel `pixel`, showing `h`, remembers (mean, rays) and how many rays it traces this
// frame (`samples`): the reprojection, then the budget.
vec2 plan(Cameras c, PixelHit h, ivec2 pixel, ivec2 size, out uint samples) {
    // ANCHOR: previous_point
    // The same point of the same triangle in the previous frame: the same barycentrics on the
    // corners the instance's previous transform put there, and the normal then, turned to the
    // same side. Exact for an instance that moved; a camera that moved changes nothing here.
    Rows then = instance_rows(rays.previous_instances, h.instance);
    vec3 pa = placed(h.o0, then);
    vec3 pe1 = placed(h.o1, then) - pa;
    vec3 pe2 = placed(h.o2, then) - pa;
    vec3 point_then = pa + h.uv.x * pe1 + h.uv.y * pe2;
    vec3 normal_then = h.facing * plane_normal(pe1, pe2);
    vec2 kept = remembered(c, point_then, normal_then, h.instance, size);
    // ANCHOR_END: previous_point
    // ANCHOR: near_motion
    // Occlusion is what lies within `radius` of a point, so it changed only where something
    // moved that near. There, how much it changed is unknown, and a few new rays cannot tell a
    // change from noise: remember fewer rays, so that the mean follows within a few frames.
    if (rays.moved.w > 0.0 && rays.near_motion_cap > 0u && distance(h.position, rays.moved.xyz) < rays.moved.w) {
        kept.y = min(kept.y, float(rays.near_motion_cap));
    }
    // ANCHOR_END: near_motion

    // ANCHOR: budget
    // How many rays this pixel traces: many where nothing is remembered (less than half a ray),
    // a few while the history fills, and once it holds `cap` rays only one frame in
    // `settled_every` (its turn staggered by a hash of the pixel), so that it still follows slow
    // changes around it.
    samples = rays.samples;
    if (kept.y < 0.5) {
        kept = vec2(0.0);
        samples = rays.fresh;
    } else if (kept.y >= float(rays.cap)) {
        bool turn = rays.settled_every > 0u && (pcg(uint(pixel.x) + 65536u * uint(pixel.y)) + rays.frame) % rays.settled_every == 0u;
        samples = turn ? rays.samples : 0u;
    }
    // ANCHOR_END: budget
    return kept;
}

// Entry `at` of the list: `pixel`, its point and normal, and what it remembers. Its texels are
// stored already, with that alone.
void list_pixel(uint at, ivec2 pixel, PixelHit h, vec2 kept) {
    List(rays.list).pixels[at] = Listed(uint(pixel.x) | uint(pixel.y) << 16u, 0u, kept.x, kept.y,
                                        float[3](h.position.x, h.position.y, h.position.z),
                                        float[3](h.n.x, h.n.y, h.n.z));
}
