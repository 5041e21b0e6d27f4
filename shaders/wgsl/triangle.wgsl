// Chapter 15: chapter 02's triangle, drawn by wgpu, tilted in depth (0.2 at its left corner, 0.8
// at its right) so that a line GL draws at depth 0.5 passes behind its left half and in front of
// its right half.

struct Corner {
    @builtin(position) position: vec4f,
    @location(0) uv: vec2f,
}

@vertex
fn vertex(@builtin(vertex_index) index: u32) -> Corner {
    // (x, y, depth) and (u, v) per corner; no vertex buffer.
    var corners = array(vec3f(0.0, 0.8, 0.5), vec3f(-0.8, -0.8, 0.2), vec3f(0.8, -0.8, 0.8));
    var uvs = array(vec2f(0.5, 0.0), vec2f(0.0, 1.0), vec2f(1.0, 1.0));
    return Corner(vec4f(corners[index], 1.0), uvs[index]);
}

struct Targets {
    @location(0) colour: vec4f,
    // Depth as a colour: what GL's composite writes to its own depth buffer.
    @location(1) depth: f32,
}

@fragment
fn fragment(corner: Corner) -> Targets {
    // Chapter 02's colours, (u, v, 1 - v); the depth wgpu's rasteriser interpolated.
    return Targets(vec4f(corner.uv.x, corner.uv.y, 1.0 - corner.uv.y, 1.0), corner.position.z);
}
