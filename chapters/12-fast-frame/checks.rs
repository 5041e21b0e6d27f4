//! Chapter 12's checks, after the frames, in one place (`common::frame::fast::check` holds what
//! each compares): the last frame's composite and overlays, its pictures, and the lean frame
//! against chapter 08's fat one on the same scene, camera and rays.

use anyhow::Result;
use common::Report;
use common::frame::Overlays;
use common::frame::fast::check::{self, Chapter08Run, ErrorAgainst, LastFrame, Surface};
use common::frame::fast::composite::{ComputeComposite, Uniforms};
use common::frame::fast::trace::{Pattern, Rays, SurfaceTracer};
use common::frame::fast::visibility::Targets;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::scene::{Camera, Scene};
use std::path::PathBuf;

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
        for (name, ok) in last.check(&surface) {
            report.check(name, ok);
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
    let chapter_08 = check::trace_chapter_08(apis, targets, run)?;
    chapter_08.compare(&surface, per_pixel.as_ref(), report);
    Ok(())
}
