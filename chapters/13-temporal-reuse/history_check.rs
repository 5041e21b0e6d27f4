//! Chapter 13's own checks, on the CPU from what the frames read back: no pixel keeps history
//! across the cut from a surface the previous frame did not see, and on a pan what is kept
//! agrees with a new trace within its noise.

use crate::path::Path;
use crate::temporal::Texel;
use common::Report;
use common::frame::fast::check::{Surface, unpack_normal};
use common::frame::fast::visibility::MeshIds;
use common::scene::Camera;
use glam::{Vec2, Vec3, Vec4Swizzles as _};

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
pub fn cut(
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
pub fn pan(history: &[Texel], reference: &Surface, (rays, cap, fresh): (u32, u32, u32), report: &mut Report) {
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
