//! `convergence temporal`: chapter 13's frame (its library, `temporal_reuse`) walked along its path
//! headless, with the choices the chapter makes undone one at a time, and measured: each frame's
//! error after the blur against a converged trace of that frame, its GPU and wall-clock times,
//! and with `--compare` the methods side by side (compare.md, compare.csv and two plots).
//!
//! Run: `cargo run --release --bin convergence -- temporal --size 1920x1080 --compare
//! --error-against 1024 --error-every 4` (the page's tables name their own flags).

mod measure;
mod walk;

use anyhow::Result;
use common::base::cli::Smallest;
use common::scene::gbuffer::contexts_in_window;
use common::{CommonArgs, Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use fast_frame::composite::{Uniforms, View};
use glow::HasContext;
use std::process::ExitCode;
use temporal_reuse::tracer::accept_bits;
use temporal_reuse::{Accept, Drawn, FreshPass, Objects, PATH_FRAMES, TemporalArgs};

/// The name the tool's report, its output folder and its pictures take: its own, so that a walk
/// never writes over the chapter's pictures in `out/13-temporal-reuse/`.
const NAME: &str = "convergence-temporal";
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
#[command(mut_arg("frames", |arg| arg.help(format!(
    "How many frames to walk, 0 to 10000000 (0 walks one) [default: {PATH_FRAMES}, the whole path]"
))))]
struct Args {
    /// Chapter 13's own flags, as the chapter takes them.
    #[command(flatten)]
    temporal: TemporalArgs,
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
    /// timeline.svg in --out, as `bench --timeline` draws chapter 12's (0: none).
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

    // Chapter 13's steps 1-4, as its main.rs makes them, with the choices this run varies.
    let mut stage = args.temporal.stage(size.aspect(), report)?;
    stage.budget.accept = accept_bits(&args.accept);
    stage.budget.per_pixel = args.pattern == Pattern::PerPixel;
    stage.budget.fresh_pass = args.fresh_pass;
    report.set("fresh_pass", args.fresh_pass);
    report.set("next_ids", args.next_ids);

    let headless = CommonArgs { headless: true, ..args.common.clone() };
    let (vk, window, gl_context, handoff) = contexts_in_window(NAME, report, &RAY_TRACED_INTEROP, &headless)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    let apis = (&vk, &gl_context, &handoff);
    let mut objects = Objects::new(apis, &stage, args.temporal.blas, size.extent())?;
    // The error is measured on the picture a reader sees: the final view.
    let uniforms = Uniforms::new(args.temporal.blur, args.temporal.power, View::Final, stage.start.far);
    let (passes, sized) = objects.passes(apis, &stage, uniforms, args.next_ids == NextIds::Early);
    let chosen = match args.method {
        Method::Temporal => Drawn::Temporal(stage.budget),
        Method::Fresh => Drawn::Fresh(args.temporal.rays.samples),
    };
    let out = args.common.out_dir(NAME);
    let walking = walk::Walking {
        name: NAME,
        frames: args.common.frames.unwrap_or(PATH_FRAMES).max(1),
        compare: args.compare,
        error_against: args.error_against,
        error_every: args.error_every,
        timeline: args.timeline,
        out: out.clone(),
        prefix: args.temporal.scene.picture_name(NAME),
    };
    let mut walks = walk::headless(&passes, sized, (chosen, stage.budget), &walking, report)?;
    if let Some(times) = &times {
        measure::take_times(&mut walks, times, stage.path.cut())?;
    }
    if args.compare {
        let table = measure::write(&out, &walks, stage.path.cut(), &vk.info.name)?;
        eprint!("{table}");
    }
    if args.error_against > 0 || args.compare {
        report.set("walks", &walks); // frame by frame: times and errors
    }
    gl_context.check_error("the frames")?;
    common::interop::report_handoff(report, &handoff);

    unsafe { gl.finish() };
    vk.wait_idle()?; // once: no owner below waits
    drop(objects);
    drop(handoff);
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}
