//! Chapter 11's checks: the CUDA picture against the CPU tracer, the composite against what the
//! tracer wrote, the lines' depth test, and the composite's depth against rasterised depth.

use crate::composite::{DepthComposite, DepthUniforms, Source};
use crate::scene::{self, GROUND, TraceParams};
use anyhow::Result;
use common::Report;
use common::frame::shows_colour;
use common::scene::Camera;
use glam::{Mat4, Vec3, Vec4};
use glow::HasContext;

/// What GL's buffer holds now (the PBO, or the imported Vulkan memory), as 32-bit words.
pub fn read_buffer(gl: &glow::Context, buffer: glow::Buffer, bytes: u64) -> Vec<u32> {
    let mut out = vec![0u8; bytes as usize];
    unsafe {
        gl.finish();
        gl.bind_buffer(glow::COPY_READ_BUFFER, Some(buffer));
        gl.get_buffer_sub_data(glow::COPY_READ_BUFFER, 0, &mut out);
        gl.bind_buffer(glow::COPY_READ_BUFFER, None);
    }
    out.chunks_exact(4).map(|w| u32::from_ne_bytes(w.try_into().unwrap())).collect()
}

/// Who traced the spheres.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TracedBy {
    Cuda,
    /// `scene::trace`, the reference every CUDA picture is compared with.
    Cpu,
}

/// Medians of the per-frame GPU times (CPU time for the CPU tracer), under `<path>.<what>`, for
/// the path named `path` (`pbo`, `zero_copy`).
pub fn report_times(report: &mut Report, path: &str, traced_by: TracedBy, times: &[Vec<f64>; 3]) {
    let trace = match traced_by {
        TracedBy::Cuda => "cuda_kernel",
        TracedBy::Cpu => "cpu_trace",
    };
    let mut line = format!("{path:>9}:");
    for (what, samples) in [trace, "gl_upload", "gl_composite"].iter().zip(times) {
        if samples.is_empty() {
            continue;
        }
        let (median, _) = common::clocks::timestamps::median_p95(samples);
        report.time_ms(&format!("{path}.{what}_median"), median);
        line += &format!("  {what} {median:.3} ms");
    }
    eprintln!("{line}");
}

/// One path's last frame, for checking.
pub struct Frame<'a> {
    pub gl: &'a glow::Context,
    pub composite: &'a DepthComposite,
    pub source: Source<'a>,
    pub depth: &'a DepthUniforms,
    pub view_projection: Mat4,
    pub camera: &'a Camera,
    pub traced_by: TracedBy,
}

impl Frame<'_> {
    /// Records the checks of the path named `path`, each named `<path>_<check>`; returns the
    /// picture (composite and lines, bottom row first).
    pub fn check(
        &self,
        report: &mut Report,
        path: &str,
        params: &TraceParams,
        traced: &[u32],
    ) -> Result<Vec<u8>> {
        let Frame { gl, composite, traced_by, .. } = *self;
        let (w, h) = (composite.width as usize, composite.height as usize);
        let name = |check: &str| format!("{path}_{check}");

        // The CPU tracer's picture: the reference for CUDA's, and the scene's hits.
        let mut reference = vec![0u32; 2 * w * h];
        let hits = scene::trace(params, &mut reference);
        if traced_by == TracedBy::Cuda {
            let differing = differing_pixels(traced, &reference, w * h);
            report.set(&name("pixels_differing_from_cpu"), differing);
            // Rounding may flip a pixel on a silhouette or a checker edge: at most 1 in 1,000.
            report.check(&name("cuda_matches_cpu_reference"), differing * 1000 <= w * h);
        } else {
            report.check(&name("gl_buffer_holds_the_traced_pixels"), traced == reference);
        }

        // The composite alone: the traced colours, and the traced depth.
        composite.draw_traced(gl, self.source, self.depth);
        let plain = composite.read_colour(gl);
        let shown = plain.chunks_exact(4).zip(&traced[..w * h]).all(|(p, &c)| p[..3] == c.to_le_bytes()[..3]);
        report.check(&name("composite_shows_the_traced_colours"), shown);
        let traced_depth = composite.read_depth(gl);
        // Every pixel a ray hit (spheres too): GL's depth against the formula on the CPU.
        let d = self.depth;
        let mut formula_worst = 0;
        for (i, hit) in hits.iter().enumerate().filter(|(_, hit)| hit.t > 0.0) {
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let (sx, sy) = (x / w as f32 * 2.0 - 1.0, y / h as f32 * 2.0 - 1.0);
            let expected = scene::window_depth(hit.t, (sx, sy), d.tan_half, (d.near, d.far));
            let steps = (expected as f64 * ((1 << 24) - 1) as f64).round() as u32;
            formula_worst = formula_worst.max(steps.abs_diff(traced_depth[i]));
        }
        report.set(&name("formula_steps_worst"), formula_worst);
        report.check(&name("gl_depth_is_the_formula_on_the_cpu"), formula_worst <= DEPTH_STEPS);

        // With the lines: hidden where a ray-traced surface is nearer, shown where none is.
        composite.draw_lines(gl, self.view_projection);
        let picture = composite.read_colour(gl);
        let probes = self.probe(&hits, params, w, h);
        // A probe the picture offers no pixel for fails its check (and says so): a check that
        // quietly went missing would prove nothing.
        let probed = |probe: Option<(usize, usize, [u8; 3])>, what: &str, shown: bool| {
            probe.map_or_else(
                || {
                    eprintln!("overlay: no pixel of the gizmo {what} at this size; the check fails");
                    false
                },
                |p| shows_colour(&picture, w, p) == shown,
            )
        };
        let hidden = probed(probes.0, "behind a sphere", false);
        report.check(&name("overlay_hidden_behind_a_traced_surface"), hidden);
        let visible = probed(probes.1, "in the open", true);
        report.check(&name("overlay_shown_where_nothing_is_in_front"), visible);

        // ANCHOR: depth_check
        // The ground square rasterised by GL against the ground as the tracer hit it, at every
        // pixel whose 3 x 3 neighbourhood the tracer saw as ground. A rasteriser first snaps each
        // vertex to a grid of 1 / 2^GL_SUBPIXEL_BITS of a pixel, which tilts the triangle's depth
        // plane a little: the rasterised depth may be off by about that fraction of the depth's
        // change per pixel, on top of the float roundings (DEPTH_STEPS). Half a pixel's error
        // in the formula would be 2^(SUBPIXEL_BITS - 2) times more.
        let subpixel_bits = unsafe { gl.get_parameter_i32(glow::SUBPIXEL_BITS) }.clamp(1, 16);
        composite.rasterise_ground(gl, self.view_projection);
        let rasterised = composite.read_depth(gl);
        let ground = |x: usize, y: usize| hits[y * w + x].object == GROUND && hits[y * w + x].t > 0.0;
        let (mut steps, mut beyond) = (Vec::new(), 0);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                if (y - 1..=y + 1).all(|v| (x - 1..=x + 1).all(|u| ground(u, v))) {
                    let i = y * w + x;
                    let d = |j: usize| traced_depth[j] as f64;
                    // Depth steps per pixel, across and up (central differences).
                    let gradient = (d(i + 1) - d(i - 1)).abs() / 2.0 + (d(i + w) - d(i - w)).abs() / 2.0;
                    let snapping = 2.0 * gradient / (1u32 << subpixel_bits) as f64;
                    let off = traced_depth[i].abs_diff(rasterised[i]);
                    if off as f64 > DEPTH_STEPS as f64 + snapping {
                        beyond += 1;
                    }
                    steps.push(off);
                }
            }
        }
        let (compared, worst) = (steps.len(), steps.iter().copied().max().unwrap_or(0));
        let within_one = steps.iter().filter(|&&s| s <= 1).count();
        report.set("subpixel_bits", subpixel_bits);
        report.set(&name("depth_pixels_compared"), compared);
        report.set(&name("depth_pixels_within_one_step_percent"), (within_one * 100).checked_div(compared));
        report.set(&name("depth_steps_worst"), worst);
        report.set(&name("depth_pixels_beyond_tolerance"), beyond);
        report.check(&name("traced_depth_matches_rasterised_depth"), compared > 0 && beyond == 0);
        // ANCHOR_END: depth_check
        Ok(picture)
    }

    /// Points along the gizmo that are certainly hidden (a traced surface clearly in front, all
    /// around) and certainly visible (nothing in front, all around): (x, y, colour).
    fn probe(&self, hits: &[scene::Hit], p: &TraceParams, w: usize, h: usize) -> Probes {
        let (mut hidden, mut visible) = (None, None);
        let forward = (self.camera.target - self.camera.eye).normalize();
        // The view depth the tracer found at a pixel: t along the unit ray, times its cosine.
        let view_depth = |x: usize, y: usize| {
            let (sx, sy) = ((x as f32 + 0.5) / w as f32 * 2.0 - 1.0, (y as f32 + 0.5) / h as f32 * 2.0 - 1.0);
            let ray = Vec3::from_slice(&p.forward[..3])
                + sx * Vec3::from_slice(&p.right[..3])
                + sy * Vec3::from_slice(&p.up[..3]);
            let t = hits[y * w + x].t;
            if t > 0.0 { t / ray.length() } else { f32::INFINITY }
        };
        for &(start, end, colour) in &self.composite.axes {
            for step in 2..=19 {
                let point = start.lerp(end, step as f32 / 20.0);
                let clip = self.view_projection * Vec4::from((point, 1.0));
                let ndc = clip.truncate() / clip.w;
                if clip.w <= 0.0 || ndc.x.abs() > 0.9 || ndc.y.abs() > 0.9 {
                    continue;
                }
                let x = ((ndc.x + 1.0) / 2.0 * w as f32) as usize;
                let y = ((ndc.y + 1.0) / 2.0 * h as f32) as usize;
                let depth = forward.dot(point - self.camera.eye);
                let around = |test: &dyn Fn(f32) -> bool| {
                    (y - 2..=y + 2).all(|v| (x - 2..=x + 2).all(|u| test(view_depth(u, v))))
                };
                if hidden.is_none() && around(&|d| d < 0.9 * depth) {
                    hidden = Some((x, y, colour));
                }
                if visible.is_none() && around(&|d| d > 1.1 * depth) {
                    visible = Some((x, y, colour));
                }
            }
        }
        (hidden, visible)
    }
}

type Probe = Option<(usize, usize, [u8; 3])>;
type Probes = (Probe, Probe);

/// How far, in steps of the 24-bit depth buffer (2^-24), two computations of one depth may
/// differ. Both are computed in 32-bit floats, whose spacing between 0.5 and 1 is one step:
/// each of the few roundings on either side may move the result by a step (lavapipe: most
/// pixels within one step, none beyond 6). A wrong formula is off by thousands.
pub const DEPTH_STEPS: u32 = 8;

/// Pixels whose colour differs by more than 2/255 in a channel, or whose distance differs by
/// more than one part in 10^5 (or that one tracer hit and the other missed).
fn differing_pixels(a: &[u32], b: &[u32], pixels: usize) -> usize {
    (0..pixels)
        .filter(|&i| {
            let (ca, cb) = (a[i].to_le_bytes(), b[i].to_le_bytes());
            let colour = ca.iter().zip(cb).any(|(&x, y)| x.abs_diff(y) > 2);
            let (ta, tb) = (f32::from_bits(a[pixels + i]), f32::from_bits(b[pixels + i]));
            colour || (ta - tb).abs() > 1e-5 * ta.max(tb)
        })
        .count()
}
