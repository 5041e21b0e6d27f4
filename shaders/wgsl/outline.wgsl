// Chapter 15: wgpu's compute pass over GL's picture. A pixel whose colour differs from a
// neighbour's by more than EDGE (summed over red, green and blue, in 0-255 steps) is on an edge
// and turns white; every other pixel is copied. Integer steps, so the CPU can check it exactly.

@group(0) @binding(0) var picture: texture_2d<f32>;
@group(0) @binding(1) var outlined: texture_storage_2d<rgba8unorm, write>;

// Set by the pipeline (outline.rs's EDGE and GROUP), so that the Rust side, whose check repeats
// the sum on the CPU, and this shader cannot disagree.
override EDGE: i32;
override GROUP: u32;

fn steps(xy: vec2i) -> vec3i {
    // Unorm8 reads as k / 255: times 255 and rounded, exactly k again.
    return vec3i(round(textureLoad(picture, xy, 0).rgb * 255.0));
}

@compute @workgroup_size(GROUP, GROUP)
fn outline(@builtin(global_invocation_id) id: vec3u) {
    let size = vec2i(textureDimensions(picture));
    let xy = vec2i(id.xy);
    if xy.x >= size.x || xy.y >= size.y {
        return; // the last workgroups reach past a size that is not a multiple of GROUP
    }
    let here = steps(xy);
    var neighbours = array(vec2i(1, 0), vec2i(-1, 0), vec2i(0, 1), vec2i(0, -1));
    var edge = false;
    for (var i = 0; i < 4; i++) {
        let there = steps(clamp(xy + neighbours[i], vec2i(0), size - 1));
        let d = abs(here - there);
        edge = edge || d.x + d.y + d.z > EDGE;
    }
    textureStore(outlined, xy, select(textureLoad(picture, xy, 0), vec4f(1.0), edge));
}
