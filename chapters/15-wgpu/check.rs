//! Chapter 15's checks, made on the last frame while GL holds the images: GL's view of the shared
//! memory against wgpu's readback (the same bytes), GL's picture against wgpu's (the same
//! pixels), wgpu's triangle against chapter 02's colours, and the line against wgpu's depth.

use crate::show::{LINE_COLOUR, LINE_Y, Show};
use common::frame::shows_colour;
use common::instruments::output;
use glow::HasContext;

/// wgpu's readbacks of the last frame, top row first: the picture's RGBA8 and the depths.
pub struct WgpuSaw {
    pub picture: Vec<u8>,
    pub depth: Vec<u8>,
}

/// The checks, and GL's picture with the line (top row first), for the PNG.
pub fn last_frame(
    gl: &glow::Context,
    show: &Show,
    [picture, depth]: [glow::Texture; 2],
    wgpu: &WgpuSaw,
    (w, h): (u32, u32),
) -> (Vec<(&'static str, bool)>, Vec<u8>) {
    // GL reads the imported textures: memory order, which is wgpu's order (top row first).
    let gl_picture = output::read_texture_rgba8(gl, picture, w, h);
    let gl_depth: Vec<u8> =
        output::read_texture_f32(gl, depth, w, h, 1).iter().flat_map(|d| d.to_ne_bytes()).collect();
    let mut checks = vec![
        ("gl_reads_wgpus_picture", gl_picture == wgpu.picture),
        ("gl_reads_wgpus_depth", gl_depth == wgpu.depth),
    ];
    // wgpu drew chapter 02's triangle: its colour (u, v, 1 - v) at a point inside, the clear outside.
    let at = |x: f32, y: f32| {
        let column = ((x + 1.0) / 2.0 * w as f32) as usize;
        let row = ((1.0 - y) / 2.0 * h as f32) as usize; // from the top
        (column.min(w as usize - 1), row.min(h as usize - 1))
    };
    let rgb = |pixels: &[u8], (column, row): (usize, usize)| {
        let i = (row * w as usize + column) * 4;
        [pixels[i], pixels[i + 1], pixels[i + 2]]
    };
    let inside = at(-0.5, -0.6);
    let centre =
        [(inside.0 as f32 + 0.5) / w as f32 * 2.0 - 1.0, 1.0 - (inside.1 as f32 + 0.5) / h as f32 * 2.0];
    let (u, v) = ((centre[0] + 0.8) / 1.6, (0.8 - centre[1]) / 1.6);
    let expected = [u, v, 1.0 - v].map(|c| (c * 255.0).round() as u8);
    let close = |a: [u8; 3], b: [u8; 3]| a.iter().zip(b).all(|(&a, b)| a.abs_diff(b) <= 12);
    checks.push(("wgpu_drew_chapter_02s_triangle", close(rgb(&wgpu.picture, inside), expected)));
    // wgpu's depth where the triangle is: 0.5 + 0.375 x (its corners' depths, interpolated).
    let depth_at = |(column, row): (usize, usize)| {
        let i = (row * w as usize + column) * 4;
        f32::from_ne_bytes(wgpu.depth[i..i + 4].try_into().unwrap())
    };
    checks.push(("wgpu_wrote_its_depth", (depth_at(inside) - (0.5 + 0.375 * centre[0])).abs() < 0.02));

    // GL's picture without the line: wgpu's, pixel for pixel.
    show.draw(gl, [picture, depth], false);
    let shown = unsafe {
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*show.target.framebuffer));
        output::read_gl_rgba8(gl, w, h)
    };
    checks.push(("gl_shows_wgpus_picture", shown == wgpu.picture));
    // With the line: hidden behind the triangle's left half, shown in front of its right half and
    // in the open (a pixel either side of the probe: the line may fall on either row).
    show.draw(gl, [picture, depth], true);
    let with_line = unsafe {
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*show.target.framebuffer));
        output::read_gl_rgba8(gl, w, h)
    };
    let probe = |x: f32| {
        let (column, row) = at(x, LINE_Y);
        (column.clamp(1, w as usize - 2), row.clamp(1, h as usize - 2), LINE_COLOUR)
    };
    // The line's depth (LINE_DEPTH, 0.5) against the triangle's, 0.5 + 0.375 x: nearer for x > 0.
    checks.push(("line_hidden_behind_the_triangle", !shows_colour(&with_line, w as usize, probe(-0.35))));
    checks.push(("line_shown_in_front_of_the_triangle", shows_colour(&with_line, w as usize, probe(0.35))));
    checks.push(("line_shown_in_the_open", shows_colour(&with_line, w as usize, probe(-0.85))));
    (checks, with_line)
}
