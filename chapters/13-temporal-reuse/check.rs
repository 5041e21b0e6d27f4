//! Chapter 13's checks, in one place, on the CPU from what the frames read back: no pixel keeps
//! history across the cut from a surface the previous frame did not see; on a pan what is kept
//! agrees with a new trace within its noise; with a still camera and nothing moving, the history
//! holds chapter 08's very rays; and chapter 12's checks of the last frame, with its pictures.
//! A walk calls [`Checks::after`] once per frame, and asks [`Checks::reads_back`] before it draws
//! the next frame's ids early.

use super::frame::{Drawn, Passes, Sized};
use super::path::{Path, PathKind};
use super::tracer::{Budget, Texel};
use anyhow::Result;
use common::instruments::report::Report;
use common::scene::Camera;
use fast_frame::check::{self, LastFrame, Surface, unpack_normal};
use fast_frame::composite::View;
use fast_frame::trace::{Pattern, Rays};
use fast_frame::visibility::MeshIds;
use glam::{Vec2, Vec3, Vec4Swizzles as _};
use std::path::PathBuf;

/// What a headless walk checks: the cut as it passes, and the last of its `frames` frames, whose
/// pictures go to `out` as `<prefix>.png` and `<prefix>-ao.png`.
pub struct Checks {
    pub chapter: &'static str,
    pub frames: u32,
    pub out: PathBuf,
    pub prefix: String,
    /// The frame before the cut, read back for the cut's check.
    pub before_cut: Option<Seen>,
}

impl Checks {
    /// Whether the checks read frame `frame` back: the frames either side of the cut, and the
    /// last. Such a frame does not draw the next frame's ids at its end, since the checks read
    /// its own ids after it.
    pub fn reads_back(&self, path: &Path, frame: u32) -> bool {
        path.cut().is_some_and(|c| frame + 1 == c || frame == c) || frame + 1 == self.frames
    }

    /// After frame `frame`, drawn by `drawn` with `camera`: the cut's check where the path cuts,
    /// and the last frame's checks and pictures.
    pub fn after(
        &mut self,
        p: &Passes,
        sized: &mut Sized,
        (drawn, camera, frame): (Drawn, &Camera, u32),
        report: &mut Report,
    ) -> Result<()> {
        if let Drawn::Temporal(budget) = drawn {
            self.before_cut =
                watch_the_cut(p, sized, (camera, frame), self.before_cut.take(), (budget, report))?;
        }
        if frame + 1 == self.frames {
            self.last_frame(p, sized, camera, drawn, report)?;
        }
        Ok(())
    }

    /// The last frame: chapter 12's checks of the surface, the composite and the overlays, the
    /// pictures, and what the path makes checkable.
    fn last_frame(
        &self,
        p: &Passes,
        sized: &mut Sized,
        camera: &Camera,
        drawn: Drawn,
        report: &mut Report,
    ) -> Result<()> {
        let gl = &p.apis.gl.gl;
        let surface = chapter_12_checks(p, sized, camera, self.chapter, report)?;
        if let Some(last) = last_frame(p, sized, camera) {
            last.write_pictures(report, &surface, &self.out, &self.prefix)?;
        }
        let Drawn::Temporal(budget) = drawn else { return Ok(()) };
        if budget.samples == 0 {
            return Ok(()); // nothing traced: nothing to compare
        }
        match p.path.kind() {
            // ANCHOR: still
            // A still camera and nothing moving: every pixel's history holds all its rays, the
            // same points of the same sequence chapter 08 traces, while they fit under the cap.
            PathKind::Still if p.path.moving.is_none() => {
                let total = budget.fresh + (self.frames - 1) * budget.samples;
                if total > budget.cap {
                    eprintln!(
                        "history: {total} rays a pixel pass the cap of {}; chapter 08 is not compared",
                        budget.cap
                    );
                    return Ok(());
                }
                let scene_scale = p.scene.size() / 2.0;
                let run = check::Chapter08Run {
                    scene: p.scene,
                    shared: p.shared,
                    camera,
                    per_frame: budget.samples,
                    total,
                    radius: p.radius,
                };
                // With the 4x4 blocks, chapter 08's rays are traced again per pixel for the
                // pixel-by-pixel comparison (chapter 12 does the same); the means are this frame's.
                let per_pixel = match budget.per_pixel {
                    true => None,
                    false => {
                        let pattern = Pattern::PerPixel;
                        let rays =
                            Rays { samples: budget.samples, radius: p.radius, scene_scale, pattern, salt: 0 };
                        sized.fresh.retrace(p.apis, &sized.targets, camera, rays, total)?;
                        Some(Surface::read(gl, &sized.targets))
                    }
                };
                let chapter_08 = check::trace_chapter_08(p.apis, &sized.targets, run)?;
                chapter_08.compare(&surface, per_pixel.as_ref(), report);
            }
            // ANCHOR_END: still
            PathKind::Pan => {
                let history = sized.temporal.read_history(p.apis.vk, p.apis.commands)?;
                let rays = 256;
                let scene_scale = p.scene.size() / 2.0;
                let reference = Rays {
                    samples: rays,
                    radius: p.radius,
                    scene_scale,
                    pattern: Pattern::PerPixel,
                    salt: 1,
                };
                sized.fresh.retrace(p.apis, &sized.targets, camera, reference, rays)?;
                let traced = Surface::read(gl, &sized.targets);
                pan(&history, &traced, (rays, budget.cap, budget.fresh), report);
            }
            _ => {}
        }
        Ok(())
    }
}

/// The frames around the cut, read back for the cut check: the one before it kept, the one at
/// it checked against it.
fn watch_the_cut(
    p: &Passes,
    sized: &Sized,
    (camera, frame): (&Camera, u32),
    before: Option<Seen>,
    (budget, report): (Budget, &mut Report),
) -> Result<Option<Seen>> {
    let Some(cut) = p.path.cut().filter(|&c| c > 0) else { return Ok(None) };
    let gl = &p.apis.gl.gl;
    let seen = || Seen {
        surface: Surface::read(gl, &sized.targets),
        ids: check::read_ids(gl, &sized.targets),
        camera: *camera,
        frame,
    };
    if frame + 1 == cut {
        return Ok(Some(seen()));
    }
    if let (true, Some(before)) = (frame == cut, before.as_ref()) {
        let history = sized.temporal.read_history(p.apis.vk, p.apis.commands)?;
        if budget.cap > budget.fresh && budget.samples > 0 {
            self::cut(before, &seen(), &history, (p.path, p.ids, budget.fresh), report);
        }
    }
    Ok(before)
}

/// Chapter 12's checks of the last frame: the surface's values, the composite and the overlays.
/// Returns the surface, as read; a frame whose scene covers no pixel is refused, naming `chapter`.
pub fn chapter_12_checks(
    p: &Passes,
    sized: &Sized,
    camera: &Camera,
    chapter: &str,
    report: &mut Report,
) -> Result<Surface> {
    let gl = &p.apis.gl.gl;
    let surface = Surface::read(gl, &sized.targets);
    surface.require_covered(chapter)?;
    surface.check_values(report);
    if let Some(last) = last_frame(p, sized, camera) {
        for (name, verdict) in last.check(&surface) {
            report.verdict(name, verdict);
        }
    }
    Ok(surface)
}

/// What chapter 12's last-frame checks and pictures draw with (none without overlays).
fn last_frame<'a>(p: &'a Passes, sized: &'a Sized, camera: &'a Camera) -> Option<LastFrame<'a>> {
    Some(LastFrame {
        gl: &p.apis.gl.gl,
        targets: &sized.targets,
        composite: p.composite,
        overlays: p.overlays?,
        camera,
        uniforms: p.uniforms(camera, View::Final),
    })
}

/// One frame as read back: its surface (view depth and normal per pixel), its ids, its camera.
pub struct Seen {
    pub surface: Surface,
    pub ids: Vec<u32>,
    pub camera: Camera,
    pub frame: u32,
}

impl Seen {
    /// The point pixel `(x, y)` (bottom row 0) saw at view depth `depth`, on its camera's ray.
    fn point(&self, (x, y): (usize, usize), depth: f32) -> Vec3 {
        let (w, h) = (self.surface.width as f32, self.surface.height as f32);
        let aspect = w / h;
        let ndc = Vec2::new((x as f32 + 0.5) / w, (y as f32 + 0.5) / h) * 2.0 - 1.0;
        let far = self.camera.view_projection(aspect).inverse() * ndc.extend(1.0).extend(1.0);
        let ray = (far.xyz() / far.w - self.camera.eye).normalize();
        let forward = (self.camera.target - self.camera.eye).normalize();
        self.camera.eye + ray * (depth / ray.dot(forward))
    }
}

/// Which instance an id names (chapter 12's decode, on the CPU); `None` for the background.
fn instance_of(ids: &[MeshIds], id: u32) -> Option<u32> {
    let id = id.checked_sub(1)?;
    let mesh = ids.iter().rev().find(|m| m.first_id <= id)?;
    Some(mesh.first_instance + (id - mesh.first_id) / mesh.triangles)
}

// ANCHOR: cut
/// At the cut: every pixel that kept history (it holds more rays than a fresh pixel traces)
/// must show a point the frame before saw: its own point, moved back to where it was then, lands
/// within a texel of a pixel that showed the same instance, at a point on its plane (its normal
/// moved back alike). Worked out here from the two frames' depths, normals and ids as GL reads
/// them back, apart from the shader's own reading of its history; twice as tolerant of the plane
/// (2% of the depth), so that only a real miss counts.
fn cut(
    before: &Seen,
    after: &Seen,
    history: &[Texel],
    (path, ids, fresh): (&Path, &[MeshIds], u32),
    report: &mut Report,
) {
    let (w, h) = (after.surface.width, after.surface.height);
    if (before.surface.width, before.surface.height) != (w, h) {
        return; // resized at the cut: nothing was kept, and the frames do not line up
    }
    let aspect = w as f32 / h as f32;
    let then = before.camera.view_projection(aspect);
    let (mut kept, mut started_over, mut unseen) = (0usize, 0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let Some(instance) = instance_of(ids, after.ids[i]) else { continue };
            if history[i].rays <= fresh {
                started_over += 1;
                continue;
            }
            kept += 1;
            let mut point = after.point((x, y), after.surface.depth(i));
            let mut normal = unpack_normal(after.surface.texels[i * 4 + 2]);
            if let Some(moving) = path.moving.as_ref().filter(|m| m.index as u32 == instance) {
                let back = moving.at(before.frame) * moving.at(after.frame).inverse();
                point = back.transform_point3(point);
                normal = back.transform_vector3(normal).normalize();
            }
            let clip = then * point.extend(1.0);
            let at = (clip.xy() / clip.w * 0.5 + 0.5) * Vec2::new(w as f32, h as f32) - 0.5;
            let depth_then =
                (point - before.camera.eye).dot((before.camera.target - before.camera.eye).normalize());
            let seen = clip.w > 0.0
                && (0..4).any(|k| {
                    let (tx, ty) = (at.x.floor() as i64 + (k & 1), at.y.floor() as i64 + (k >> 1));
                    if tx < 0 || ty < 0 || tx >= w as i64 || ty >= h as i64 {
                        return false;
                    }
                    let j = ty as usize * w + tx as usize;
                    let there = before.point((tx as usize, ty as usize), before.surface.depth(j));
                    instance_of(ids, before.ids[j]) == Some(instance)
                        && (there - point).dot(normal).abs() <= 0.02 * depth_then
                });
            unseen += !seen as usize;
        }
    }
    eprintln!(
        "cut: {kept} pixels kept their history, {started_over} started over; \
         {unseen} kept it from surfaces the frame before did not see"
    );
    report.set("cut_pixels_kept", kept);
    report.set("cut_pixels_started_over", started_over);
    report.set("cut_pixels_kept_unseen", unseen);
    if kept > 0 && started_over > 0 {
        report.check("no_history_kept_across_the_cut_from_unseen_surfaces", unseen == 0);
    } else {
        eprintln!(
            "no_history_kept_across_the_cut_from_unseen_surfaces is not checked at this size: the cut kept \
             {kept} pixels and started {started_over} over, and the check needs both"
        );
    }
}
// ANCHOR_END: cut

// ANCHOR: pan
/// On a pan, what the pixels kept against a new trace of the same frame (`reference`, many
/// rays, independent of the history's): the difference of each pixel in units of its expected
/// noise, from the rays on both sides, must stay within noise (root mean square at most 2), and
/// the mean difference must be within four standard errors (no drift).
fn pan(history: &[Texel], reference: &Surface, (rays, cap, fresh): (u32, u32, u32), report: &mut Report) {
    let (mut n, mut z2, mut sum, mut variance) = (0usize, 0.0f64, 0.0f64, 0.0f64);
    let mut covered = 0usize;
    for (i, texel) in history.iter().enumerate() {
        if texel.instance == 0 || reference.depth(i) <= 0.0 {
            continue;
        }
        covered += 1;
        if texel.rays <= fresh {
            continue;
        }
        let (ours, theirs) = (texel.mean as f64, reference.texels[i * 4] as f64);
        let kept = texel.rays.min(cap) as f64;
        let spread = (ours * (1.0 - ours)).max(theirs * (1.0 - theirs)).max(0.25 / rays as f64);
        let expected = spread / kept + spread / rays as f64;
        z2 += (ours - theirs).powi(2) / expected;
        sum += ours - theirs;
        variance += expected;
        n += 1;
    }
    let rms_z = (z2 / n.max(1) as f64).sqrt();
    let drift = sum / n.max(1) as f64;
    let tolerance = 4.0 * (variance / n.max(1) as f64 / n.max(1) as f64).sqrt() + 1e-3;
    report.set("pan_pixels_covered", covered);
    report.set("pan_pixels_kept", n);
    report.set("pan_rms_noise_units", (rms_z * 1e3).round() / 1e3);
    report.set("pan_mean_difference", (drift * 1e4).round() / 1e4);
    report.check("pan_history_agrees_with_a_new_trace", n > 0 && rms_z <= 2.0 && drift.abs() <= tolerance);
}
// ANCHOR_END: pan
