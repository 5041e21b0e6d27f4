//! Chapter 09: animated instances.
//!
//! A ring of bunnies runs in a circle. Each frame the CPU writes their transforms into the
//! instance buffer that GL draws from and the TLAS is built from; Vulkan updates the TLAS in
//! place (no new tree, no allocation), traces ambient occlusion against it, and GL composites.
//! The report measures what an update costs against a rebuild, and what it costs the rays. In a
//! window the ring runs on the wall clock; headless, at `--time` + frame x `--step`.
//!
//! Run: `cargo run --release --bin 09-animated-instances` (keys: Space stops and starts the ring,
//! +/- rays, F10 the panel, Esc quits; drag to orbit, wheel to zoom).

use anyhow::Result;
use ash::vk;
use common::base::cli::AnimationArgs;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::base::window::Key;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::frame::input::window_input;
use common::frame::panel::{self, Control};
use common::frame::playback::{self, Playback};
use common::frame::{Composite, Uniforms};
use common::instruments::output;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BuildInputs, InPlace, Refresh, TlasFlags, instances_geometry};
use common::rt::ao::{AoArgs, AoRays, AoTracer, rays_this_frame};
use common::scene::Camera;
use common::scene::gbuffer::{self, GBuffers};
use common::{Flags, RAY_TRACED_INTEROP, Report, VulkanContext, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

mod ring;

const CHAPTER: &str = "09-animated-instances";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 16,
    height: 16,
    why: "1% of the pixels must change between the first and the last frame",
    shape: Some((
        4.0,
        4.0,
        "framed wider or taller, the ring covers too few pixels for 1% of the picture to change",
    )),
};

/// Chapter 09: a TLAS updated in place as instances move.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    ao: AoArgs,
    /// The model that runs in the ring [default: the tutorial's assets/bunny.obj].
    #[arg(long)]
    model: Option<std::path::PathBuf>,
    /// How many run in the ring (2 to 1000).
    #[arg(long, default_value_t = 20, value_parser = common::base::cli::number::<u32>(2..=1000))]
    count: u32,
    /// Seconds per lap (0.01 to 100000).
    #[arg(long, default_value_t = 10.0, value_parser = common::base::cli::number::<f32>(0.01..=1e5), allow_negative_numbers = true)]
    lap: f32,
    #[command(flatten)]
    animation: AnimationArgs,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    // 1. Make the ring, as it stands at the first frame
    // A model given is found from the current directory; the default, from the checkout.
    let model = match &args.model {
        Some(path) => path.clone(),
        None => common::scene::default_asset("bunny.obj", "--model")?,
    };
    let (scene, ring) = ring::scene(&model, args.count, args.lap, args.animation.time)?;
    let mut size = args.common.size;
    let mut camera = Camera::framing(scene.bounds, size.aspect());
    let radius = args.ao.radius_to_trace(&scene)?;
    report.set("runners", ring.count);
    report.set("ring_radius", (ring.radius as f64 * 1e3).round() / 1e3);

    // 2. Both contexts (GL in a window when there is a display), the shared scene, and a TLAS
    // that may be updated
    let (vk, mut window, gl_context, handoff) =
        gbuffer::contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    let update_timer = Timestamps::new(&vk)?; // before `updates`, whose submissions write it
    // ANCHOR: updatable
    // As chapter 06 built it, plus ALLOW_UPDATE. Then what updating it in place needs: the
    // geometry it was built from (the shared instance buffer) and one scratch buffer for good.
    let shared = RayTracedScene::with_tlas(&vk, &gl_context, &scene, TlasFlags::UPDATABLE)?;
    let instances = &shared.buffers.instances.vk;
    let inputs = BuildInputs {
        handle: *shared.structures.tlas.handle,
        ty: vk::AccelerationStructureTypeKHR::TOP_LEVEL,
        flags: TlasFlags::UPDATABLE.0,
        geometry: instances_geometry(&vk, instances),
        primitives: scene.instances.len() as u32,
    };
    let tlas = InPlace::new(&vk, &shared.allocator, &shared.structures.loader, inputs)?;
    // The updates get a command buffer of their own, submitted before each frame's trace.
    let updates = Commands::new(&vk)?;
    // ANCHOR_END: updatable
    report.set("update_scratch_bytes", tlas.update_scratch_bytes);
    report.set("build_scratch_bytes", tlas.build_scratch_bytes);

    // 3. G-buffers, the AO tracer and chapter 08's composite
    let storage = vk::ImageUsageFlags::STORAGE;
    let mut gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, size.extent(), storage)?;
    let tlas_handle = *shared.structures.tlas.handle;
    let mut tracer = AoTracer::new(&vk, &gl_context, &shared.allocator, tlas_handle, &gbuffers)?;
    let mut composite = Composite::new(gl, &gbuffers, scene.bounds)?;
    let uniforms = Uniforms::final_picture(args.ao.power, camera.far);
    let trace_timer = Timestamps::new(&vk)?;
    // Made after everything the traces use: an early return drops it first, and its Drop waits
    // for the last trace before the tracer or the G-buffers are destroyed.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };

    // 4. Every frame: the window's input, move the runners, update the TLAS, draw, trace, composite
    let frame_limit =
        if window.is_some() { args.common.window_frames() } else { args.common.headless_frames() };
    let scene_scale = scene.size() / 2.0;
    let mut rebuild_every = args.animation.rebuild_every;
    // Each pass's GPU time (common::clocks::timing): GL's read when they arrive, Vulkan's after the wait
    // at the top of the next frame, which the frame makes anyway.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let mut last_refresh = None;
    let (mut tlas_updates, mut tlas_rebuilds) = (0u32, 0u32);
    let mut pictures = Vec::new();
    // In a window the ring runs on the wall clock, unless Space (or `--step 0`) stopped it.
    let mut playback = Playback::new(args.animation.step, args.ao.samples);
    let (mut time, mut traced_at, mut frame) = (args.animation.time, None, 0);
    loop {
        if let Some(window) = window.as_mut() {
            let eye = camera.eye;
            let keys = |key: &Key| playback.key(key);
            let Some(resized) =
                window_input(window, &gl_context, (&mut camera, scene.bounds), (size, 1), keys)
            else {
                break; // Esc, or the window closed
            };
            let values = [
                ("sync", handoff.name().to_owned()),
                ("runners", ring.count.to_string()),
                ("time", format!("{time:.2} s")),
                ("TLAS updates", tlas_updates.to_string()),
                ("TLAS rebuilds", tlas_rebuilds.to_string()),
                ("rays a pixel", tracer.accumulated.to_string()),
            ];
            window.panel(|ui| {
                let rebuild = ("rebuild every", Control::Count(&mut rebuild_every, 0..=60), "0: update");
                playback.controls(ui, [rebuild]);
                panel::values(ui, &values);
                panel::pass_times(ui, &times);
            });
            if frame_limit > 0 && frame >= frame_limit {
                break;
            }
            playback.advance(&mut time);
            if camera.eye != eye {
                tracer.reset(); // the mean is of what the pixels showed from where the camera was
            }
            if let Some(new) = resized {
                size = new; // every image anew, as chapter 08 resizes
                let frame_parts = (&mut gbuffers, &mut tracer, &mut composite);
                playback::resize(apis, (&shared.buffers, storage), frame_parts, size)?;
            }
        } else if frame >= frame_limit {
            break;
        } else {
            time = args.animation.at(frame);
        }
        // ANCHOR: frame
        // The previous frame's Vulkan work is done: its trace, the TLAS update submitted before
        // it, and (the trace having waited for it) GL's draw. Nothing reads the instance
        // buffer now, so the CPU may write it. (The trace's own `begin` would wait here anyway.)
        commands.wait(&vk, "vkWaitForFences for the previous frame")?;
        read_times(&vk, last_refresh.take(), &update_timer, &trace_timer, &mut times)?;
        ring.write(instances, time);
        let refresh = match rebuild_every {
            k if k > 0 && frame > 0 && frame % k == 0 => Refresh::Rebuild,
            _ => Refresh::Update,
        };
        tlas.submit(&vk, &updates, &shared.structures.loader, refresh, update_timer.as_ref())?;
        gl_timer.time(gl, "gbuffer", || gbuffers.draw(gl, &scene, &camera))?;
        // Anything that moved changes the occlusion around it: the running mean is of a
        // picture that is gone. Start it again (standing still, it accumulates).
        if traced_at.replace(time).is_some_and(|before| before != time) {
            tracer.reset();
        }
        // A window refines: one ray a pixel while the ring runs, more once it stands still (and
        // none once a still ring has `--max-samples`).
        let samples =
            rays_this_frame(playback.samples, tracer.accumulated, args.ao.max_samples, window.is_some());
        if samples > 0 {
            let rays = AoRays { samples, accumulated: 0, radius, scene_scale };
            tracer.trace(apis, &gbuffers, rays, trace_timer.as_ref())?;
        }
        gl_timer.time(gl, "composite", || composite.draw(gl, &gbuffers, &tracer, &uniforms))?;
        gl_timer.end_frame(gl, &mut times);
        // ANCHOR_END: frame
        if let Some(window) = &mut window {
            window.show_times(|| times.line());
            composite.show(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        times.frame_done();
        match refresh {
            Refresh::Update => tlas_updates += 1,
            Refresh::Rebuild => tlas_rebuilds += 1,
        }
        last_refresh = Some((refresh, samples > 0));
        if window.is_none() && (frame == 0 || frame + 1 == frame_limit || args.animation.every_frame) {
            let upright = output::flip_rows(&composite.read(gl), size.width, size.height);
            pictures.push((frame, upright));
        }
        frame += 1;
    }
    commands.wait(&vk, "vkWaitForFences after the last frame")?;
    read_times(&vk, last_refresh, &update_timer, &trace_timer, &mut times)?;
    gl_timer.finish(gl, &mut times);
    gl_context.check_error("the frame loop")?;
    // Headless, each frame stands for `--step` seconds; a window's, for the time it ran.
    let seconds_run =
        if window.is_some() { time - args.animation.time } else { args.animation.step * frame as f32 };
    report.set("frames", frame);
    report.set("samples_per_pixel", tracer.accumulated);
    report.set("tlas_updates", tlas_updates);
    report.set("tlas_rebuilds", tlas_rebuilds);
    report.set(
        "rebuild_policy",
        match rebuild_every {
            0 => "never: update every frame".to_owned(),
            k => format!("rebuild every {k} frames, update in between"),
        },
    );
    report.set("lengths_travelled", (ring.lengths_travelled(seconds_run) as f64 * 100.0).round() / 100.0);

    // 5. Check the last frame's occlusion, the motion, and write the frames (headless)
    let (w, h) = (size.width, size.height);
    common::rt::ao::check_occlusion(report, gl, &gbuffers, &tracer);
    if window.is_some() {
        playback.report(report); // the motion not judged, the rays a frame the keys left
    } else {
        let moved = frame > 1 && args.animation.step > 0.0; // then the frames must show it
        output::save_frames(report, &args.common.out_dir(CHAPTER), CHAPTER, (w, h), &pictures, moved)?;
    }

    // 6. Measure: the same rays through the updated TLAS, then through a rebuilt one
    // ANCHOR: measure
    // The AO shader's rays depend only on the pixel and the sample index: with the running mean
    // restarted, both traces cast exactly the same rays, and must find the same occluders.
    let rays = AoRays { samples: args.ao.samples, accumulated: 0, radius, scene_scale };
    gbuffers.draw(gl, &scene, &camera);
    let (after_updates, updated_ms) = tracer.trace_once(apis, &gbuffers, rays, trace_timer.as_ref())?;
    tlas.submit(&vk, &updates, &shared.structures.loader, Refresh::Rebuild, update_timer.as_ref())?;
    gbuffers.draw(gl, &scene, &camera);
    let (after_rebuild, rebuilt_ms) = tracer.trace_once(apis, &gbuffers, rays, trace_timer.as_ref())?;
    let differing = after_updates.iter().zip(&after_rebuild).filter(|(a, b)| a != b).count();
    report.set("pixels_differing_updated_vs_rebuilt", differing);
    // A stale or corrupted update would put occluders where the runners were, not where they are.
    report.check("updated_tlas_traces_like_a_rebuilt_one", differing * 1000 <= (w * h) as usize);
    // ANCHOR_END: measure
    if let Some(u) = &update_timer {
        times.add("tlas_rebuild", u.read_ms(&vk)?);
    }
    times.record(report);
    let said = ["trace through the updated TLAS", "through a rebuilt one"];
    AoTracer::report_traces(report, "updates", said, (updated_ms, rebuilt_ms));

    common::interop::report_handoff(report, &handoff);
    // 7. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once, for the traces and the updates
    drop(gl_timer);
    drop(commands);
    drop((trace_timer, update_timer));
    drop(composite);
    drop(tracer); // the AO image (GL's side, then Vulkan's), then the pipeline
    drop(gbuffers);
    drop(updates); // the updates' command buffer
    drop(tlas); // the in-place update's scratch buffer (the TLAS is `shared`'s)
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

/// Adds the GPU times of the frame whose fence has signalled: its TLAS refresh and, if it traced
/// (`.1`), its trace.
fn read_times(
    vk: &VulkanContext,
    last: Option<(Refresh, bool)>,
    update_timer: &Option<Timestamps>,
    trace_timer: &Option<Timestamps>,
    times: &mut PassTimes,
) -> Result<()> {
    if let (Some((refresh, traced)), Some(u), Some(t)) = (last, update_timer, trace_timer) {
        times.add(if refresh == Refresh::Update { "tlas_update" } else { "tlas_rebuild" }, u.read_ms(vk)?);
        if traced {
            times.add("ao_trace", t.read_ms(vk)?);
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
