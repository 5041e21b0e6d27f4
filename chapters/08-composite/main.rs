//! Chapter 08: composite.
//!
//! The end of the road: GL shades the scene with its own albedo and Vulkan's ray-traced
//! occlusion, blurred without bleeding across edges, then draws lines (an axis gizmo and a
//! selected object's box) that the scene's surfaces hide correctly, because they are tested
//! against the depth GL rasterised the G-buffers with. In a window the camera orbits with the
//! mouse, and every change starts the occlusion's accumulation again.
//!
//! Run: `cargo run --release --bin 08-composite` (keys: 1-6 views, +/- rays, [/] radius,
//! B blur, P power, O overlays, F10 the panel, Esc quits; drag to orbit, wheel to zoom).

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::base::window::Key;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::frame::input::{resize_every, window_input};
use common::frame::{Composite, Overlays, View, panel};
use common::instruments::census::ResizeCensus;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::TlasFlags;
use common::rt::ao::{AoRays, AoTracer, rays_this_frame};
use common::scene::Camera;
use common::scene::gbuffer::{self, GBuffers};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

mod check;
mod settings;
use check::LastFrame;
use settings::{Args, Settings};

const CHAPTER: &str = "08-composite";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "the overlay checks need a pixel of the gizmo, with 2 pixels of room around it, behind a surface \
          and another in the open",
    shape: Some((f32::INFINITY, 2.0, "framed taller, the gizmo's axes leave the picture")),
};

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let mut size = args.common.size;

    // 1. Load the scene, and aim the camera at it
    let scene = args.scene.load()?;
    let mut camera = Camera::framing(scene.bounds, size.aspect());
    camera.orbit(0.0, 0.0, args.zoom, scene.bounds);
    let radius = args.ao.radius(&scene)?;
    let select = args.select.unwrap_or(if scene.instances.len() > 1 { 1 } else { 0 });
    ensure!(
        select < scene.instances.len(),
        "--select {select}: the scene has {} instances",
        scene.instances.len()
    );
    let mut settings = Settings {
        samples: args.ao.samples,
        radius,
        power: args.ao.power,
        blur: args.blur,
        view: args.view,
        overlays: true,
    };

    // 2. Vulkan, then GL: in a window when there is a display, headless otherwise
    // A size the device cannot hold the G-buffers at is refused here, before anything is allocated.
    let (vk, mut window, gl_context, handoff) =
        gbuffer::contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;

    // 3. Everything chapters 05-07 built: shared scene, acceleration structures, G-buffers, AO
    let shared = RayTracedScene::with_layout(&vk, &gl_context, &scene, TlasFlags::STATIC, args.blas)?;
    let storage = vk::ImageUsageFlags::STORAGE;
    let mut gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, size.extent(), storage)?;
    let mut tracer =
        AoTracer::new(&vk, &gl_context, &shared.allocator, *shared.structures.tlas.handle, &gbuffers)?;

    // 4. The composite pass and the overlays: GL only
    // ANCHOR: setup
    let mut composite = Composite::new(gl, &gbuffers, scene.bounds)?;
    let overlays = Overlays::new(gl, &scene, select)?;
    // ANCHOR_END: setup

    // 5. Every frame: input, G-buffers, rays, composite, overlays
    let frame_limit =
        if window.is_some() { args.common.window_frames() } else { args.common.headless_frames() };
    let mut frame = 0;
    let mut drew_a_frame = false;
    let (mut resizes, mut census) = (0, ResizeCensus::default());
    // Each pass's GPU time: GL's read when they arrive, the trace's once its fence has signalled
    // for the next frame's trace (the wait that frame makes anyway): timing adds no wait.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let timestamps = Timestamps::new(&vk)?;
    // Made after everything the traces use: an early return drops it first, and its Drop waits
    // for the last trace before the tracer or the G-buffers are destroyed.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let (mut trace_pending, mut traced) = (false, 0u64);
    let mut skipped = None;
    let views = View::ALL.map(|v| (v, v.name()));
    loop {
        // ANCHOR: input
        let new_size;
        if let Some(window) = window.as_mut() {
            let before = (settings, camera.eye);
            let apply_key = |key: &Key| {
                settings.apply_key(key, &View::ALL);
            };
            let Some(resized) =
                window_input(window, &gl_context, (&mut camera, scene.bounds), (size, 1), apply_key)
            else {
                break; // Esc, or the window closed
            };
            new_size = resized;
            // The panel: the same settings as controls, then what the frame shows of itself
            let accumulated = tracer.accumulated.to_string();
            window.panel(|ui| {
                panel::settings(ui, &mut settings, &views, radius / 8.0..=radius * 8.0, true);
                panel::values(ui, &[("sync", handoff.name().into()), ("rays a pixel", accumulated.clone())]);
                panel::pass_times(ui, &times);
            });
            // The running mean describes what each pixel showed, with this radius: a moved camera or
            // a new radius makes it describe something else. Rays per frame, blur and power do not.
            if settings.radius != before.0.radius || camera.eye != before.1 {
                tracer.reset();
            }
            if frame_limit > 0 && frame >= frame_limit {
                break;
            }
        } else if frame >= frame_limit {
            break;
        } else {
            // Headless, the same path a window's resize takes: three quarters, whole, half.
            new_size = resize_every(args.resize_every, frame, args.common.size, 8);
        }
        // ANCHOR_END: input
        // ANCHOR: resize
        if let Some(new) = new_size {
            // Every shared image is made anew at the new size, once the GPU is done with the old
            // ones (the reference sample leaked them and kept descriptors pointing at them).
            unsafe { gl.finish() };
            commands.wait(&vk, "vkWaitForFences before a resize")?;
            size = new;
            let fresh = GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, size.extent(), storage)?;
            let old = std::mem::replace(&mut gbuffers, fresh);
            tracer.resize(&vk, &gl_context, &gbuffers)?;
            composite.resize(gl, &gbuffers)?;
            drop(old); // GL's objects, then each image, GL's side first
            resizes += 1;
            census.count(&gl_context)?; // what exists after one resize must exist after every later one
        }
        // ANCHOR_END: resize
        // ANCHOR: frame
        let aspect = size.aspect();
        gl_timer.time(gl, "gbuffer", || gbuffers.draw(gl, &scene, &camera))?;
        if let Some(reason) = common::rt::ao::nothing_to_trace(settings.samples, settings.radius) {
            if skipped.replace(reason).is_none() {
                eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
            }
            tracer.fill_unoccluded(&vk, &gl_context, &handoff)?; // once per AO image
        } else if tracer.accumulated < args.ao.max_samples {
            // A window refines: its first picture after a change costs one ray a pixel, not 16.
            let refine = window.is_some();
            let samples = rays_this_frame(settings.samples, tracer.accumulated, args.ao.max_samples, refine);
            let scene_scale = scene.size() / 2.0;
            let rays = AoRays { samples, accumulated: 0, radius: settings.radius, scene_scale };
            if std::mem::take(&mut trace_pending) {
                common::clocks::timing::read_after(
                    &vk,
                    *commands.fence,
                    timestamps.as_ref(),
                    "ao_trace",
                    &mut times,
                )?;
            }
            tracer.trace(apis, &gbuffers, rays, timestamps.as_ref())?;
            traced += samples as u64 * (size.width * size.height) as u64;
            trace_pending = timestamps.is_some();
        }
        let uniforms = settings.uniforms(camera.far);
        gl_timer.time(gl, "composite", || composite.draw(gl, &gbuffers, &tracer, &uniforms))?;
        if settings.overlays {
            let view_projection = camera.view_projection(aspect);
            gl_timer.time(gl, "overlays", || overlays.draw(gl, &composite.target(), view_projection))?;
        }
        gl_timer.end_frame(gl, &mut times);
        // ANCHOR_END: frame
        if let Some(window) = &mut window {
            window.show_times(|| times.line());
            composite.show(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        times.frame_done();
        frame += 1;
        drew_a_frame = true;
    }
    if resizes > 0 {
        report.set("resizes", resizes);
    }
    // Open fds, the resources `common` counts, and every kind of GL object as GL counts them.
    census.check(&gl_context, report)?;
    if trace_pending {
        common::clocks::timing::read_after(
            &vk,
            *commands.fence,
            timestamps.as_ref(),
            "ao_trace",
            &mut times,
        )?;
    }
    gl_timer.finish(gl, &mut times);
    times.record(report);
    check::report_trace_times(report, times.samples("ao_trace"), traced);
    gl_context.check_error("the frame loop")?;

    // 6. Check the last frame: the composite against a CPU reference, the overlays' depth test
    if drew_a_frame {
        let last_frame = LastFrame {
            gl,
            gbuffers: &gbuffers,
            tracer: &tracer,
            composite: &composite,
            overlays: settings.overlays.then_some(&overlays),
            camera: &camera,
            uniforms: settings.uniforms(camera.far),
        };
        for (name, verdict) in last_frame.check(&overlays)? {
            report.verdict(name, verdict);
        }
        report.set("samples", settings.samples); // rays a pixel a frame, as the keys and panel left it
        report.set("samples_per_pixel", tracer.accumulated);
        if let Some(reason) = skipped {
            report.set("ao_skipped", reason);
        }
        report.set("radius", settings.radius);
        report.set("near_far_ratio", (camera.far / camera.near).round());
        report.set("blur", settings.blur);
        report.set("blas_layout", args.blas);
        report.set("frames", frame);
        if window.is_none() {
            let (out_dir, prefix) = (args.common.out_dir(CHAPTER), args.scene.picture_name(CHAPTER));
            let views = if args.all_views { View::ALL.to_vec() } else { vec![last_frame.uniforms.view] };
            last_frame.write_pictures(report, CHAPTER, &out_dir, &prefix, &views)?;
        }
    }

    common::interop::report_handoff(report, &handoff);
    // 7. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once, as the book's "Waiting before teardown" says
    drop(commands);
    drop(timestamps);
    drop(gl_timer);
    drop(overlays); // GL only: the lines' buffer and vertex array, the program
    drop(composite); // GL only: its target, vertex array and program
    drop(tracer); // the AO image (GL's side, then Vulkan's), then the pipeline
    drop(gbuffers);
    drop(shared); // the structures, then the shared buffers, each GL side first
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    if let Some(window) = &window {
        window.report_panel(report);
    }
    drop(window);
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
