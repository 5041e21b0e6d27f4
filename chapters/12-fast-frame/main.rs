//! Chapter 12: the fast frame.
//!
//! Chapter 08's picture, drawn for speed. GL writes one 32-bit id per pixel instead of 36 bytes
//! of G-buffers; Vulkan's ray generation shader rebuilds the exact hit point and normal from the
//! scene's shared buffers and traces the occlusion; a GL compute shader blurs and composites;
//! the overlays are drawn over it, tested against the id pass's depth. Each choice is measured
//! by `bench` (the book's deeper page for this chapter says which command measures which).
//!
//! Run: `cargo run --release --bin 12-fast-frame` (keys: 1-5 views, +/- rays, [/] radius,
//! B blur, P power, O overlays, T sample pattern, Esc quits; drag to orbit, wheel to zoom).

use anyhow::Result;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::base::window::Key;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes, read_after};
use common::frame::input::{Settings as Keys, resize_every, window_input};
use common::frame::{Overlays, panel};
use common::instruments::census::ResizeCensus;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::TlasFlags;
use common::rt::ao::rays_this_frame;
use common::scene::Camera;
use common::scene::gbuffer::contexts_in_window;
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use fast_frame::check;
use fast_frame::composite::{ComputeComposite, View};
use fast_frame::trace::SurfaceTracer;
use fast_frame::visibility::{self, Targets, VisibilityPass};
use glow::HasContext;
use std::process::ExitCode;

mod settings;
use settings::{Args, Settings};

const CHAPTER: &str = "12-fast-frame";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "one compute group, and the overlay checks need a pixel of the gizmo, with 2 pixels of room around \
          it, behind a surface and another in the open",
    shape: Some((
        4.0,
        2.0,
        "framed taller, the gizmo's axes leave the picture; wider, its per-pixel AO strays from chapter 08's",
    )),
};
/// The smallest side a window's resize (or `--resize-every`) draws at.
const SMALLEST_SIDE: u32 = SMALLEST.width;

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let mut size = args.common.size;

    // 1. Load the scene, and aim the camera at it
    let scene = args.scene.load()?;
    let mut camera = Camera::framing(scene.bounds, size.aspect());
    camera.orbit(0.0, 0.0, args.zoom, scene.bounds);
    let radius = args.ao.radius(&scene)?;
    let keys = Keys {
        samples: args.ao.samples,
        radius,
        power: args.ao.power,
        blur: args.blur,
        view: args.view,
        overlays: true,
    };
    let mut settings = Settings { keys, pattern: args.pattern };

    // 2. Vulkan, then GL: in a window when there is a display, headless otherwise
    let (vk, mut window, gl_context, handoff) =
        contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;

    // 3. The shared scene and its structures (chapters 05-06), every triangle numbered
    let shared = RayTracedScene::with_layout(&vk, &gl_context, &scene, TlasFlags::STATIC, args.blas)?;
    let ids = visibility::number_triangles(&vk, &scene, &shared.buffers)?;

    // 4. The images of one size, and the three passes: ids (GL), rays (Vulkan), composite (GL)
    // ANCHOR: setup
    let mut targets = Targets::new(&vk, &gl_context, &handoff, size.extent())?;
    let visibility = VisibilityPass::new(&gl_context, &shared.buffers)?;
    let mut tracer = SurfaceTracer::new(&vk, &shared, &ids, &targets)?;
    let composite = ComputeComposite::new(gl)?;
    let overlays = Overlays::new(gl, &scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
    // ANCHOR_END: setup

    // 5. Every frame: input, ids, rays, composite, overlays
    let frame_limit =
        if window.is_some() { args.common.window_frames() } else { args.common.headless_frames() };
    let (mut frame, mut resizes, mut census) = (0, 0, ResizeCensus::default());
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let timestamps = Timestamps::new(&vk)?;
    let mut trace_pending = false; // a trace submitted, its GPU time not read yet
    // Made after everything the frames use: an early return drops it first, and its Drop waits
    // for the last frame's Vulkan work before any of that is destroyed.
    let commands = Commands::new(&vk)?;
    let skipped = common::rt::ao::nothing_to_trace(settings.samples, settings.radius);
    if let Some(reason) = skipped {
        eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
    }
    let views = View::ALL.map(|v| (v, v.name()));
    loop {
        let mut new_size = None;
        if let Some(window) = window.as_mut() {
            let before = (settings, camera.eye);
            let apply_key = |key: &Key| settings::apply_key(key, &mut settings);
            let Some(resized) = window_input(
                window,
                &gl_context,
                (&mut camera, scene.bounds),
                (size, SMALLEST_SIDE),
                apply_key,
            ) else {
                break; // Esc, or the window closed
            };
            new_size = resized;
            let accumulated = tracer.accumulated.to_string();
            window.panel(|ui| {
                panel::settings(ui, &mut settings.keys, &views, radius / 8.0..=radius * 8.0, true);
                let pattern = format!("{:?} (T)", settings.pattern).to_lowercase();
                let values = [
                    ("pattern", pattern),
                    ("sync", handoff.name().into()),
                    ("rays a pixel", accumulated.clone()),
                ];
                panel::values(ui, &values);
                panel::pass_times(ui, &times);
            });
            // A new camera, radius or sample pattern makes the running mean describe another thing.
            let changed = (settings.radius, settings.pattern) != (before.0.radius, before.0.pattern);
            if changed || camera.eye != before.1 {
                tracer.accumulated = 0;
            }
        }
        if frame_limit > 0 && frame >= frame_limit {
            break;
        }
        if window.is_none() {
            // Three quarters, whole, half, as chapter 08's `--resize-every`.
            new_size = resize_every(args.resize_every, frame, args.common.size, SMALLEST_SIDE);
        }
        // ANCHOR: resize
        if let Some(new) = new_size {
            // Every image of the old size goes, once neither API uses it; the rest stays.
            unsafe { gl.finish() };
            commands.wait(&vk, "vkWaitForFences before a resize")?;
            size = new;
            drop(std::mem::replace(&mut targets, Targets::new(&vk, &gl_context, &handoff, size.extent())?));
            tracer.resized(&vk, &targets);
            resizes += 1;
            census.count(&gl_context)?; // what exists after one resize must exist after every later one
        }
        // ANCHOR_END: resize
        // ANCHOR: frame
        gl_timer
            .time(gl, "visibility", || visibility.draw(gl, &targets.ids_target(), &scene, &ids, &camera))?;
        if tracer.accumulated < args.ao.max_samples || skipped.is_some() {
            let samples = if skipped.is_some() {
                0
            } else {
                // A window refines: its first picture after a change costs one ray a pixel.
                let refine = window.is_some();
                rays_this_frame(settings.samples, tracer.accumulated, args.ao.max_samples, refine)
            };
            let rays = settings.rays(samples, scene.size() / 2.0);
            if std::mem::take(&mut trace_pending) {
                // The last trace's time: `trace` waits for its fence anyway (one command buffer).
                read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
            }
            let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
            tracer.trace(apis, &targets, &camera, rays, timestamps.as_ref())?;
            trace_pending = true;
        }
        let uniforms = settings.uniforms(camera.far);
        gl_timer.time(gl, "composite", || composite.draw(gl, &targets, &uniforms))?;
        if settings.overlays {
            let view_projection = camera.view_projection(size.aspect());
            gl_timer
                .time(gl, "overlays", || overlays.draw(gl, &targets.overlay_target(), view_projection))?;
        }
        gl_timer.end_frame(gl, &mut times);
        // ANCHOR_END: frame
        if let Some(window) = &mut window {
            window.show_times(|| times.line());
            targets.show(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        times.frame_done();
        frame += 1;
    }
    if trace_pending {
        read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
    }
    gl_timer.finish(gl, &mut times);
    times.record(report);
    gl_context.check_error("the frame loop")?;
    census.check(&gl_context, report)?;

    // 6. Check the last frame, and the lean frame against chapter 08's on the same rays
    // ANCHOR: checks
    let (accumulated, scene_scale) = (tracer.accumulated, scene.size() / 2.0);
    let rays = settings.rays(if skipped.is_some() { 0 } else { settings.samples }, scene_scale);
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let drawn = check::Drawn {
        scene: &scene,
        shared: &shared,
        targets: &targets,
        composite: &composite,
        overlays: &overlays,
        camera: &camera,
        uniforms: settings.uniforms(camera.far),
        rays,
        accumulated,
        frames: frame,
    };
    let pictures = window.is_none().then(|| (args.common.out_dir(CHAPTER), args.scene.picture_name(CHAPTER)));
    let asked = check::Asked { chapter: CHAPTER, pictures, error_against: args.error_against };
    check::after_the_frames(apis, drawn, &mut tracer, asked, report)?;
    // ANCHOR_END: checks
    report.set("samples_per_pixel", accumulated);
    report.set("triangle_ids", ids.iter().map(|m| m.triangles as u64 * m.instances as u64).sum::<u64>());
    report.set("frames", frame);
    report.set("resizes", resizes);
    report.set("pattern", settings.pattern);
    common::interop::report_handoff(report, &handoff);

    // 7. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once, as the book's "Waiting before teardown" says
    drop(commands);
    drop(timestamps);
    drop(gl_timer);
    drop(overlays);
    drop(composite);
    drop(tracer); // the pipeline, then the mesh table
    drop(visibility);
    drop(targets);
    drop(shared); // the structures, then the shared buffers, each GL side first
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
