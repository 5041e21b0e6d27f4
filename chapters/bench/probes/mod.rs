//! `bench --probe NAME`: the questions chapter 12's design answered, each measured on the
//! chapter's frame (its library, `fast_frame`) drawn here as the chapter draws it, at every scene,
//! size, ray count and blur radius asked for, after `--frames` frames:
//!
//! - `layouts`: which lean buffer is cheaper to rasterise, the ids or a packed normal and depth
//!   (`layouts.rs`);
//! - `overlap`: does GL's work run beside Vulkan's on this driver, so that frames in flight
//!   could pay (`overlap.rs`);
//! - `vulkan-composite`: would Vulkan's compute shader composite faster than GL's
//!   (`vk_composite.rs`);
//! - `patterns`: which sample pattern buys the least error after the blur for its time
//!   (`patterns.rs`);
//! - `one-process` and `gl-stall`: chapter 14's, on its own frame (`two_processes.rs`): what the
//!   second process costs the hand-over, and what GL does with a wait nobody will satisfy.
//!
//! Each prints one markdown table (and writes it to `probe-NAME.md` in `--out`), one row per
//! setting, and sets its rows in the report.

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::Size;
use common::base::commands::Commands;
use common::clocks::timeline::{Timeline, stamp_into};
use common::clocks::timestamps::{Timestamps, median_p95};
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::frame::Overlays;
use common::interop::handoff::{Apis, Handoff};
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, TlasFlags};
use common::scene::builtin::{Ground, SceneKind};
use common::scene::{Camera, Scene};
use common::{GlContext, Report, VulkanContext};
use fast_frame::composite::{ComputeComposite, Uniforms, View};
use fast_frame::trace::{Pattern, Rays, SurfaceTracer};
use fast_frame::visibility::{self, MeshIds, Targets, VisibilityPass};
use glow::HasContext as _;
use std::fmt::Write as _;
use std::path::Path;

mod layouts;
mod overlap;
mod patterns;
mod two_processes;
mod vk_composite;

/// A question `--probe` answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Probe {
    Layouts,
    Overlap,
    VulkanComposite,
    Patterns,
    /// Chapter 14's hand-over with GL in the renderer's own process.
    OneProcess,
    /// Chapter 14's ruled-out wait: GL on a semaphore nobody signals.
    GlStall,
}

/// Where the probe runs: every scene, size, ray count, blur radius and sample pattern, `frames`
/// frames each before `rounds` rounds of the probe.
pub struct Settings {
    pub scenes: Vec<SceneKind>,
    pub sizes: Vec<Size>,
    pub spps: Vec<u32>,
    pub blurs: Vec<u32>,
    pub patterns: Vec<Pattern>,
    /// `patterns`: the converged trace's rays per pixel.
    pub reference: u32,
    pub frames: u32,
    pub rounds: u32,
    pub ground: Ground,
}

/// Chapter 12's frame at one setting, with its defaults (one flat BLAS, power 2, the default
/// radius): the passes `run` in `chapters/12-fast-frame/main.rs` makes.
/// Dropped newest first (fields in order); the GPU must be done with them.
pub struct Frame<'s> {
    pub scene: &'s Scene,
    pub ids: Vec<MeshIds>,
    pub camera: Camera,
    pub rays: Rays,
    pub composite: ComputeComposite,
    pub tracer: SurfaceTracer,
    pub visibility: VisibilityPass,
    pub targets: Targets,
}

impl<'s> Frame<'s> {
    fn new(
        (vk, gl, handoff): (&VulkanContext, &GlContext, &Handoff),
        shared: &RayTracedScene,
        scene: &'s Scene,
        extent: vk::Extent2D,
        (spp, pattern): (u32, Pattern),
    ) -> Result<Self> {
        let ids = visibility::number_triangles(vk, scene, &shared.buffers)?;
        let mut camera = Camera::framing(scene.bounds, extent.width as f32 / extent.height as f32);
        camera.orbit(0.0, 0.0, 1.0, scene.bounds); // as the chapter aims it at its default zoom
        let radius = 0.05 * scene.size(); // the chapter's default radius
        let rays = Rays { samples: spp, radius, scene_scale: scene.size() / 2.0, pattern, salt: 0 };
        let targets = Targets::new(vk, gl, handoff, extent)?;
        let visibility = VisibilityPass::new(gl, &shared.buffers)?;
        let tracer = SurfaceTracer::new(vk, shared, &ids, &targets)?;
        let composite = ComputeComposite::new(&gl.gl)?;
        Ok(Frame { scene, ids, camera, rays, composite, tracer, visibility, targets })
    }

    /// One frame as the chapter draws it: the ids, a fresh trace of `rays`, the composite.
    fn draw(&mut self, apis: Apis, uniforms: &Uniforms) -> Result<()> {
        self.draw_timed(apis, uniforms, None)
    }

    /// [`Frame::draw`], the trace between two timestamps if `stamps` is given.
    fn draw_timed(&mut self, apis: Apis, uniforms: &Uniforms, stamps: Option<&Timestamps>) -> Result<()> {
        let gl = &apis.gl.gl;
        self.visibility.draw(gl, &self.targets.ids_target(), self.scene, &self.ids, &self.camera);
        self.tracer.accumulated = 0;
        self.tracer.trace(apis, &self.targets, &self.camera, self.rays, stamps)?;
        self.composite.draw(gl, &self.targets, uniforms);
        Ok(())
    }
}

/// Chapter 12's frame on one clock (`bench --timeline N`): `frames` frames of its passes (ids,
/// trace, composite and overlays), the last `last` of them stamped, into `<out>.json` and
/// `<out>.svg`. Each frame traces `spp` fresh rays, as the bench's other rows do, where the
/// chapter's loop adds them to a running mean (the same rays, one more read a pixel). A frame's
/// trace is read once the next frame's ids are queued, where the chapter's loop reads it; the
/// gaps between the passes go in the report.
pub fn timeline(
    (vk, gl, handoff, stamps): (&VulkanContext, &GlContext, &Handoff, &Timestamps),
    scene: &Scene,
    (extent, spp): (vk::Extent2D, u32),
    (frames, last): (u32, u32),
    out: &Path,
) -> Result<serde_json::Map<String, serde_json::Value>> {
    let shared = RayTracedScene::with_layout(vk, gl, scene, TlasFlags::STATIC, BlasLayout::Flat)?;
    let mut frame = Frame::new((vk, gl, handoff), &shared, scene, extent, (spp, Pattern::Tile4x4))?;
    let g = &gl.gl;
    let overlays = Overlays::new(g, scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
    let uniforms = Uniforms::new(2, 2.0, View::Final, frame.camera.far);
    let mut timeline = Timeline::new(g, last.min(frames), ["ids", "composite"])?;
    let commands = Commands::new(vk)?; // made last: dropped first, it waits for its work
    let apis = Apis { vk, gl, handoff, commands: &commands };
    let view_projection = frame.camera.view_projection(extent.width as f32 / extent.height as f32);
    let mut traced = None; // the slot of the frame whose trace is still to be read
    for f in 0..frames {
        let slot = timeline.slot(f, frames);
        stamp_into(Some(&timeline), slot, 0);
        frame.visibility.draw(g, &frame.targets.ids_target(), scene, &frame.ids, &frame.camera);
        stamp_into(Some(&timeline), slot, 1);
        if let Some(previous) = traced.take() {
            unsafe { g.flush() };
            commands.wait(vk, "vkWaitForFences for the previous frame")?;
            if let Some(previous) = previous {
                timeline.trace_done(vk, previous, stamps)?;
            }
        }
        frame.tracer.accumulated = 0;
        frame.tracer.trace(apis, &frame.targets, &frame.camera, frame.rays, Some(stamps))?;
        traced = Some(slot);
        stamp_into(Some(&timeline), slot, 2);
        frame.composite.draw(g, &frame.targets, &uniforms);
        overlays.draw(g, &frame.targets.overlay_target(), view_projection);
        stamp_into(Some(&timeline), slot, 3);
    }
    unsafe { g.finish() };
    commands.wait(vk, "vkWaitForFences after the last frame")?;
    if let Some(Some(last)) = traced {
        timeline.trace_done(vk, last, stamps)?;
    }
    let gaps = timeline.finish(vk, &commands, stamps, out)?;
    vk.wait_idle()?; // once: no owner below waits
    drop(commands);
    drop(overlays);
    drop(frame);
    drop(shared);
    Ok(gaps)
}

/// GL's compute composite, `rounds` dispatches over the surface the frames left: its median
/// GPU milliseconds (the column `vulkan-composite` sets Vulkan's beside).
fn gl_composite_ms(
    gl: &std::rc::Rc<glow::Context>,
    frame: &Frame,
    uniforms: &Uniforms,
    rounds: u32,
) -> Result<f64> {
    let (mut timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    for _ in 0..rounds {
        timer.time(gl, "composite", || frame.composite.draw(gl, &frame.targets, uniforms))?;
        timer.end_frame(gl, &mut times);
    }
    timer.finish(gl, &mut times);
    Ok(median_p95(times.samples("composite")).0)
}

/// The probe at every setting, into the report (`probe` and its rows, the probe's checks) and
/// a markdown table on stderr and in `out`.
pub fn run(probe: Probe, s: &Settings, out: &Path, report: &mut Report) -> Result<()> {
    ensure!(s.rounds > 0, "--rounds: at least 1");
    if matches!(probe, Probe::OneProcess | Probe::GlStall) {
        return two_processes::run(probe, s, out, report);
    }
    let vk = VulkanContext::new(&common::RAY_TRACED_INTEROP)?;
    let gl = GlContext::headless(&vk.info, &common::base::gl::MEMORY_EXTENSIONS)?;
    common::connect(report, &vk, &gl)?;
    let largest = common::largest_size(&vk, &gl);
    for &size in &s.sizes {
        largest.check_flag("--sizes", "bench", size)?;
    }
    let handoff = Handoff::new(&vk, &gl)?;
    report.set("device", &vk.info.name);
    report.set("driver", &vk.info.driver);
    report.set("probe", probe);
    let mut table = String::from(match probe {
        Probe::Layouts => {
            "| scene | size | ids (R32UI) ms | normal and depth (RG32UI) ms |\n|---|---|---:|---:|\n"
        }
        Probe::Overlap => {
            "| scene | size | rays | GL during Vulkan ms | GL after Vulkan ms | GL's second pass alone ms |\n\
             |---|---|---:|---:|---:|---:|\n"
        }
        Probe::VulkanComposite => {
            "| scene | size | blur | GL compute ms | Vulkan compute ms | largest difference (1/255) |\n\
             |---|---|---:|---:|---:|---:|\n"
        }
        Probe::Patterns => {
            "| scene | size | `--pattern` | rays | AO ms | error | after blur |\n|---|---|---|---:|---:|---:|---:|\n"
        }
        Probe::OneProcess | Probe::GlStall => unreachable!("run by two_processes::run above"),
    });
    // Every probe but `patterns` draws the chapter's own pattern.
    let patterns = if probe == Probe::Patterns { s.patterns.clone() } else { vec![Pattern::Tile4x4] };
    let (mut rows, mut all_agree) = (Vec::new(), true);
    for &kind in &s.scenes {
        let scene = kind.build(s.ground)?;
        let shared = RayTracedScene::with_layout(&vk, &gl, &scene, TlasFlags::STATIC, BlasLayout::Flat)?;
        for &size in &s.sizes {
            let extent = vk::Extent2D { width: size.width, height: size.height };
            let setting = format!("| {} | {}x{} ", kind.name(), size.width, size.height);
            for (&pattern, &spp, &blur) in patterns
                .iter()
                .flat_map(|p| s.spps.iter().map(move |spp| (p, spp)))
                .flat_map(|(p, spp)| s.blurs.iter().map(move |blur| (p, spp, blur)))
            {
                let mut frame = Frame::new((&vk, &gl, &handoff), &shared, &scene, extent, (spp, pattern))?;
                let uniforms = Uniforms::new(blur, 2.0, View::Final, frame.camera.far);
                // Made after what the frames use: dropped first, it waits for their work.
                let commands = Commands::new(&vk)?;
                let apis = Apis { vk: &vk, gl: &gl, handoff: &handoff, commands: &commands };
                if probe != Probe::Patterns {
                    for _ in 0..s.frames {
                        frame.draw(apis, &uniforms)?;
                    }
                }
                let row = match probe {
                    Probe::Layouts => {
                        let (ids, normal_depth, same) =
                            layouts::measure(&gl, &frame, &shared.buffers, s.rounds)?;
                        all_agree &= same;
                        writeln!(table, "{setting}| {ids:.2} | {normal_depth:.2} |")?;
                        serde_json::json!({ "ids_r32ui_ms": ids, "normal_depth_rg32ui_ms": normal_depth })
                    }
                    Probe::Overlap => {
                        let (during, after, alone) = overlap::measure(apis, &mut frame, s.rounds)?;
                        writeln!(table, "{setting}| {spp} | {during:.2} | {after:.2} | {alone:.2} |")?;
                        serde_json::json!({ "gl_during_vulkan_ms": during, "gl_after_vulkan_ms": after, "gl_pass_alone_ms": alone })
                    }
                    Probe::VulkanComposite => {
                        let gl_ms = gl_composite_ms(&gl.gl, &frame, &uniforms, s.rounds)?;
                        let (vk_ms, largest) =
                            vk_composite::compare(apis, &shared.allocator, &frame, &uniforms, s.rounds)?;
                        // The same code, compiled by two drivers: rounding may differ (as the
                        // chapter's CPU check allows).
                        all_agree &= largest <= 2;
                        writeln!(table, "{setting}| {blur} | {gl_ms:.3} | {vk_ms:.3} | {largest} |")?;
                        serde_json::json!({ "gl_compute_ms": gl_ms, "vulkan_compute_ms": vk_ms, "largest_difference": largest })
                    }
                    Probe::Patterns => {
                        let m = patterns::measure(apis, &mut frame, &uniforms, s.frames, s.reference)?;
                        all_agree &= m.error_blurred < m.error_raw;
                        let name = serde_json::to_value(pattern)?;
                        let (ao, raw, blurred) = (m.ao_ms, m.error_raw, m.error_blurred);
                        writeln!(
                            table,
                            "{setting}| `{}` | {spp} | {ao:.2} | {raw:.4} | {blurred:.4} |",
                            name.as_str().unwrap_or("?")
                        )?;
                        serde_json::json!({ "ao_ms": ao, "error_raw": raw, "error_blurred": blurred })
                    }
                    Probe::OneProcess | Probe::GlStall => unreachable!("run by two_processes::run above"),
                };
                let at = serde_json::json!({ "scene": kind.name(), "width": size.width, "height": size.height, "spp": spp, "blur": blur, "pattern": pattern });
                rows.push(serde_json::json!({ "setting": at, "measured": row }));
                unsafe { glow::HasContext::finish(&*gl.gl) };
                vk.wait_idle()?; // once: no owner below waits
                drop(commands);
                drop(frame); // the composite, the tracer, the pass, then the images
            }
        }
        drop(shared);
    }
    match probe {
        Probe::Layouts => report.check("layouts_cover_the_same_pixels", all_agree),
        Probe::VulkanComposite => report.check("vulkan_composite_matches_gl", all_agree),
        Probe::Patterns => report.check("the_blur_lowers_every_error", all_agree),
        Probe::Overlap | Probe::OneProcess | Probe::GlStall => true,
    };
    report.check("hand_over_layouts_agreed", handoff.layouts_agreed());
    drop(handoff);
    gl.check_error("the probe")?;
    report.set("rows", rows);
    common::instruments::output::create_dir(out)?;
    let name = serde_json::to_value(probe)?.as_str().unwrap_or("probe").to_owned();
    let text = format!("Measured on {} ({}), {} rounds.\n\n{table}", vk.info.name, vk.info.driver, s.rounds);
    common::instruments::output::write_file(&out.join(format!("probe-{name}.md")), &text)?;
    eprintln!("{text}");
    Ok(())
}
