//! Chapter 13: temporal reuse.
//!
//! Chapter 12's frame traces 16 new occlusion rays per pixel every frame and forgets them. Here
//! each pixel finds where the previous frame saw the same point (the previous camera, the moving
//! instance's previous transform), keeps that frame's occlusion if it saw the same surface, and
//! adds one or two new rays to it; a pixel just uncovered traces more, and a pixel whose history
//! is full traces less. The camera orbits, cuts to another view once, and one instance runs in a
//! circle. The frame is `common::frame::temporal`; `convergence temporal` measures it.
//!
//! Run: `cargo run --release --bin 13-temporal-reuse` (keys: H chapter 12's frame and back, Esc quits).

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::{Size, Smallest};
use common::base::commands::Commands;
use common::base::window::{Key, NamedKey, Window};
use common::clocks::timestamps::Timestamps;
use common::frame::Overlays;
use common::frame::fast::composite::{ComputeComposite, Uniforms, View};
use common::frame::fast::trace::SurfaceTracer;
use common::frame::fast::visibility::{self, Targets, VisibilityPass};
use common::frame::temporal::{Budget, Checks, Clock, Drawn, Motion, Passes, Sized, TemporalTracer, check};
use common::frame::temporal::{Path, PathArgs, RayArgs};
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, BuildInputs, InPlace, TlasFlags, instances_geometry};
use common::rt::ao::AoArgs;
use common::scene::gbuffer::contexts_in_window;
use common::scene::{Camera, Instance, SceneArgs};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

const CHAPTER: &str = "13-temporal-reuse";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "one compute group, and chapter 12's overlay checks need a pixel of the gizmo, with 2 pixels of room \
          around it, behind a surface and another in the open",
    shape: Some((
        4.0,
        2.0,
        "framed taller, the gizmo's axes leave the picture; wider, the overlay checks find no pixel to probe",
    )),
};
/// The frames a headless run draws unless `--frames` says otherwise: the whole path.
const PATH_FRAMES: u32 = 120;

/// Chapter 13: chapter 12's frame, its ambient occlusion reused from frame to frame.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    rays: RayArgs,
    #[command(flatten)]
    path: PathArgs,
    /// How far an occluder counts, in world units [default: 5% of the scene's diagonal].
    #[arg(long, value_parser = common::base::cli::number::<f32>(0.0..=1e6), allow_negative_numbers = true)]
    radius: Option<f32>,
    /// Contrast: the picture shows visibility to this power (1-3).
    #[arg(long, default_value_t = 2.0, value_parser = common::base::cli::number::<f32>(1.0..=3.0), allow_negative_numbers = true)]
    power: f32,
    /// Blur radius in pixels (0 skips the blur), as chapter 12's.
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=8))]
    blur: u32,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    view: View,
    /// As chapter 12's `--blas`; only the per-mesh layout lets an instance move.
    #[arg(long, value_enum, default_value = "per-mesh")]
    blas: BlasLayout,
    /// Headless: make the images of one size anew every K frames, as a window's resize does
    /// (the history starts again).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    resize_every: Option<u32>,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let size = args.common.size;

    // 1. The scene, the path the camera and one instance follow, and the rays' budget
    let mut scene = args.scene.load()?;
    let start = Camera::framing(scene.bounds, size.aspect());
    let path = Path::new(&scene, start, &args.path);
    if let Some(moving) = &path.moving {
        ensure!(
            args.blas == BlasLayout::PerMesh,
            "--blas flat holds every instance in one tree, so none can move: use --blas per-mesh, or --mover none"
        );
        // Where it stands at frame 0, before the scene is shared and its structures built.
        scene.instances[moving.index].transform = Instance::new(moving.at(0), [0; 3]).transform;
    }
    let ao = AoArgs { samples: args.rays.samples, radius: args.radius, power: args.power, max_samples: 1 };
    let radius = ao.radius(&scene)?;
    let budget = Budget::new(&args.rays, radius, scene.size() / 2.0);
    if let Some(reason) = common::rt::ao::nothing_to_trace(budget.fresh, radius) {
        eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
    }
    report.set("path", args.path.path);
    report.set("moving_instance", path.moving.as_ref().map(|m| m.index));

    // 2. Vulkan, then GL: in a window when there is a display, headless otherwise
    let (vk, mut window, gl_context, handoff) =
        contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;

    // 3. The shared scene and its structures; a TLAS that can be updated where an instance moves
    // ANCHOR: structures
    let flags = if path.moving.is_some() { TlasFlags::UPDATABLE } else { TlasFlags::STATIC };
    let shared = RayTracedScene::with_layout(&vk, &gl_context, &scene, flags, args.blas)?;
    let ids = visibility::number_triangles(&vk, &scene, &shared.buffers)?;
    let loader = &shared.structures.loader;
    let tlas = match path.moving {
        Some(_) => {
            let inputs = BuildInputs {
                handle: *shared.structures.tlas.handle,
                ty: vk::AccelerationStructureTypeKHR::TOP_LEVEL,
                flags: flags.0,
                geometry: instances_geometry(&vk, &shared.buffers.instances.vk),
                primitives: scene.instances.len() as u32,
            };
            Some(InPlace::new(&vk, &shared.allocator, loader, inputs)?)
        }
        None => None,
    };
    // ANCHOR_END: structures

    // 4. Chapter 12's images and passes, the history, and the command buffers
    let targets = Targets::new(&vk, &gl_context, &handoff, size.extent())?;
    let visibility = VisibilityPass::new(&gl_context, &shared.buffers)?;
    let fresh = SurfaceTracer::new(&vk, &shared, &ids, &targets)?;
    let temporal = TemporalTracer::new(&vk, &shared, fresh.mesh_table(), &targets, budget.fresh_pass)?;
    let mut sized = Sized { targets, fresh, temporal };
    let composite = ComputeComposite::new(gl)?;
    let overlays = Overlays::new(gl, &scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
    let timestamps = Timestamps::new(&vk)?;
    let updates = Commands::new(&vk)?;
    // Made after everything the frames use: an early return drops it first, and its Drop waits
    // for the last frame's Vulkan work before any of that is destroyed.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let passes = Passes {
        apis,
        scene: &scene,
        shared: &shared,
        ids: &ids,
        visibility: &visibility,
        composite: &composite,
        overlays: Some(&overlays),
        path: &path,
        motion: tlas.as_ref().map(|tlas| Motion {
            instances: &shared.buffers.instances.vk,
            tlas,
            loader,
            updates: &updates,
        }),
        timestamps: timestamps.as_ref(),
        ids_ahead: true, // the next frame's ids are drawn before the CPU waits (step 5)
        uniforms: Uniforms::new(args.blur, args.power, args.view, start.far),
        radius,
    };

    // 5. The frames: in a window until it closes, else the whole path, checked as it goes
    match window.as_mut() {
        Some(window) => in_window(&passes, &mut sized, window, budget, args.common.window_frames(), report)?,
        None => headless(&passes, &mut sized, budget, args, report)?,
    }
    gl_context.check_error("the frames")?;
    common::interop::report_handoff(report, &handoff);

    // 6. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once: no guard below waits
    drop(commands);
    drop(updates);
    drop(timestamps);
    drop(overlays);
    drop(composite);
    drop(sized); // the tracers' pipelines and history, then the images of one size
    drop(visibility);
    drop(tlas);
    drop(shared); // the structures, then the shared buffers, each GL side first
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}

// ANCHOR: headless
/// The whole path headless, each frame checked as it passes (`Checks`: the cut, the last frame);
/// with `--resize-every K`, new images every K frames, as a window's resize makes them.
fn headless(
    p: &Passes,
    sized: &mut Sized,
    budget: Budget,
    args: &Flags<Args>,
    report: &mut Report,
) -> Result<()> {
    let frames = args.common.frames.unwrap_or(PATH_FRAMES).max(1);
    let (out, prefix) = (args.common.out_dir(CHAPTER), args.scene.picture_name(CHAPTER));
    let mut checks = Checks { chapter: CHAPTER, frames, out, prefix, before_cut: None };
    let mut clock = Clock::new(&p.apis.gl.gl, None)?;
    let drawn = Drawn::Temporal(budget);
    let resized_at = |frame: u32| args.resize_every.filter(|k| frame > 0 && frame % k == 0);
    let (mut resizes, mut after_first_resize) = (0, None);
    for frame in 0..frames {
        if let Some(every) = resized_at(frame) {
            // Three quarters, whole, half, as chapter 12's `--resize-every`.
            let scale = |side: u32| (side * [2, 3, 4][(frame / every) as usize % 3] / 4).max(SMALLEST.width);
            let (w, h) = (args.common.size.width, args.common.size.height);
            p.resize(sized, Size { width: scale(w), height: scale(h) })?;
            resizes += 1;
            if after_first_resize.is_none() {
                after_first_resize = Some(check::alive(p)?);
            }
        }
        // The next frame's ids are drawn at the end of this one, before the CPU waits for its
        // trace, unless the checks read this frame back or the next has images of another size.
        let next = frame + 1 < frames && resized_at(frame + 1).is_none() && !checks.reads_back(p.path, frame);
        let camera = p.draw(sized, drawn, frame, &mut clock, next)?;
        checks.after(p, sized, (drawn, &camera, frame), report)?;
    }
    if let Some(first) = after_first_resize {
        report.check("nothing_grows_across_resizes", check::alive(p)? == first);
        report.set("resizes", resizes);
    }
    clock.finish(p)?;
    clock.times.record(report);
    report.set("frames_with_ids_drawn_ahead", clock.frames_drawn_ahead);
    report.set("frames", frames);
    eprintln!("walk: {} done ({frames} frames)", drawn.name());
    Ok(())
}
// ANCHOR_END: headless

/// Frames in a window until it closes (or `frames`, if not 0): the path plays on, H switches
/// between this chapter's frame and chapter 12's, and a new window size remakes the images.
fn in_window(
    p: &Passes,
    sized: &mut Sized,
    window: &mut Window,
    budget: Budget,
    frames: u32,
    report: &mut Report,
) -> Result<()> {
    let mut clock = Clock::new(&p.apis.gl.gl, None)?;
    let (ours, chapter_12) = (Drawn::Temporal(budget), Drawn::Fresh(16));
    let mut drawn = ours;
    let (mut frame, mut camera, mut resizes, mut after_first_resize) = (0, None, 0, None);
    while frames == 0 || frame < frames {
        let keys: Vec<Key> = window.poll(p.apis.gl).collect();
        if keys.contains(&Key::Named(NamedKey::Escape)) || window.close_requested() {
            break;
        }
        if keys.iter().any(|k| matches!(k.as_ref(), Key::Character("h" | "H"))) {
            drawn = if drawn == ours { chapter_12 } else { ours };
            sized.temporal.forget();
            eprintln!("window: {}", drawn.name());
        }
        let (width, height) = window.size();
        if (width, height) != (sized.targets.extent.width, sized.targets.extent.height)
            && width >= SMALLEST.width
            && height >= SMALLEST.height
        {
            p.resize(sized, Size { width, height })?;
            resizes += 1;
            if after_first_resize.is_none() {
                after_first_resize = Some(check::alive(p)?);
            }
        }
        // A window may change size before any frame: each frame draws its own ids.
        camera = Some(p.draw(sized, drawn, frame, &mut clock, false)?);
        window.show_times(|| clock.times.line());
        sized.targets.show(&p.apis.gl.gl, window.size());
        window.swap_buffers(p.apis.gl)?;
        frame += 1;
    }
    clock.finish(p)?;
    clock.times.record(report);
    report.set("frames", frame);
    report.set("resizes", resizes);
    if let Some(first) = after_first_resize {
        report.check("nothing_grows_across_resizes", check::alive(p)? == first);
    }
    if let Some(camera) = camera {
        check::chapter_12_checks(p, sized, &camera, CHAPTER, report)?;
    }
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
