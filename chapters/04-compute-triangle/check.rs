//! Chapter 04's checks: what the frame should show, computed on the CPU.

use anyhow::Result;
use ash::vk;
use common::clocks::timing::PassTimes;
use common::instruments::census::ResizeCensus;
use common::{GlContext, Report};
use std::f32::consts::TAU;

/// What the frames showed and how long they took, gathered frame by frame for the report.
#[derive(Default)]
pub struct Checks {
    /// The colour GL clears to: a pixel that differs from it is lit.
    clear: [f32; 4],
    centre_lit: Option<bool>,
    shows_image: Option<bool>,
    /// The first and last frames read back, with their animation times.
    first_seen: Option<(Vec<u8>, f32)>,
    last_seen: Option<(Vec<u8>, f32)>,
    /// Why a frame read back (a window's, which is never refused its size) could not be judged.
    unjudged: Option<String>,
    /// GPU time of each frame's dispatch and draw, and CPU time of each whole frame.
    pub times: PassTimes,
    /// What exists once a whole cycle of `--resize-every` sizes has run (back at full size).
    pub census: ResizeCensus,
}

impl Checks {
    /// Checks for frames that GL clears to `clear` before it draws the triangle.
    pub fn new(clear: [f32; 4]) -> Checks {
        Checks { clear, ..Checks::default() }
    }

    /// Checks one read-back frame: the triangle (its corners x, y, u, v) covers the centre and
    /// shows the computed image. `unfit`: why the checks cannot judge a frame of this size (what
    /// it is, what they need), if they cannot; then none of the picture's checks is judged.
    pub fn frame(
        &mut self,
        pixels: Vec<u8>,
        (width, height): (u32, u32),
        triangle: &[[f32; 4]; 3],
        image: vk::Extent2D,
        (time, unfit): (f32, Option<(&str, String)>),
    ) {
        if let Some((what, need)) = unfit {
            self.unjudged = Some(format!("a {width}x{height} frame is {what}: the checks need {need}"));
            return;
        }
        let lit = is_lit(pixel(&pixels, width, height, [0.0, 0.0]), self.clear);
        let shows = shows_compute_image(&pixels, (width, height), triangle, image, time);
        self.centre_lit = Some(self.centre_lit.unwrap_or(true) && lit);
        self.shows_image = Some(self.shows_image.unwrap_or(true) && shows);
        match self.first_seen {
            None => self.first_seen = Some((pixels, time)),
            Some(_) => self.last_seen = Some((pixels, time)),
        }
    }

    /// The checks, what exists at the end against after the first cycle of resizes (if it
    /// was counted), and the timings, into the report.
    pub fn report(self, report: &mut Report, gl: &GlContext) -> Result<()> {
        if let Some(why) = &self.unjudged {
            for check in
                ["centre_pixel_inside_triangle", "triangle_shows_computed_image", "frames_differ_over_time"]
            {
                report.not_judged(check, why);
            }
        } else {
            self.report_pictures(report);
        }
        self.census.check(gl, report)?;
        self.times.record(report);
        Ok(())
    }

    fn report_pictures(&self, report: &mut Report) {
        report.check("centre_pixel_inside_triangle", self.centre_lit.unwrap_or(true));
        report.check("triangle_shows_computed_image", self.shows_image.unwrap_or(true));
        match (&self.first_seen, &self.last_seen) {
            // Two frames 1/60 s apart (headless `--frames 2`) may differ in fewer pixels than
            // the check counts as a change, in a small picture: too close to tell.
            (Some((_, t0)), Some((_, t1))) if (t1 - t0).abs() < 1.5 / 60.0 => eprintln!(
                "frames_differ_over_time is not checked: the first and last frames are {:.3} s \
                 apart, too close to differ visibly (3 frames or more make it)",
                (t1 - t0).abs()
            ),
            (Some((first, _)), Some((last, _))) => {
                report.check("frames_differ_over_time", differ(first, last));
            }
            _ => {}
        }
    }
}

// ANCHOR: shader_on_cpu
/// compute_triangle.comp's colour for texel (x, y) of a `size` image at `time`, line by line.
fn shader_colour(x: u32, y: u32, size: vk::Extent2D, time: f32) -> [f32; 3] {
    let (w, h) = (size.width as f32, size.height as f32);
    let p = [((x as f32 + 0.5) / w * 2.0 - 1.0) * (w / h), (y as f32 + 0.5) / h * 2.0 - 1.0];
    let radius = p[0].hypot(p[1]);
    let angle = p[1].atan2(p[0]);
    let rings = 0.5 + 0.5 * (20.0 * radius - 3.0 * time).cos();
    let hue = angle / TAU + 0.5 * radius + 0.1 * time;
    [0.0, 0.33, 0.67].map(|offset| (0.5 + 0.5 * (TAU * (hue + offset)).cos()) * (0.3 + 0.7 * rings))
}

/// What GL_LINEAR sampling of that image returns at `uv`: the four nearest texels (clamped to
/// the edge), each stored as 8-bit UNORM, weighted by distance. In 0-255.
fn sampled_colour(uv: [f32; 2], size: vk::Extent2D, time: f32) -> [f32; 3] {
    let (x, y) = (uv[0] * size.width as f32 - 0.5, uv[1] * size.height as f32 - 0.5);
    let (fx, fy) = (x - x.floor(), y - y.floor());
    let texel = |dx: f32, dy: f32| {
        let tx = (x.floor() + dx).clamp(0.0, size.width as f32 - 1.0) as u32;
        let ty = (y.floor() + dy).clamp(0.0, size.height as f32 - 1.0) as u32;
        shader_colour(tx, ty, size, time).map(|c| (c.clamp(0.0, 1.0) * 255.0).round())
    };
    let (a, b, c, d) = (texel(0.0, 0.0), texel(1.0, 0.0), texel(0.0, 1.0), texel(1.0, 1.0));
    std::array::from_fn(|i| {
        (a[i] * (1.0 - fx) + b[i] * fx) * (1.0 - fy) + (c[i] * (1.0 - fx) + d[i] * fx) * fy
    })
}

/// Does the frame show the computed image on the triangle? At the triangle's centre and halfway
/// to each corner, the pixel must be what the shader computed at that pixel's texture coordinate.
fn shows_compute_image(
    pixels: &[u8],
    (width, height): (u32, u32),
    triangle: &[[f32; 4]; 3],
    size: vk::Extent2D,
    time: f32,
) -> bool {
    let centre = [0, 1].map(|i| triangle.iter().map(|v| v[i]).sum::<f32>() / 3.0);
    let points = [centre]
        .into_iter()
        .chain(triangle.iter().map(|v| [(centre[0] + v[0]) / 2.0, (centre[1] + v[1]) / 2.0]));
    points.into_iter().all(|p| {
        let (column, row) = pixel_at(width, height, p);
        // The centre of that pixel, where GL interpolated the texture coordinate.
        let ndc = [
            (column as f32 + 0.5) / width as f32 * 2.0 - 1.0,
            1.0 - (row as f32 + 0.5) / height as f32 * 2.0,
        ];
        let expected = sampled_colour(uv_at(triangle, ndc), size, time);
        let seen = pixel(pixels, width, height, p);
        seen.iter().zip(expected).all(|(&s, e)| (s as f32 - e).abs() <= 6.0)
    })
}
// ANCHOR_END: shader_on_cpu

/// The texture coordinate GL interpolates at `p` (normalised device coordinates) in `triangle`.
fn uv_at(triangle: &[[f32; 4]; 3], p: [f32; 2]) -> [f32; 2] {
    let [a, b, c] = triangle;
    let area = |p: [f32; 2], q: &[f32; 4], r: &[f32; 4]| {
        (q[0] - p[0]) * (r[1] - p[1]) - (r[0] - p[0]) * (q[1] - p[1])
    };
    let whole = area([a[0], a[1]], b, c);
    let (wa, wb) = (area(p, b, c) / whole, area(p, c, a) / whole);
    [2, 3].map(|i| wa * a[i] + wb * b[i] + (1.0 - wa - wb) * c[i])
}

/// The (column, row) of the pixel at normalised device coordinates `p`, rows from the top.
fn pixel_at(width: u32, height: u32, p: [f32; 2]) -> (u32, u32) {
    let column = ((p[0] + 1.0) / 2.0 * width as f32) as u32;
    let row = ((1.0 - p[1]) / 2.0 * height as f32) as u32;
    (column.min(width - 1), row.min(height - 1))
}

fn pixel(pixels: &[u8], width: u32, height: u32, p: [f32; 2]) -> [u8; 4] {
    let (column, row) = pixel_at(width, height, p);
    let at = (row * width + column) as usize * 4;
    pixels[at..at + 4].try_into().unwrap()
}

fn is_lit(p: [u8; 4], clear: [f32; 4]) -> bool {
    clear.iter().zip(p).any(|(c, p)| ((c * 255.0).round() as u8).abs_diff(p) > 12)
}

/// Two frames differ when at least 1% of their pixels changed visibly.
fn differ(a: &[u8], b: &[u8]) -> bool {
    a.len() != b.len()
        || a.chunks_exact(4)
            .zip(b.chunks_exact(4))
            .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > 8))
            .count()
            * 100
            >= a.len() / 4
}
