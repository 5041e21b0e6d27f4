//! Writing what a chapter rendered: GL read-back and PNG files.

use crate::instruments::fail;
use crate::instruments::report::Report;
use anyhow::{Context as _, Result};
use glow::HasContext;
use std::path::Path;

/// Reverses the order of the rows of RGBA8 pixels. GL numbers rows from the bottom and Vulkan
/// from the top, so an image GL drew, read back by Vulkan, has its bottom row first.
pub fn flip_rows(pixels: &[u8], width: u32, height: u32) -> Vec<u8> {
    let row = width as usize * 4;
    let mut flipped = Vec::with_capacity(pixels.len());
    for y in (0..height as usize).rev() {
        flipped.extend_from_slice(&pixels[y * row..(y + 1) * row]);
    }
    flipped
}

/// Reads the bound read framebuffer's RGBA8 pixels, top row first (GL's rows start at the bottom).
pub fn read_gl_rgba8(gl: &glow::Context, width: u32, height: u32) -> Vec<u8> {
    // In usize: a u32 product of a large size would wrap (16384 x 16384 x 4 x 4 is 2^32).
    let mut pixels = vec![0u8; width as usize * height as usize * 4];
    unsafe {
        gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
        gl.read_pixels(
            0,
            0,
            width as i32,
            height as i32,
            glow::RGBA,
            glow::UNSIGNED_BYTE,
            glow::PixelPackData::Slice(Some(&mut pixels)),
        );
    }
    flip_rows(&pixels, width, height)
}

/// Creates `dir` and its parents, as one fallible step.
pub fn create_dir(dir: &Path) -> Result<()> {
    fail::call("creating an output directory", || std::fs::create_dir_all(dir))
        .with_context(|| format!("creating {}", dir.display()))
}

/// Writes `contents` to `path` (a report, a table, a CSV), as one fallible step.
pub fn write_file(path: &Path, contents: impl AsRef<[u8]>) -> Result<()> {
    fail::call("writing an output file", || std::fs::write(path, contents))
        .with_context(|| format!("writing {}", path.display()))
}

/// Draws a plot into `path` with `draw` (plotters writes the file), as one fallible step.
pub fn draw_plot(path: &Path, draw: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    fail::step("drawing a plot")?;
    draw(path).with_context(|| format!("drawing {}", path.display()))
}

/// Writes RGBA8 pixels (top row first) as `<dir>/<name>.png` and lists the image in the report.
pub fn save_rgba8(
    report: &mut Report,
    dir: &Path,
    name: &str,
    (width, height): (u32, u32),
    pixels: &[u8],
) -> Result<()> {
    create_dir(dir)?;
    let path = dir.join(format!("{name}.png"));
    let encoded =
        encode_png((width, height), pixels).with_context(|| format!("encoding {}", path.display()))?;
    fail::call("writing a PNG", || std::fs::write(&path, &encoded))
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!("wrote {}", path.display());
    report.image(name, &path, width, height, "RGBA8");
    Ok(())
}

/// RGBA8 pixels (top row first) encoded as an 8-bit RGBA PNG, in memory: the file is then
/// written in one call, so that a failed write (a full disk) is an error, not lost in a buffered
/// writer's drop.
fn encode_png((width, height): (u32, u32), pixels: &[u8]) -> Result<Vec<u8>> {
    let mut encoded = Vec::new();
    let mut encoder = png::Encoder::new(&mut encoded, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()?;
    Ok(encoded)
}

/// Reads a PNG this tutorial wrote: 8-bit RGBA, top row first. Returns its size and pixels; any
/// other kind of PNG is refused, naming what it is.
pub fn read_png_rgba8(path: &Path) -> Result<((u32, u32), Vec<u8>)> {
    let read = || -> Result<((u32, u32), Vec<u8>)> {
        let file = std::io::BufReader::new(std::fs::File::open(path)?);
        let mut reader = png::Decoder::new(file).read_info()?;
        let size = reader.output_buffer_size().context("the image is too large to decode")?;
        let mut pixels = vec![0; size];
        let frame = reader.next_frame(&mut pixels)?;
        anyhow::ensure!(
            (frame.color_type, frame.bit_depth) == (png::ColorType::Rgba, png::BitDepth::Eight),
            "a {:?} {:?}-bit PNG, not the 8-bit RGBA this tutorial writes",
            frame.color_type,
            frame.bit_depth as u8
        );
        pixels.truncate(frame.buffer_size());
        Ok(((frame.width, frame.height), pixels))
    };
    read().with_context(|| format!("reading {}", path.display()))
}

/// [`save_rgba8`] for pixels as GL drew them, bottom row first in memory: turned upright.
pub fn save_gl_rgba8(
    report: &mut Report,
    dir: &Path,
    name: &str,
    size: (u32, u32),
    pixels: &[u8],
) -> Result<()> {
    save_rgba8(report, dir, name, size, &flip_rows(pixels, size.0, size.1))
}

/// An animation's frames (frame number, RGBA8 pixels top row first), written as
/// `<chapter>-frame-NNN.png`; where something `moved`, checked first ([`check_frames_differ`]).
pub fn save_frames(
    report: &mut Report,
    dir: &Path,
    chapter: &str,
    size: (u32, u32),
    frames: &[(u32, Vec<u8>)],
    moved: bool,
) -> Result<()> {
    if moved {
        check_frames_differ(report, size, frames);
    }
    for (frame, pixels) in frames {
        save_rgba8(report, dir, &format!("{chapter}-frame-{frame:03}"), size, pixels)?;
    }
    Ok(())
}

/// For an animation in which something moved: the first and the last frame must differ in more
/// than 1% of their pixels (`frames_differ_over_time`).
pub fn check_frames_differ(report: &mut Report, (width, height): (u32, u32), frames: &[(u32, Vec<u8>)]) {
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else { return };
    let changed = first.1.chunks_exact(4).zip(last.1.chunks_exact(4)).filter(|(a, b)| a != b).count();
    report.set("pixels_changed_first_to_last", changed);
    report.check("frames_differ_over_time", changed * 100 > width as usize * height as usize);
}

/// Reads an RGBA8 GL texture's level 0, in memory order (GL's bottom row first), with
/// `glGetTexImage`: from a texture whose storage is imported Vulkan memory, NVIDIA's driver
/// (580) returns it in a fraction of a millisecond, where `glReadPixels` through a framebuffer
/// takes about 27 ms for 320x240 (measured on an H100, 2026-11-26).
pub fn read_texture_rgba8(gl: &glow::Context, texture: glow::Texture, width: u32, height: u32) -> Vec<u8> {
    // In usize: a u32 product of a large size would wrap.
    let mut pixels = vec![0u8; width as usize * height as usize * 4];
    unsafe {
        gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
        gl.bind_texture(glow::TEXTURE_2D, Some(texture));
        gl.get_tex_image(
            glow::TEXTURE_2D,
            0,
            glow::RGBA,
            glow::UNSIGNED_BYTE,
            glow::PixelPackData::Slice(Some(&mut pixels)),
        );
        gl.bind_texture(glow::TEXTURE_2D, None);
    }
    pixels
}

/// Reads a GL texture's level 0 as `components` floats per pixel (1 for R32F, 4 for RGBA32F),
/// in memory order: GL's bottom row first.
pub fn read_texture_f32(
    gl: &glow::Context,
    texture: glow::Texture,
    width: u32,
    height: u32,
    components: u32,
) -> Vec<f32> {
    let format = if components == 1 { glow::RED } else { glow::RGBA };
    // In usize: a u32 product of a large size would wrap (16384 x 16384 x 4 x 4 is 2^32), and
    // GL would write gigabytes into an empty buffer. `gbuffer::check_size` bounds what comes here.
    let mut bytes = vec![0u8; width as usize * height as usize * components as usize * 4];
    unsafe {
        gl.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
        gl.bind_texture(glow::TEXTURE_2D, Some(texture));
        gl.get_tex_image(
            glow::TEXTURE_2D,
            0,
            format,
            glow::FLOAT,
            glow::PixelPackData::Slice(Some(&mut bytes)),
        );
        gl.bind_texture(glow::TEXTURE_2D, None);
    }
    bytes.chunks_exact(4).map(|b| f32::from_ne_bytes(b.try_into().unwrap())).collect()
}

/// Greyscale RGBA8 pixels from values in [0, 1].
pub fn grey(values: &[f32]) -> Vec<u8> {
    values
        .iter()
        .flat_map(|&v| {
            let g = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            [g, g, g, 255]
        })
        .collect()
}

/// The chart [`log_log_plot`] draws into: both axes logarithmic.
pub type LogLogChart<'a, 'b> = plotters::prelude::ChartContext<
    'a,
    plotters::prelude::SVGBackend<'b>,
    plotters::prelude::Cartesian2d<plotters::prelude::LogCoord<f64>, plotters::prelude::LogCoord<f64>>,
>;

/// How [`log_log_plot`] writes an axis' tick value.
pub type TickLabel<'a> = &'a dyn Fn(&f64) -> String;

/// A log-log plot as an SVG of `size` pixels: `caption` above, the axes named and their labels
/// written by `labels`, each axis half as wide again each way as `points` span; `draw` adds the
/// series, then the legend is drawn over a white box. An error if there is no point to span.
/// `labels` format the x and y axes' tick values.
pub fn log_log_plot(
    path: &Path,
    (size, caption): ((u32, u32), &str),
    (x_desc, y_desc): (&str, &str),
    labels: (TickLabel, TickLabel),
    points: impl Iterator<Item = (f64, f64)> + Clone,
    draw: impl FnOnce(&mut LogLogChart) -> Result<()>,
) -> Result<()> {
    use plotters::prelude::*;
    let span = |axis: fn(&(f64, f64)) -> f64| {
        points.clone().map(|p| axis(&p)).fold((f64::MAX, 0f64), |(a, b), v| (a.min(v), b.max(v)))
    };
    let ((x0, x1), (y0, y1)) = (span(|p| p.0), span(|p| p.1));
    anyhow::ensure!(x1 > 0.0 && y1 > 0.0, "nothing to plot (no GPU timestamps?)");
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((x0 / 1.5..x1 * 1.5).log_scale(), (y0 / 1.5..y1 * 1.5).log_scale())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(labels.0)
        .y_label_formatter(labels.1)
        .draw()?;
    draw(&mut chart)?;
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
