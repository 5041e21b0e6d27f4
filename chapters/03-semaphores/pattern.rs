//! What chapter 03's frames draw and check: colours no earlier frame used, and Vulkan's pattern.

use ash::vk;
use common::Report;
use common::base::commands::HostBuffer;
use common::instruments::output;
use std::path::Path;

/// Colours no earlier frame used: GL's for the frame, and Vulkan's.
pub fn frame_colours(frame: u32) -> ([u8; 3], [u8; 3]) {
    let step = (40 + 50 * (frame % 4)) as u8;
    let shade = (frame * 23 % 200) as u8 + 40;
    ([shade, step, 230], [230, shade, step])
}

/// Vulkan's pattern: a checkerboard of `colour` and black, in 16-pixel squares.
pub fn checkerboard(bytes: &mut [u8], extent: vk::Extent2D, colour: [u8; 3]) {
    for (i, pixel) in bytes.chunks_exact_mut(4).enumerate() {
        let (x, y) = (i as u32 % extent.width, i as u32 / extent.width);
        let lit = (x / 16 + y / 16) % 2 == 0;
        let [r, g, b] = if lit { colour } else { [0, 0, 0] };
        pixel.copy_from_slice(&[r, g, b, 255]);
    }
}

/// Does the image Vulkan copied out start with GL's colour? (Its first square is all GL's.)
pub fn first_pixel_is(readback: &HostBuffer, colour: [u8; 3]) -> bool {
    readback.bytes()[..3].iter().zip(colour).all(|(&a, b)| a.abs_diff(b) <= 1)
}

/// The last frame's two pictures, `chapter.png` and `chapter-gl.png`: Vulkan's pattern as GL
/// read it back, and GL's clear as Vulkan copied it out.
pub fn save_last_frame(
    report: &mut Report,
    out_dir: &Path,
    chapter: &str,
    extent: vk::Extent2D,
    seen_by_gl: &[u8],
    seen_by_vulkan: &HostBuffer,
) -> anyhow::Result<()> {
    let size = (extent.width, extent.height);
    output::save_rgba8(report, out_dir, chapter, size, seen_by_gl)?;
    let name = format!("{chapter}-gl");
    output::save_rgba8(report, out_dir, &name, size, seen_by_vulkan.bytes())
}
