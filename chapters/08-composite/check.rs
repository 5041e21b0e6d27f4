//! Chapter 08's checks and pictures: the last frame's composite against the same formula on the
//! CPU, the overlays' depth test against the G-buffers, the trace's timings, and the PNGs.

use anyhow::Result;
use common::Report;
use common::base::cli::{Size, check_covered};
use common::frame::{Composite, Overlays, Pixels, Uniforms, View, matches_reference, shows_colour};
use common::instruments::output;
use common::rt::ao::AoTracer;
use common::scene::Camera;
use common::scene::gbuffer::GBuffers;
use std::path::Path;

/// What the last frame drew with, for checking it and writing it out.
pub struct LastFrame<'a> {
    pub gl: &'a glow::Context,
    pub gbuffers: &'a GBuffers,
    pub tracer: &'a AoTracer,
    pub composite: &'a Composite,
    /// `None` when the overlays were switched off.
    pub overlays: Option<&'a Overlays>,
    pub camera: &'a Camera,
    /// The composite's uniforms as the last frame had them (its view included).
    pub uniforms: Uniforms,
}

impl LastFrame<'_> {
    /// The checks, on the last frame's pixels as GL holds them (rows bottom-up, as in memory): each
    /// judged (`Ok`), or not, with why (`Err`): a view can leave no pixel of the gizmo, with 2
    /// pixels of room, behind a surface or in the open (a small window, an orbit, another model).
    pub fn check(&self, overlays: &Overlays) -> Result<Vec<(&'static str, Result<bool, String>)>> {
        let LastFrame { gl, gbuffers, tracer, composite, camera, .. } = *self;
        let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
        let gbuffer = Pixels::read(gl, gbuffers, tracer);

        // The final view without overlays, against the same formula computed on the CPU.
        let uniforms = Uniforms { view: View::Final, ..self.uniforms };
        composite.draw(gl, gbuffers, tracer, &uniforms);
        let plain = composite.read(gl);
        let matches = matches_reference(&gbuffer, &plain, &uniforms);
        // Then with the overlays: hidden where the G-buffers say a surface is in front, shown elsewhere.
        let view_projection = camera.view_projection(w as f32 / h as f32);
        overlays.draw(gl, &composite.target(), view_projection);
        let with_lines = composite.read(gl);
        let probes = overlays.probe(&gbuffer.view_depth(), gbuffer.width, gbuffer.height, camera);
        let hidden = probes.hidden.map(|p| !shows_colour(&with_lines, w as usize, p));
        let visible = probes.visible.map(|p| shows_colour(&with_lines, w as usize, p));
        let none =
            |where_| format!("no pixel of the gizmo, with 2 of room, is {where_} in this {w}x{h} view");
        Ok(vec![
            ("composite_matches_cpu_reference", Ok(matches)),
            ("overlay_hidden_behind_a_surface", hidden.ok_or_else(|| none("behind a surface"))),
            ("overlay_shown_where_nothing_is_in_front", visible.ok_or_else(|| none("in the open"))),
        ])
    }

    /// Headless: a picture of each of `views` (the last frame's own, or with `--all-views` every
    /// debug view), as `prefix[-view].png` in `out_dir`; the mean AO shown. A size the scene
    /// covers no pixel of is refused here, where the mean would be over none (the error names
    /// `chapter`).
    pub fn write_pictures(
        &self,
        report: &mut Report,
        chapter: &str,
        out_dir: &Path,
        prefix: &str,
        views: &[View],
    ) -> Result<()> {
        let LastFrame { gl, gbuffers, tracer, composite, camera, .. } = *self;
        let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
        let view_projection = camera.view_projection(w as f32 / h as f32);
        let ao_mean = {
            composite.draw(gl, gbuffers, tracer, &Uniforms { view: View::Ao, ..self.uniforms });
            let ao = composite.read(gl);
            let positions = output::read_texture_f32(gl, gbuffers.textures()[0], w, h, 4);
            let covered: Vec<usize> = (0..(w * h) as usize).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
            // A mean over no pixel is not a number: refuse the size instead.
            check_covered("--size", chapter, Size { width: w, height: h }, covered.len() as u64)?;
            covered.iter().map(|&i| ao[i * 4] as f64 / 255.0).sum::<f64>() / covered.len() as f64
        };
        report.set("ao_mean", (ao_mean * 1e3).round() / 1e3);
        for &view in views {
            composite.draw(gl, gbuffers, tracer, &Uniforms { view, ..self.uniforms });
            if let (View::Final, Some(overlays)) = (view, self.overlays) {
                overlays.draw(gl, &composite.target(), view_projection);
            }
            let name = match view {
                View::Final => prefix.to_owned(),
                other => format!("{prefix}-{}", other.name()),
            };
            output::save_gl_rgba8(report, out_dir, &name, (w, h), &composite.read(gl))?;
        }
        Ok(())
    }
}

/// The rays launched per second of the trace's GPU time.
pub fn report_trace_times(report: &mut Report, trace_ms: &[f64], rays_launched: u64) {
    if trace_ms.is_empty() {
        return;
    }
    let total: f64 = trace_ms.iter().sum();
    // Every pixel launches its rays (background pixels return at once): launched rays.
    report.set("mrays_per_s_launched", (rays_launched as f64 / (total / 1e3) / 1e6 * 10.0).round() / 10.0);
}
