//! Chapter 13: temporal reuse.
//!
//! Chapter 12's frame traces 16 new occlusion rays per pixel every frame and forgets them. Here
//! each pixel finds where the previous frame saw the same point (the previous camera, the moving
//! instance's previous transform), keeps that frame's occlusion if it saw the same surface, and
//! adds one or two new rays to it; a pixel just uncovered traces more, and a pixel whose history
//! is full traces less. The camera orbits, cuts to another view once, and one instance runs in a
//! circle; every frame's error is measured against a converged trace of that frame.
//!
//! Run: `cargo run --release --bin 13-temporal-reuse` (keys: H history on/off, Esc quits).

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::{Size, Smallest};
use common::base::commands::Commands;
use common::clocks::timestamps::Timestamps;
use common::frame::Overlays;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, BuildInputs, InPlace, TlasFlags, instances_geometry};
use common::rt::ao::AoArgs;
use common::scene::gbuffer::contexts_in_window;
use common::scene::{Camera, Instance};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

mod frame;
mod history_check;
mod measure;
mod path;
mod settings;
mod temporal;
mod walk;

use common::frame::fast::composite::{ComputeComposite, Uniforms};
use common::frame::fast::trace::SurfaceTracer;
use common::frame::fast::visibility::{self, Targets, VisibilityPass};
use frame::{Drawn, Motion, Passes, Sized};
use settings::{Args, Method};
use temporal::{Budget, TemporalTracer};

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

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    ensure!(
        !(args.compare && args.resize_every.is_some()),
        "--compare walks every method at one size: leave out --resize-every"
    );
    let size = args.common.size;
    // Read first: a file that is not there or not a compare.csv is refused before any GPU work.
    let times = args.times_from.as_deref().map(measure::read_times).transpose()?;

    // 1. The scene, the path the camera and one instance follow, and the rays' budget
    let mut scene = args.scene.load()?;
    let start = Camera::framing(scene.bounds, size.aspect());
    let path = path::Path::new(&scene, start, args);
    if let Some(moving) = &path.moving {
        ensure!(
            args.blas == BlasLayout::PerMesh,
            "--blas flat holds every instance in one tree, so none can move: use --blas per-mesh, or --mover none"
        );
        // Where it stands at frame 0, before the scene is shared and its structures built.
        scene.instances[moving.index].transform = Instance::new(moving.at(0), [0; 3]).transform;
    }
    let ao = AoArgs { samples: args.samples, radius: args.radius, power: args.power, max_samples: 1 };
    let radius = ao.radius(&scene)?;
    let budget = Budget::new(args, radius, scene.size() / 2.0);
    if let Some(reason) = common::rt::ao::nothing_to_trace(budget.fresh, radius) {
        eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
    }
    report.set("path", args.path);
    report.set("fresh_pass", args.fresh_pass);
    report.set("next_ids", args.next_ids);
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
    let temporal = TemporalTracer::new(&vk, &shared, fresh.mesh_table(), &targets, args.fresh_pass)?;
    let mut sized = Sized { targets, fresh, temporal };
    let composite = ComputeComposite::new(gl)?;
    let overlays = Overlays::new(gl, &scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
    let timestamps = Timestamps::new(&vk)?;
    let updates = Commands::new(&vk)?;
    // Made after everything the frames use: an early return drops it first, and its Drop waits
    // for the last frame's Vulkan work before any of that is destroyed.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let uniforms = Uniforms::new(args.blur, args.power, args.view, start.far);
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
        ids_ahead: args.next_ids == settings::NextIds::Early,
        uniforms,
        radius,
    };
    let chosen = match args.method {
        Method::Temporal => Drawn::Temporal(budget),
        Method::Fresh => Drawn::Fresh(args.samples),
    };

    // 5. The frames: in a window until it closes, else the path, once per method compared
    if let Some(window) = window.as_mut() {
        walk::in_window(&passes, &mut sized, window, chosen, args.common.window_frames(), report)?;
    } else {
        let mut walks = walk::headless(&passes, &mut sized, chosen, args, report)?;
        if let Some(times) = &times {
            measure::take_times(&mut walks, times, path.cut())?;
        }
        if args.compare {
            let table = measure::write(&args.common.out_dir(CHAPTER), &walks, path.cut(), &vk.info.name)?;
            eprint!("{table}");
        }
        if args.error_against > 0 || args.compare {
            report.set("walks", &walks); // frame by frame: times and errors
        }
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

/// A new window size: every image of the old size goes, once neither API uses it, and the
/// tracers point at the new ones (the history starts again).
pub fn resize(passes: &Passes, sized: &mut Sized, size: Size) -> Result<()> {
    let Apis { vk, gl, commands, .. } = passes.apis;
    unsafe { gl.gl.finish() };
    commands.wait(vk, "vkWaitForFences before a resize")?;
    drop(std::mem::replace(&mut sized.targets, Targets::new(vk, gl, passes.apis.handoff, size.extent())?));
    sized.fresh.resized(vk, &sized.targets);
    sized.temporal.resized(vk, &passes.shared.allocator, &sized.targets)
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
