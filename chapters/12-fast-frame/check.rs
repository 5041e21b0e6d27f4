//! Chapter 12's checks: the composite against its formula on the CPU, the overlays' depth test,
//! and the lean frame against chapter 08's fat one on the same scene, camera and rays: the same
//! pixels covered, the same hit points, the same occlusion. `after_the_frames` runs them all, once
//! the frames are drawn; the rest of the file is what each compares.

use super::composite::{ComputeComposite, Uniforms, View};
use super::trace::{Pattern, Rays, SurfaceTracer};
use super::visibility::Targets;
use anyhow::Result;
use common::base::cli::{Size, check_covered};
use common::frame::{Overlays, shows_colour};
use common::instruments::output;
use common::instruments::report::Report;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::scene::{Camera, Scene};
use glam::Vec3;
use glow::HasContext;
use std::path::{Path, PathBuf};

/// What the frames drew with, and what they left.
pub struct Drawn<'a> {
    pub scene: &'a Scene,
    pub shared: &'a RayTracedScene,
    pub targets: &'a Targets,
    pub composite: &'a ComputeComposite,
    pub overlays: &'a Overlays,
    pub camera: &'a Camera,
    pub uniforms: Uniforms,
    /// The rays of one frame (0 where there was nothing to trace), and how many the surface holds.
    pub rays: Rays,
    pub accumulated: u32,
    pub frames: u32,
}

/// What the checks write and measure beside the checks themselves.
pub struct Asked {
    /// The chapter's name, for an error that names it.
    pub chapter: &'static str,
    /// Headless: the pictures' folder and name.
    pub pictures: Option<(PathBuf, String)>,
    /// `--error-against`: rays per pixel of the converged trace (0: not measured).
    pub error_against: u32,
}

/// Every check of the frame, into the report. The tracer traces again: the error's rays,
/// chapter 08's sample pattern.
pub fn after_the_frames(
    apis: Apis,
    d: Drawn,
    tracer: &mut SurfaceTracer,
    asked: Asked,
    report: &mut Report,
) -> Result<()> {
    let gl = &apis.gl.gl;
    let surface = Surface::read(gl, d.targets);
    surface.require_covered(asked.chapter)?;
    if d.frames > 0 {
        let last = LastFrame {
            gl,
            targets: d.targets,
            composite: d.composite,
            overlays: d.overlays,
            camera: d.camera,
            uniforms: d.uniforms,
        };
        for (name, verdict) in last.check(&surface) {
            report.verdict(name, verdict);
        }
        if let Some((out, prefix)) = &asked.pictures {
            last.write_pictures(report, &surface, out, prefix)?;
        }
        if asked.error_against > 0 && d.rays.samples > 0 {
            let against = ErrorAgainst { last: &last, tracer, rays: d.rays, reference: asked.error_against };
            let (raw, blurred) = against.measure(apis)?;
            let error = serde_json::json!({ "rays": asked.error_against, "raw": raw, "blurred": blurred });
            report.set("ao_rms_error", error);
        }
    }
    surface.check_values(report);
    // Chapter 08 traces with its own pattern: where this frame used another, the same rays are
    // traced again per pixel, so that every pixel can be compared, not only the means.
    let (rays, camera, targets) = (d.rays, d.camera, d.targets);
    let per_pixel = if rays.pattern == Pattern::PerPixel || rays.samples == 0 {
        None
    } else {
        tracer.retrace(apis, targets, camera, Rays { pattern: Pattern::PerPixel, ..rays }, d.accumulated)?;
        Some(Surface::read(gl, targets))
    };
    let run = Chapter08Run {
        scene: d.scene,
        shared: d.shared,
        camera,
        per_frame: rays.samples,
        total: d.accumulated,
        radius: rays.radius,
    };
    let chapter_08 = trace_chapter_08(apis, targets, run)?;
    chapter_08.compare(&surface, per_pixel.as_ref(), report);
    Ok(())
}

/// The surface Vulkan wrote, as GL holds it (memory order: GL's bottom row first).
pub struct Surface {
    pub width: usize,
    pub height: usize,
    /// RGBA per pixel: visibility, view depth (0: background), packed normal, packed albedo.
    pub texels: Vec<f32>,
}

impl Surface {
    pub fn read(gl: &glow::Context, targets: &Targets) -> Surface {
        let (w, h) = (targets.extent.width, targets.extent.height);
        let texels = output::read_texture_f32(gl, *targets.surface.texture.texture, w, h, 4);
        Surface { width: w as usize, height: h as usize, texels }
    }

    pub fn depth(&self, i: usize) -> f32 {
        self.texels[i * 4 + 1]
    }

    pub fn covered(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.width * self.height).filter(|&i| self.depth(i) > 0.0)
    }

    /// Refuses the size when the scene covers no pixel of it: every mean and check over the
    /// covered pixels (the occlusion's mean, its error, chapter 08's comparison) would be over none.
    pub fn require_covered(&self, chapter: &str) -> Result<()> {
        let size = Size { width: self.width as u32, height: self.height as u32 };
        check_covered("--size", chapter, size, self.covered().count() as u64)
    }

    /// Every visibility a fraction of rays, and exactly 1 where GL drew no id.
    pub fn check_values(&self, report: &mut Report) {
        let visibility = |i: usize| self.texels[i * 4];
        report.check("ao_within_0_and_1", self.covered().all(|i| (0.0..=1.0).contains(&visibility(i))));
        let mut background = (0..self.width * self.height).filter(|&i| self.depth(i) <= 0.0);
        report.check("background_unoccluded", background.all(|i| visibility(i) == 1.0));
    }
}

/// The picture's RGBA8 pixels, bottom row first.
pub fn read_picture(gl: &glow::Context, targets: &Targets) -> Vec<u8> {
    let (w, h) = (targets.extent.width, targets.extent.height);
    let mut pixels = vec![0u8; w as usize * h as usize * 4];
    unsafe {
        gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
        gl.bind_texture(glow::TEXTURE_2D, Some(*targets.picture));
        let data = glow::PixelPackData::Slice(Some(&mut pixels));
        gl.get_tex_image(glow::TEXTURE_2D, 0, glow::RGBA, glow::UNSIGNED_BYTE, data);
        gl.bind_texture(glow::TEXTURE_2D, None);
    }
    pixels
}

/// The visibility ids as GL holds them (0: background).
pub fn read_ids(gl: &glow::Context, targets: &Targets) -> Vec<u32> {
    let (w, h) = (targets.extent.width as usize, targets.extent.height as usize);
    let mut bytes = vec![0u8; w * h * 4];
    unsafe {
        gl.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
        gl.bind_texture(glow::TEXTURE_2D, Some(*targets.visibility.texture.texture));
        let data = glow::PixelPackData::Slice(Some(&mut bytes));
        gl.get_tex_image(glow::TEXTURE_2D, 0, glow::RED_INTEGER, glow::UNSIGNED_INT, data);
        gl.bind_texture(glow::TEXTURE_2D, None);
    }
    bytes.chunks_exact(4).map(|b| u32::from_ne_bytes(b.try_into().unwrap())).collect()
}

/// What the last frame drew with.
pub struct LastFrame<'a> {
    pub gl: &'a glow::Context,
    pub targets: &'a Targets,
    pub composite: &'a ComputeComposite,
    pub overlays: &'a Overlays,
    pub camera: &'a Camera,
    pub uniforms: Uniforms,
}

impl LastFrame<'_> {
    /// The composite against the CPU, then the overlays: hidden where the surface is in front.
    pub fn check(&self, surface: &Surface) -> Vec<(&'static str, Result<bool, String>)> {
        let LastFrame { gl, targets, composite, overlays, camera, .. } = *self;
        let uniforms = Uniforms { view: View::Final, ..self.uniforms };
        composite.draw(gl, targets, &uniforms);
        let plain = read_picture(gl, targets);
        let matches = matches_reference(surface, &plain, &uniforms);
        let (w, h) = (targets.extent.width, targets.extent.height);
        let view_projection = camera.view_projection(w as f32 / h as f32);
        overlays.draw(gl, &targets.overlay_target(), view_projection);
        let with_lines = read_picture(gl, targets);
        let depth: Vec<f32> = (0..surface.width * surface.height).map(|i| surface.depth(i)).collect();
        let probes = overlays.probe(&depth, surface.width, surface.height, camera);
        // Judged where the view offers such a point, as in chapter 08; not judged, and said so,
        // where it does not (a small window, or a camera inside the pile).
        let shows = |probe: Option<(usize, usize, [u8; 3])>, shown, where_| {
            let none = || format!("no pixel of the gizmo, with 2 of room, is {where_} in this {w}x{h} view");
            probe.map(|p| shows_colour(&with_lines, surface.width, p) == shown).ok_or_else(none)
        };
        vec![
            ("composite_matches_cpu_reference", Ok(matches)),
            ("overlay_hidden_behind_a_surface", shows(probes.hidden, false, "behind a surface")),
            ("overlay_shown_where_nothing_is_in_front", shows(probes.visible, true, "in the open")),
        ]
    }

    /// The final picture (with overlays) and the blurred occlusion, as PNGs; the mean occlusion
    /// over covered pixels, as chapter 08 reports it.
    pub fn write_pictures(
        &self,
        report: &mut Report,
        surface: &Surface,
        out: &Path,
        prefix: &str,
    ) -> Result<()> {
        let LastFrame { gl, targets, composite, overlays, camera, .. } = *self;
        let (w, h) = (targets.extent.width, targets.extent.height);
        composite.draw(gl, targets, &Uniforms { view: View::Ao, ..self.uniforms });
        let ao = read_picture(gl, targets);
        let covered: Vec<usize> = surface.covered().collect();
        let mean =
            covered.iter().map(|&i| ao[i * 4] as f64 / 255.0).sum::<f64>() / covered.len().max(1) as f64;
        report.set("ao_mean", (mean * 1e3).round() / 1e3);
        output::save_gl_rgba8(report, out, &format!("{prefix}-ao"), (w, h), &ao)?;
        composite.draw(gl, targets, &Uniforms { view: View::Final, ..self.uniforms });
        overlays.draw(gl, &targets.overlay_target(), camera.view_projection(w as f32 / h as f32));
        output::save_gl_rgba8(report, out, prefix, (w, h), &read_picture(gl, targets))?;
        Ok(())
    }
}

// ANCHOR: reference
/// The compute shader's formula on the CPU, at a spread of covered pixels, against what GL
/// drew (within 2/255 per channel).
pub fn matches_reference(s: &Surface, drawn: &[u8], u: &Uniforms) -> bool {
    let (w, h) = (s.width as i32, s.height as i32);
    let at = |x: i32, y: i32| (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize;
    let covered: Vec<usize> = s.covered().collect();
    let step = (covered.len() / 64).max(1);
    let mut compared = 0;
    for &i in covered.iter().step_by(step) {
        let (x, y) = ((i % s.width) as i32, (i / s.width) as i32);
        let (depth, normal) = (s.depth(i), unpack_normal(s.texels[i * 4 + 2]));
        let (mut sum, mut count) = (0.0, 0.0);
        for dy in -u.blur_radius..=u.blur_radius {
            for dx in -u.blur_radius..=u.blur_radius {
                let j = at(x + dx, y + dy);
                let other = s.depth(j);
                let same_depth = other > 0.0 && (other - depth).abs() <= u.depth_tolerance * depth;
                let same_facing = unpack_normal(s.texels[j * 4 + 2]).dot(normal) >= u.normal_tolerance;
                if same_depth && same_facing {
                    sum += s.texels[j * 4];
                    count += 1.0;
                }
            }
        }
        let occlusion = (sum / count).powf(u.power);
        let albedo = s.texels[i * 4 + 3] as u32;
        for c in 0..3 {
            let expected = (((albedo >> (8 * c)) & 0xFF) as f32 / 255.0 * occlusion * 255.0).round();
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

/// ao.rgen's unpack_normal, on the CPU.
pub fn unpack_normal(packed: f32) -> Vec3 {
    let q = packed as u32;
    let p = glam::Vec2::new((q >> 12) as f32, (q & 4095) as f32) / 4095.0 * 2.0 - 1.0;
    let mut n = Vec3::new(p.x, p.y, 1.0 - p.x.abs() - p.y.abs());
    if n.z < 0.0 {
        let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
        (n.x, n.y) = ((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y));
    }
    n.normalize()
}

// ANCHOR: against_08
/// The lean frame against chapter 08's G-buffers and AO image, drawn and traced with the same
/// camera and rays: `positions` (RGBA32F, w the view depth) and `visibility` (R32F) read back.
pub struct Chapter08 {
    pub positions: Vec<f32>,
    pub visibility: Vec<f32>,
    /// This chapter's ids, read back with them, and GL's sub-pixel precision (GL_SUBPIXEL_BITS).
    pub ids: Vec<u32>,
    pub subpixel_bits: u32,
}

impl Chapter08 {
    /// `s`: the frame's surface; `per_pixel`: the same rays traced with chapter 08's pattern,
    /// where the frame used another.
    pub fn compare(&self, s: &Surface, per_pixel: Option<&Surface>, report: &mut Report) {
        let same_rays = per_pixel.is_none();
        let pixels = s.width * s.height;
        let theirs = |i: usize| self.positions[i * 4 + 3];
        // Coverage: the same triangles at the same pixels, but where two triangles tie in depth
        // (one pass may keep either).
        let differ = (0..pixels).filter(|&i| (theirs(i) > 0.0) != (s.depth(i) > 0.0)).count();
        let both: Vec<usize> = (0..pixels).filter(|&i| theirs(i) > 0.0 && s.depth(i) > 0.0).collect();
        report.set("coverage_pixels_differing", differ);
        report.check("covers_the_pixels_chapter_08_covers", !both.is_empty() && differ * 1000 <= pixels);
        // ANCHOR: hit_points
        // Hit points: the rebuilt point's view depth against GL's interpolated one, at every pixel
        // whose 3 x 3 neighbourhood is covered. GL snaps each vertex to 1 / 2^SUBPIXEL_BITS of a
        // pixel before it rasterises, which tilts the triangle's depth plane a little: where the
        // neighbourhood is one triangle, GL's depth may be off by about that fraction of the
        // depth's change per pixel, on top of float rounding (chapter 11 met the same). Half a
        // pixel's error in the rebuilt ray is 2^(SUBPIXEL_BITS - 2) times more. Where triangles
        // meet, the two passes (other programs, so other roundings) may give a pixel on the edge
        // to either triangle: there GL's depth must be within the neighbourhood's depths.
        let (w, d) = (s.width, |j: usize| s.depth(j) as f64);
        let (mut strict, mut compared, mut beyond, mut worst) = (0, 0, 0, 0.0f64);
        for y in 1..s.height - 1 {
            for x in 1..w - 1 {
                let i = y * w + x;
                let around = || (y - 1..=y + 1).flat_map(move |v| (v * w + x - 1)..=(v * w + x + 1));
                if around().any(|j| d(j) <= 0.0) || theirs(i) <= 0.0 {
                    continue;
                }
                let rounding = 2e-5 * d(i);
                let tolerance = if around().all(|j| self.ids[j] == self.ids[i]) {
                    strict += 1;
                    let gradient = (d(i + 1) - d(i - 1)).abs() / 2.0 + (d(i + w) - d(i - w)).abs() / 2.0;
                    rounding + 2.0 * gradient / (1u64 << self.subpixel_bits) as f64
                } else {
                    rounding + around().map(|j| (d(j) - d(i)).abs()).fold(0.0, f64::max)
                };
                let off = (d(i) - theirs(i) as f64).abs();
                beyond += (off > tolerance) as usize;
                worst = worst.max(off / tolerance);
                compared += 1;
            }
        }
        report.set("subpixel_bits", self.subpixel_bits);
        report.set("hit_pixels_compared", compared);
        report.set("hit_pixels_inside_one_triangle", strict);
        report.set("hit_pixels_beyond_tolerance", beyond);
        report.set("hit_depth_worst_of_tolerance", (worst * 100.0).round() / 100.0);
        let none =
            format!("no covered pixel has its 3 x 3 neighbourhood covered in this {w}x{} view", s.height);
        let verdict = if compared > 0 { Ok(beyond == 0) } else { Err(none) };
        report.verdict("rebuilt_hits_match_the_rasterised_positions", verdict);
        // ANCHOR_END: hit_points
        // Occlusion: the same rays from (nearly) the same points. The means must agree within
        // Monte Carlo noise: four standard errors of the mean difference, counting each 8x8 tile
        // as one sample where a tile pattern makes its pixels' errors move together. Per pixel,
        // with chapter 08's own sample pattern, nearly every pixel must be the same.
        let n = both.len().max(1) as f64;
        let mean = |f: &dyn Fn(usize) -> f64| both.iter().map(|&i| f(i)).sum::<f64>() / n;
        let difference = |i: usize| s.texels[i * 4] as f64 - self.visibility[i] as f64;
        let (ours, chapter_08) = (mean(&|i| s.texels[i * 4] as f64), mean(&|i| self.visibility[i] as f64));
        let spread = (mean(&|i| difference(i).powi(2)) - (ours - chapter_08).powi(2)).max(0.0).sqrt();
        let samples = if same_rays { n } else { (n / 64.0).max(1.0) };
        let tolerance = 4.0 * spread / samples.sqrt() + 1e-3;
        report.set("visibility_mean", (ours * 1e4).round() / 1e4);
        report.set("visibility_mean_chapter_08", (chapter_08 * 1e4).round() / 1e4);
        report.set("visibility_mean_tolerance", (tolerance * 1e4).round() / 1e4);
        report.check("ao_mean_agrees_with_chapter_08", (ours - chapter_08).abs() <= tolerance);
        let traced = per_pixel.unwrap_or(s);
        let per_pixel = mean(&|i| (traced.texels[i * 4] as f64 - self.visibility[i] as f64).abs());
        report.set("visibility_mean_abs_difference", (per_pixel * 1e4).round() / 1e4);
        report.check("ao_per_pixel_agrees_with_chapter_08", per_pixel <= 0.01);
    }
}
// ANCHOR_END: against_08

/// What chapter 08 is asked to trace, to be compared with this chapter's frames: the same scene
/// and camera, and the same rays, `per_frame` at a time up to `total` per pixel.
pub struct Chapter08Run<'a> {
    pub scene: &'a common::scene::Scene,
    pub shared: &'a common::rt::RayTracedScene,
    pub camera: &'a Camera,
    pub per_frame: u32,
    pub total: u32,
    pub radius: f32,
}

/// Chapter 08's G-buffers and AO for `run`, at the size of `targets`: read back, then destroyed.
pub fn trace_chapter_08(apis: Apis, targets: &Targets, run: Chapter08Run) -> Result<Chapter08> {
    let Chapter08Run { scene, shared, camera, per_frame, total, radius } = run;
    let (allocator, buffers, tlas) = (&shared.allocator, &shared.buffers, *shared.structures.tlas.handle);
    let (vk, gl) = (apis.vk, apis.gl);
    let extent = targets.extent;
    use common::rt::ao::AoTracer;
    use common::scene::gbuffer::GBuffers;
    let storage = ash::vk::ImageUsageFlags::STORAGE;
    let gbuffers = GBuffers::new(vk, gl, apis.handoff, buffers, extent, storage)?;
    gbuffers.draw(&gl.gl, scene, camera);
    let mut tracer = AoTracer::new(vk, gl, allocator, tlas, &gbuffers)?;
    // Its own command buffer, made after what it traces with: dropped first on an early return,
    // it waits for its last trace before `tracer` and `gbuffers` go.
    let commands = common::base::commands::Commands::new(vk)?;
    let apis = Apis { commands: &commands, ..apis };
    let scene_scale = scene.size() / 2.0;
    if per_frame == 0 || total == 0 || radius == 0.0 {
        tracer.fill_unoccluded(vk, gl, apis.handoff)?;
    }
    while tracer.accumulated < total && per_frame > 0 && radius > 0.0 {
        let samples = per_frame.min(total - tracer.accumulated);
        let rays = common::rt::ao::AoRays { samples, accumulated: 0, radius, scene_scale };
        tracer.trace(apis, &gbuffers, rays, None)?;
    }
    let (w, h) = (extent.width, extent.height);
    let positions = output::read_texture_f32(&gl.gl, gbuffers.textures()[0], w, h, 4);
    let visibility = output::read_texture_f32(&gl.gl, *tracer.image.texture.texture, w, h, 1);
    let ids = read_ids(&gl.gl, targets);
    let subpixel_bits = unsafe { gl.gl.get_parameter_i32(glow::SUBPIXEL_BITS) }.clamp(1, 16) as u32;
    unsafe { gl.gl.finish() };
    commands.wait(vk, "vkWaitForFences before the checks")?;
    drop(commands);
    drop(tracer);
    drop(gbuffers);
    Ok(Chapter08 { positions, visibility, ids, subpixel_bits })
}

// ANCHOR: error_after_blur
/// How far one frame's occlusion, as shown (blurred, to its power), is from a converged one: the
/// root mean square difference over covered pixels, in [0, 1], before and after the blur. The
/// frame is traced anew (one frame of `rays`, nothing accumulated); the converged one with
/// `reference` rays per pixel from other rotations of the sequence, so that its errors are
/// independent of the frame's (its own error adds `rays.samples / reference` to the square).
pub struct ErrorAgainst<'a> {
    pub last: &'a LastFrame<'a>,
    pub tracer: &'a mut super::trace::SurfaceTracer,
    pub rays: super::trace::Rays,
    pub reference: u32,
}

impl ErrorAgainst<'_> {
    pub fn measure(self, apis: Apis) -> Result<(f64, f64)> {
        let gl = apis.gl;
        let LastFrame { targets, composite, camera, .. } = *self.last;
        let shown = |blur| -> Vec<u8> {
            let uniforms = Uniforms { view: View::Ao, blur_radius: blur, ..self.last.uniforms };
            composite.draw(&gl.gl, targets, &uniforms);
            read_picture(&gl.gl, targets)
        };
        let blur = self.last.uniforms.blur_radius;
        self.tracer.accumulated = 0;
        self.tracer.trace(apis, targets, camera, self.rays, None)?;
        let (frame_blurred, frame_raw) = (shown(blur), shown(0));
        let surface = Surface::read(&gl.gl, targets);
        let pattern = super::trace::Pattern::PerPixel;
        let rays = super::trace::Rays { samples: 256, pattern, salt: 1, ..self.rays };
        self.tracer.retrace(apis, targets, camera, rays, self.reference)?;
        let (converged_blurred, converged_raw) = (shown(blur), shown(0));
        let covered: Vec<usize> = surface.covered().collect();
        let rms = |a: &[u8], b: &[u8]| {
            let sum: f64 =
                covered.iter().map(|&i| ((a[i * 4] as f64 - b[i * 4] as f64) / 255.0).powi(2)).sum();
            (sum / covered.len().max(1) as f64).sqrt()
        };
        Ok((rms(&frame_raw, &converged_raw), rms(&frame_blurred, &converged_blurred)))
    }
}
// ANCHOR_END: error_after_blur
