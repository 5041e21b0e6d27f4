//! Chapter 15's checks, made on the last frame while GL holds the images: GL's view of the shared
//! memory against wgpu's readback (the same bytes), GL's picture against wgpu's (the same
//! pixels), wgpu's triangle against chapter 02's colours, the line against wgpu's depth; then the
//! other way, wgpu's view of GL's picture against GL's, and its outline against the CPU's.

use crate::outline::EDGE;
use crate::shared::SharedImage;
use crate::show::{LINE_COLOUR, LINE_Y, Show};
use common::frame::shows_colour;
use common::instruments::output;
use glow::HasContext;

/// wgpu's readbacks of its picture and its depths on the last frame (memory order).
pub struct WgpuSaw {
    pub picture: Vec<u8>,
    pub depth: Vec<u8>,
}

pub type Checks = Vec<(&'static str, bool)>;

/// wgpu draws, GL shows: the checks, and GL's picture with the line (top row first), for the PNG.
pub fn wgpu_to_gl(
    gl: &glow::Context,
    show: &Show,
    [picture, depth]: [&SharedImage; 2],
    wgpu: &WgpuSaw,
    (w, h): (u32, u32),
) -> (Checks, Vec<u8>) {
    // GL reads the imported textures: memory order, which is wgpu's order (top row first).
    let gl_picture = output::read_texture_rgba8(gl, *picture.gl.texture, w, h);
    let gl_depth: Vec<u8> = output::read_texture_f32(gl, *depth.gl.texture, w, h, 1)
        .iter()
        .flat_map(|d| d.to_ne_bytes())
        .collect();
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
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*show.framebuffers.drawn));
        output::read_gl_rgba8(gl, w, h)
    };
    checks.push(("gl_shows_wgpus_picture", shown == wgpu.picture));
    // With the line: hidden behind the triangle's left half, shown in front of its right half and
    // in the open (a pixel either side of the probe: the line may fall on either row).
    show.draw(gl, [picture, depth], true);
    let with_line = unsafe {
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*show.framebuffers.drawn));
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

/// GL draws, wgpu reads: wgpu's readbacks of GL's picture and of its outline (memory order)
/// against GL's own reads, and the outline against the CPU's. Returns the checks and the outline
/// as GL reads it, top row first, for the PNG.
pub fn gl_to_wgpu(
    gl: &glow::Context,
    [drawn, outlined]: [&SharedImage; 2],
    [wgpu_drawn, wgpu_outlined]: [&[u8]; 2],
    (w, h): (u32, u32),
) -> (Checks, Vec<u8>) {
    let gl_drawn = output::read_texture_rgba8(gl, *drawn.gl.texture, w, h);
    let gl_outlined = output::read_texture_rgba8(gl, *outlined.gl.texture, w, h);
    let expected = outline(wgpu_drawn, w as usize);
    let checks = vec![
        ("wgpu_reads_gls_picture", wgpu_drawn == gl_drawn),
        // Exactly the CPU's outline, and an outline: some pixel changed.
        ("wgpu_outlined_gls_picture", wgpu_outlined == expected && expected != wgpu_drawn),
        ("gl_reads_wgpus_outline", gl_outlined == wgpu_outlined),
    ];
    // GL's first row is the bottom of its picture: the PNG's is the top.
    let rows: Vec<&[u8]> = gl_outlined.chunks(w as usize * 4).rev().collect();
    (checks, rows.concat())
}

/// In a window, on the last frame: the back buffer, after GL's copy, is the outline pixel for
/// pixel. Judged when the window is the picture's size, as it is unless smaller than the smallest.
pub fn window_shows(
    gl: &glow::Context,
    outline: &[u8],
    picture: (u32, u32),
    window: (u32, u32),
) -> (&'static str, Result<bool, String>) {
    let verdict = if picture == window {
        let shown = unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None); // the window's back buffer
            output::read_gl_rgba8(gl, window.0, window.1)
        };
        Ok(shown == outline)
    } else {
        let ((w, h), (pw, ph)) = (window, picture);
        Err(format!("the {w}x{h} window shows the {pw}x{ph} picture scaled (pictures are at least 16x16)"))
    };
    ("the_window_shows_the_outline", verdict)
}

/// outline.wgsl's answer, on the CPU: RGBA8 `pixels` of `width`, each pixel that differs from a
/// neighbour by more than [`EDGE`] white.
fn outline(pixels: &[u8], width: usize) -> Vec<u8> {
    let height = pixels.len() / 4 / width;
    let at = |x: usize, y: usize| &pixels[(y * width + x) * 4..][..4];
    let mut out = pixels.to_vec();
    for y in 0..height {
        for x in 0..width {
            let neighbours = [
                ((x + 1).min(width - 1), y),
                (x.saturating_sub(1), y),
                (x, (y + 1).min(height - 1)),
                (x, y.saturating_sub(1)),
            ];
            let differs =
                |(u, v)| (0..3).map(|c| at(x, y)[c].abs_diff(at(u, v)[c]) as u32).sum::<u32>() > EDGE;
            if neighbours.into_iter().any(differs) {
                out[(y * width + x) * 4..][..4].fill(255);
            }
        }
    }
    out
}
