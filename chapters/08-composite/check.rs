//! Chapter 08's checks and pictures: the last frame's composite against the same formula on the
//! CPU, the overlays' depth test against the G-buffers, the trace's timings, and the PNGs.

use anyhow::Result;
use common::ao::AoTracer;
use common::frame::{Composite, Uniforms, View};
use common::frame::{Overlays, shows_colour};
use common::gbuffer::GBuffers;
use common::scene::Camera;
use common::{Report, output};
use glam::Vec3;
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
    /// The checks, on the last frame's pixels as GL holds them (rows bottom-up, as in memory).
    pub fn check(&self, overlays: &Overlays) -> Result<Vec<(&'static str, bool)>> {
        let LastFrame { gl, gbuffers, tracer, composite, camera, .. } = *self;
        let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
        let textures = gbuffers.textures();
        let positions = output::read_texture_f32(gl, textures[0], w, h, 4);
        let normals = output::read_texture_f32(gl, textures[1], w, h, 4);
        let albedo = output::read_texture_f32(gl, textures[2], w, h, 4);
        let visibility = output::read_texture_f32(gl, tracer.image.texture.texture, w, h, 1);
        let gbuffer =
            Pixels { width: w as usize, height: h as usize, positions, normals, albedo, visibility };

        // The final view without overlays, against the same formula computed on the CPU.
        let uniforms = Uniforms { view: View::Final, ..self.uniforms };
        composite.draw(gl, gbuffers, tracer, &uniforms);
        let plain = composite.read(gl);
        let mut checks =
            vec![("composite_matches_cpu_reference", matches_reference(&gbuffer, &plain, &uniforms))];
        // Then with the overlays: hidden where the G-buffers say a surface is in front, shown elsewhere.
        let view_projection = camera.view_projection(w as f32 / h as f32);
        overlays.draw(gl, &composite.target(), view_projection);
        let with_lines = composite.read(gl);
        let depth: Vec<f32> = gbuffer.positions.chunks_exact(4).map(|p| p[3]).collect();
        let probes = overlays.probe(&depth, (gbuffer.width, gbuffer.height), camera);
        if let Some(hidden) = probes.hidden {
            checks.push(("overlay_hidden_behind_a_surface", !shows_colour(&with_lines, w as usize, hidden)));
        }
        if let Some(visible) = probes.visible {
            checks.push((
                "overlay_shown_where_nothing_is_in_front",
                shows_colour(&with_lines, w as usize, visible),
            ));
        }
        Ok(checks)
    }

    /// Headless: the picture of the last frame's view (the final picture by default), and with
    /// `all_views` every debug view, as `prefix[-view].png` in `out_dir`; the mean AO shown.
    pub fn write_pictures(
        &self,
        report: &mut Report,
        out_dir: &Path,
        prefix: &str,
        all_views: bool,
    ) -> Result<()> {
        let LastFrame { gl, gbuffers, tracer, composite, camera, .. } = *self;
        let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
        let views: Vec<View> = if all_views { View::ALL.to_vec() } else { vec![self.uniforms.view] };
        let view_projection = camera.view_projection(w as f32 / h as f32);
        let ao_mean = {
            composite.draw(gl, gbuffers, tracer, &Uniforms { view: View::Ao, ..self.uniforms });
            let ao = composite.read(gl);
            let positions = output::read_texture_f32(gl, gbuffers.textures()[0], w, h, 4);
            let covered: Vec<usize> = (0..(w * h) as usize).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
            covered.iter().map(|&i| ao[i * 4] as f64 / 255.0).sum::<f64>() / covered.len().max(1) as f64
        };
        report.set("ao_mean", (ao_mean * 1e3).round() / 1e3);
        for view in views {
            composite.draw(gl, gbuffers, tracer, &Uniforms { view, ..self.uniforms });
            if let (View::Final, Some(overlays)) = (view, self.overlays) {
                overlays.draw(gl, &composite.target(), view_projection);
            }
            let name = match view {
                View::Final => prefix.to_owned(),
                other => format!("{prefix}-{}", other.name()),
            };
            let upright = output::flip_rows(&composite.read(gl), w, h);
            output::save_rgba8(report, out_dir, &name, w, h, &upright)?;
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

/// The G-buffers and the AO as GL read them back (memory order).
pub struct Pixels {
    pub width: usize,
    pub height: usize,
    pub positions: Vec<f32>,
    pub normals: Vec<f32>,
    pub albedo: Vec<f32>,
    pub visibility: Vec<f32>,
}

// ANCHOR: reference
/// The composite shader's formula on the CPU, at a spread of covered pixels, against what GL
/// drew (within 2/255 per channel).
pub fn matches_reference(g: &Pixels, drawn: &[u8], u: &Uniforms) -> bool {
    let (w, h) = (g.width as i32, g.height as i32);
    let at = |x: i32, y: i32| (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize;
    let covered: Vec<usize> = (0..g.width * g.height).filter(|&i| g.positions[i * 4 + 3] > 0.0).collect();
    let step = (covered.len() / 64).max(1);
    let mut compared = 0;
    for &i in covered.iter().step_by(step) {
        let (x, y) = ((i % g.width) as i32, (i / g.width) as i32);
        let (depth, normal) = (g.positions[i * 4 + 3], Vec3::from_slice(&g.normals[i * 4..i * 4 + 3]));
        let (mut sum, mut count) = (0.0, 0.0);
        for dy in -u.blur_radius..=u.blur_radius {
            for dx in -u.blur_radius..=u.blur_radius {
                let j = at(x + dx, y + dy);
                let other = g.positions[j * 4 + 3];
                let same_depth = other > 0.0 && (other - depth).abs() <= u.depth_tolerance * depth;
                let same_facing =
                    Vec3::from_slice(&g.normals[j * 4..j * 4 + 3]).dot(normal) >= u.normal_tolerance;
                if same_depth && same_facing {
                    sum += g.visibility[j];
                    count += 1.0;
                }
            }
        }
        let occlusion = (sum / count).powf(u.power);
        for c in 0..3 {
            let expected = (g.albedo[i * 4 + c] * occlusion * 255.0).round();
            // Pixels right at a tolerance's edge may go either way between GPU and CPU floats.
            if (drawn[i * 4 + c] as f32 - expected).abs() > 2.0 {
                eprintln!("composite differs at ({x}, {y}): drew {}, expected {expected}", drawn[i * 4 + c]);
                return false;
            }
        }
        compared += 1;
    }
    compared > 0
}
// ANCHOR_END: reference
