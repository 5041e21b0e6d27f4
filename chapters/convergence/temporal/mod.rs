//! `convergence temporal`: chapter 13's frame (`common::frame::temporal`) walked along its path
//! headless, with the choices the chapter makes undone one at a time, and measured: each frame's
//! error after the blur against a converged trace of that frame, its GPU and wall-clock times,
//! and with `--compare` the methods side by side (compare.md, compare.csv and two plots).
//!
//! Run: `cargo run --release --bin convergence -- temporal --size 1920x1080 --compare
//! --error-against 1024 --error-every 4` (the page's tables name their own flags).

mod measure;
mod walk;

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::clocks::timestamps::Timestamps;
use common::frame::Overlays;
use common::frame::fast::composite::{ComputeComposite, Uniforms, View};
use common::frame::fast::trace::SurfaceTracer;
use common::frame::fast::visibility::{self, Targets, VisibilityPass};
use common::frame::temporal::tracer::accept_bits;
use common::frame::temporal::{Accept, Budget, Drawn, FreshPass, Motion, Passes, Sized, TemporalTracer};
use common::frame::temporal::{Path, PathArgs, RayArgs};
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, BuildInputs, InPlace, TlasFlags, instances_geometry};
use common::rt::ao::AoArgs;
use common::scene::gbuffer::contexts_in_window;
use common::scene::{Camera, Instance, SceneArgs};
use common::{CommonArgs, Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

/// The name the tool's report, its output folder and its pictures take.
const NAME: &str = "13-temporal-reuse";
/// Chapter 13's smallest picture (its checks run here too).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "chapter 13's checks need a pixel of the gizmo, with 2 pixels of room around it, behind a surface \
          and another in the open",
    shape: Some((4.0, 2.0, "framed taller or wider, chapter 13's overlay checks find no pixel to probe")),
};

/// `convergence temporal`: chapter 13's frame along its path, its choices varied, its error and
/// times measured. Headless always.
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
    /// As chapter 12's `--blas`; only the per-mesh layout lets an instance move.
    #[arg(long, value_enum, default_value = "per-mesh")]
    blas: BlasLayout,
    /// Which tests a remembered texel must pass to be reused (`none`: every texel is reused, so
    /// moving things leave ghosts; for measuring what the tests are worth).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "instance,plane,normal")]
    accept: Vec<Accept>,
    /// Which points of the sample sequence each pixel takes: chapter 12's 4x4 blocks, carried on
    /// from frame to frame, or chapter 07's rotation per pixel (a still camera then traces
    /// chapter 08's very rays).
    #[arg(long, value_enum, default_value = "tile4x4")]
    pattern: Pattern,
    /// Where a pixel with nothing remembered traces its `--fresh` rays: `packed`, in a second
    /// launch, one ray per invocation, over the pixels the first listed; `inline`, in the one
    /// launch, where its warp waits for them while its neighbours trace a few. The same rays
    /// either way, so the same picture.
    #[arg(long, value_enum, default_value = "packed")]
    fresh_pass: FreshPass,
    /// When GL draws the next frame's ids: `early`, at the end of this frame, before the CPU
    /// waits for this frame's trace (chapter 13's); `late`, after that wait, as chapter 12 does.
    /// The same pictures either way.
    #[arg(long, value_enum, default_value = "early")]
    next_ids: NextIds,
    /// `temporal`: chapter 13's frame; `fresh`: chapter 12's, new rays every frame and nothing
    /// kept, drawn along the same path for comparison.
    #[arg(long, value_enum, default_value = "temporal")]
    method: Method,
    /// After every `--error-every`th frame, trace this many rays per pixel of the same frame with
    /// no history, and report the frame's error against them after the blur (0: don't; 1024 is
    /// the book's reference).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=1 << 16))]
    error_against: u32,
    /// Measure the error on every Kth frame of the path (the frames around the cut always).
    #[arg(long, default_value_t = 1, value_parser = common::base::cli::number::<u32>(1..=1000))]
    error_every: u32,
    /// The last N frames' passes, GL's and Vulkan's on one clock, into timeline.json and
    /// timeline.svg in --out, as chapter 12's (0: none).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=64))]
    timeline: u32,
    /// Draw the path again with chapter 12's frame at 16, 8 and 4 rays and chapter 13's at 1, 2
    /// and 4, each timed and (with --error-against) measured, and write compare.md, compare.csv
    /// and compare.svg to --out.
    #[arg(long)]
    compare: bool,
    /// With --compare: each method's times in the table and in the plot of error against time
    /// come from this compare.csv, written by a run without --error-against (whose read-backs
    /// between frames, and FLIP on the CPU, slow the GPU).
    #[arg(long, requires = "compare")]
    times_from: Option<std::path::PathBuf>,
}

/// Which points of the sequence a pixel's rays take (`--pattern`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
enum Pattern {
    Tile4x4,
    PerPixel,
}

/// When GL draws the next frame's ids (`--next-ids`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
enum NextIds {
    Early,
    Late,
}

/// How a frame's occlusion is made (`--method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
enum Method {
    Temporal,
    Fresh,
}

/// `convergence temporal ...`: `args` are the tool's own, from `temporal` on.
pub fn main(args: Vec<std::ffi::OsString>) -> ExitCode {
    common::base::chapter::run_chapter_with_args(NAME, SMALLEST, args, run)
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let size = args.common.size;
    // Read first: a file that is not there or not a compare.csv is refused before any GPU work.
    let times = args.times_from.as_deref().map(measure::read_times).transpose()?;

    // Chapter 13's steps 1-4, as its main.rs makes them; then the choices this run varies.
    let mut scene = args.scene.load()?;
    let start = Camera::framing(scene.bounds, size.aspect());
    let path = Path::new(&scene, start, &args.path);
    if let Some(moving) = &path.moving {
        ensure!(
            args.blas == BlasLayout::PerMesh,
            "--blas flat holds every instance in one tree, so none can move: use --blas per-mesh, or --mover none"
        );
        scene.instances[moving.index].transform = Instance::new(moving.at(0), [0; 3]).transform;
    }
    let ao = AoArgs { samples: args.rays.samples, radius: args.radius, power: args.power, max_samples: 1 };
    let radius = ao.radius(&scene)?;
    let budget = Budget {
        accept: accept_bits(&args.accept),
        per_pixel: args.pattern == Pattern::PerPixel,
        fresh_pass: args.fresh_pass,
        ..Budget::new(&args.rays, radius, scene.size() / 2.0)
    };
    if let Some(reason) = common::rt::ao::nothing_to_trace(budget.fresh, radius) {
        eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
    }
    report.set("path", args.path.path);
    report.set("fresh_pass", args.fresh_pass);
    report.set("next_ids", args.next_ids);
    report.set("moving_instance", path.moving.as_ref().map(|m| m.index));

    let headless = CommonArgs { headless: true, ..args.common.clone() };
    let (vk, window, gl_context, handoff) = contexts_in_window(NAME, report, &RAY_TRACED_INTEROP, &headless)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
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
    let targets = Targets::new(&vk, &gl_context, &handoff, size.extent())?;
    let visibility = VisibilityPass::new(&gl_context, &shared.buffers)?;
    let fresh = SurfaceTracer::new(&vk, &shared, &ids, &targets)?;
    let temporal = TemporalTracer::new(&vk, &shared, fresh.mesh_table(), &targets, args.fresh_pass)?;
    let mut sized = Sized { targets, fresh, temporal };
    let composite = ComputeComposite::new(gl)?;
    let overlays = Overlays::new(gl, &scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
    let timestamps = Timestamps::new(&vk)?;
    let updates = Commands::new(&vk)?;
    let commands = Commands::new(&vk)?; // made last: dropped first, it waits for its work
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
        ids_ahead: args.next_ids == NextIds::Early,
        uniforms: Uniforms::new(args.blur, args.power, View::Final, start.far),
        radius,
    };
    let chosen = match args.method {
        Method::Temporal => Drawn::Temporal(budget),
        Method::Fresh => Drawn::Fresh(args.rays.samples),
    };
    let out = args.common.out_dir(NAME);
    let walking = walk::Walking {
        name: NAME,
        frames: args.common.frames.unwrap_or(120).max(1),
        compare: args.compare,
        error_against: args.error_against,
        error_every: args.error_every,
        timeline: args.timeline,
        out: out.clone(),
        prefix: args.scene.picture_name(NAME),
    };
    let mut walks = walk::headless(&passes, &mut sized, (chosen, budget), &walking, report)?;
    if let Some(times) = &times {
        measure::take_times(&mut walks, times, path.cut())?;
    }
    if args.compare {
        let table = measure::write(&out, &walks, path.cut(), &vk.info.name)?;
        eprint!("{table}");
    }
    if args.error_against > 0 || args.compare {
        report.set("walks", &walks); // frame by frame: times and errors
    }
    gl_context.check_error("the frames")?;
    common::interop::report_handoff(report, &handoff);

    unsafe { gl.finish() };
    vk.wait_idle()?; // once: no owner below waits
    drop(commands);
    drop(updates);
    drop(timestamps);
    drop(overlays);
    drop(composite);
    drop(sized);
    drop(visibility);
    drop(tlas);
    drop(shared);
    drop(handoff);
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}
