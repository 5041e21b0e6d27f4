//! `bench`: chapter 08's whole frame (G-buffers, hand-over, AO trace, composite, overlays) in
//! three modes, side by side in one process, on the same scenes, sizes and rays:
//!
//! - `zero-copy`: shared memory and shared semaphores (the host fallback where the driver has
//!   no semaphores, as on lavapipe: the report's `zero_copy_sync` says which);
//! - `host-sync`: shared memory, the CPU waiting at each hand-over;
//! - `cpu-round-trip`: no interop at all; the G-buffers and the AO go through the CPU.
//!
//! Per-pass times come from the GPU (GL time queries, Vulkan timestamps); a frame's time is
//! the wall-clock time between frames, once many frames run back to back.
//!
//! `--probe NAME` instead answers one of chapter 12's design questions on its frame
//! (`probes/`): which lean buffer, whether GL's work runs beside Vulkan's, GL's composite or
//! Vulkan's; or one of chapter 14's: the hand-over in one process, GL's wait on a semaphore
//! nobody signals.
//!
//! Run: `cargo run --release --bin bench -- [--json] [--quick] [--out DIR] [--probe NAME]`.

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::{Size, Smallest, check_covered, parse_size};
use common::base::commands::Commands;
use common::base::gl::{DebugOutput, GlContext, MEMORY_EXTENSIONS};
use common::clocks::timeline::Timeline;
use common::clocks::timestamps::Timestamps;
use common::interop::exportable::SceneMemory;
use common::interop::handoff::{Apis, Handoff};
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, TlasFlags};
use common::scene::Scene;
use common::{Print, RAY_TRACED_INTEROP, Report, VulkanContext};
use std::path::PathBuf;
use std::process::ExitCode;

mod fast;
mod frame;
mod outputs;
mod probes;
mod round_trip;

use common::scene::builtin::{Ground, SceneKind};
use fast_frame::trace::Pattern;
use frame::{Frame, Samples, Setting};

/// Chapter 08's frame, zero-copy against host-synchronised against a CPU round trip.
#[derive(clap::Parser)]
struct Args {
    /// Print exactly one JSON report on stdout; the table goes to stderr.
    #[arg(long)]
    json: bool,
    /// Small sizes and few frames: for tests, in seconds on a CPU.
    #[arg(long)]
    quick: bool,
    /// Where bench.json, bench.md and bench.svg go.
    #[arg(long, default_value = "out/bench")]
    out: PathBuf,
    /// Scenes [default: default, large, ceiling].
    #[arg(long, value_enum, value_delimiter = ',')]
    scenes: Vec<SceneKind>,
    /// Sizes, WIDTHxHEIGHT [default: 1920x1080,3840x2160; --quick: 64x48,96x64].
    #[arg(long, value_delimiter = ',', value_parser = parse_size)]
    sizes: Vec<Size>,
    /// Rays per pixel per frame [default: 1,4,16,64; --quick: 1,4; with --probe: 16].
    #[arg(long, value_delimiter = ',', value_parser = common::base::cli::number::<u32>(1..=256))]
    spp: Vec<u32>,
    /// How GL reports problems while the bench runs (every chapter: synchronous).
    #[arg(long, value_enum, default_value = "synchronous")]
    gl_debug: DebugOutput,
    /// Draw the G-buffers depth first (`GBuffers::draw_depth_first`) instead of in one pass.
    #[arg(long)]
    depth_prepass: bool,
    /// Where the shared scene buffers live: `host` (every chapter: the first host-visible type)
    /// or `device` (device-local and host-visible, where the GPU offers such memory).
    #[arg(long, value_enum, default_value = "host")]
    scene_memory: SceneMemory,
    /// The BLAS layout: one BLAS per mesh and a TLAS instance per scene instance (every chapter),
    /// or `flat`, every instance's triangles in one BLAS under one TLAS instance.
    #[arg(long, value_enum, default_value = "per-mesh")]
    blas: BlasLayout,
    /// Measured frames per mode and setting [default: 30; --quick: 3], after 2 unmeasured ones
    /// (with --probe: the frames drawn before the probe).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=100_000))]
    frames: Option<u32>,
    /// Also draw the last N frames' passes of chapter 08's frame and of chapter 12's, each on one
    /// clock, into timeline-08.svg and timeline-12.svg (0: none).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=64))]
    timeline: u32,
    /// The converged reference of the ablation, of `--probe patterns` and of chapter 13's error, in
    /// rays per pixel [default: 1024; --quick: 64].
    #[arg(long, value_parser = common::base::cli::number::<u32>(16..=1 << 20))]
    reference_rays: Option<u32>,
    /// Instead of the sweep: one of chapter 12's design questions, measured on its frame at
    /// every scene [default: default], size and ray count: `layouts` (the ids or a packed normal
    /// and depth), `overlap` (GL's work beside Vulkan's), `vulkan-composite` (GL's compute
    /// composite against Vulkan's) or `patterns` (each sample pattern's trace time and error);
    /// chapter 14's on its own frame: `one-process` (the hand-over with no second process) or
    /// `gl-stall` (GL waiting on a semaphore nobody signals).
    #[arg(long, value_enum)]
    probe: Option<probes::Probe>,
    /// The probe's rounds at each setting [default: 100; --quick: 2].
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=100_000))]
    rounds: Option<u32>,
    /// The blur radii the probe composites with, 0-8 [default: 2].
    #[arg(long, value_delimiter = ',', value_parser = common::base::cli::number::<u32>(0..=8))]
    blurs: Vec<u32>,
    /// The sample patterns `--probe patterns` compares [default: all six].
    #[arg(long, value_enum, value_delimiter = ',')]
    patterns: Vec<Pattern>,
}

/// How the frame's images travel between GL and Vulkan.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    ZeroCopy,
    HostSync,
    CpuRoundTrip,
    /// Chapter 12's frame, run as its own program (`fast.rs`).
    FastFrame,
    /// Chapter 13's frame orbiting, with an instance moving, run as its own program (`fast.rs`).
    TemporalReuse,
    /// The same, orbiting in the closer view its path cuts to.
    TemporalReuseCloser,
}

impl Mode {
    /// Chapter 08's frame, the three ways this program draws it itself.
    const ALL: [Mode; 3] = [Mode::ZeroCopy, Mode::HostSync, Mode::CpuRoundTrip];
}

// ANCHOR: row
/// One line of the results: a mode at one scene, size and ray count, each pass timed.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub mode: Mode,
    pub scene: &'static str,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Median wall-clock time from one frame to the next.
    pub frame_ms: f64,
    pub p95_ms: f64,
    /// GPU medians of the G-buffer pass (GL), the trace (Vulkan), composite + overlays (GL).
    pub raster_ms: f64,
    /// What is left of a frame besides the three passes: hand-overs, copies, CPU waits.
    pub handoff_ms: f64,
    pub ao_ms: f64,
    pub composite_ms: f64,
    /// AO rays per second of trace time, in billions: `spp` rays from every covered pixel
    /// (background pixels cast none).
    pub grays_per_s: f64,
}
// ANCHOR_END: row

fn main() -> ExitCode {
    let args: Args = clap::Parser::parse();
    let mut report = Report::new("bench");
    if let Err(error) = common::base::chapter::accounted(|| run(&args, &mut report)) {
        eprintln!("error: {error:#}");
        return ExitCode::from(2);
    }
    common::finish(report, if args.json { Print::Json } else { Print::Summary })
}

/// Chapter 12's smallest picture, whose frame bench runs beside chapter 08's at every size (and
/// chapter 08's is smaller).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "chapter 12, whose frame it runs: one compute group, and the overlay checks need a pixel of \
          the gizmo, with 2 pixels of room around it, behind a surface and another in the open",
    shape: Some((4.0, 2.0, "as chapter 12's")),
};

fn run(args: &Args, report: &mut Report) -> Result<()> {
    // 1. What to measure
    let scenes = if args.scenes.is_empty() {
        vec![SceneKind::Default, SceneKind::Large, SceneKind::Ceiling]
    } else {
        args.scenes.clone()
    };
    let sizes = match (&args.sizes[..], args.quick) {
        ([], false) => vec![Size { width: 1920, height: 1080 }, Size { width: 3840, height: 2160 }],
        ([], true) => vec![Size { width: 64, height: 48 }, Size { width: 96, height: 64 }],
        (sizes, _) => sizes.to_vec(),
    };
    for &size in &sizes {
        SMALLEST.check_flag("--sizes", "bench", size)?;
    }
    let spps = match (&args.spp[..], args.quick) {
        ([], false) => vec![1, 4, 16, 64],
        ([], true) => vec![1, 4],
        (spps, _) => spps.to_vec(),
    };
    ensure!(spps.iter().all(|s| (1..=256).contains(s)), "--spp: each must be 1 to 256");
    let ground = if args.quick { Ground::Coarse } else { Ground::Fine };
    if let Some(probe) = args.probe {
        let settings = probes::Settings {
            scenes: if args.scenes.is_empty() { vec![SceneKind::Default] } else { args.scenes.clone() },
            sizes,
            spps: if args.spp.is_empty() { vec![16] } else { spps },
            blurs: if args.blurs.is_empty() { vec![2] } else { args.blurs.clone() },
            patterns: if args.patterns.is_empty() { Pattern::ALL.to_vec() } else { args.patterns.clone() },
            reference: args.reference_rays.unwrap_or(if args.quick { 64 } else { 1024 }),
            frames: args.frames.unwrap_or(if args.quick { 3 } else { 30 }),
            rounds: args.rounds.unwrap_or(if args.quick { 2 } else { 100 }),
            ground,
        };
        return probes::run(probe, &settings, &args.out, report);
    }
    // Half in each of two rounds.
    let frames_per_run = args.frames.unwrap_or(if args.quick { 3 } else { 30 }).div_ceil(2);

    // 2. Vulkan, GL, and both ways to synchronise
    let vk = VulkanContext::new(&RAY_TRACED_INTEROP)?;
    let gl = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    common::connect(report, &vk, &gl)?;
    let largest = common::largest_size(&vk, &gl);
    for &size in &sizes {
        largest.check_flag("--sizes", "bench", size)?;
    }
    gl.set_debug_output(args.gl_debug);
    common::interop::exportable::set_scene_memory(args.scene_memory);
    let settings = serde_json::json!({
        "gl_debug": args.gl_debug,
        "depth_prepass": args.depth_prepass,
        "scene_memory": args.scene_memory,
        "blas": args.blas,
    });
    report.set("settings", settings);
    report.set("device", &vk.info.name);
    report.set("driver", &vk.info.driver);
    // Every memory type the device offers, so that a run says which `--scene-memory` could choose.
    let types = &vk.memory_properties.memory_types[..vk.memory_properties.memory_type_count as usize];
    let offered: Vec<String> = types.iter().map(|t| format!("{:?}", t.property_flags)).collect();
    report.set("memory_types", offered);
    let zero_copy = Handoff::new(&vk, &gl)?;
    report.set("zero_copy_sync", zero_copy.name());
    let host = Handoff::Host { disagreements: std::cell::Cell::new(0) };
    let stamps = Timestamps::new(&vk)?;
    ensure!(stamps.is_some(), "{}: the queue writes no timestamps, which bench measures with", vk.info.name);
    let stamps = stamps.expect("checked");

    let open_fds_before = common::open_fd_count()?;

    // 3. Every scene, size and ray count, the modes interleaved
    let mut rows = Vec::new();
    // Chapter 13 at chapter 12's error, per scene, size and ray count (`fast::EqualError`),
    // against the ablation's converged reference.
    let mut equal_error = Vec::new();
    let reference = args.reference_rays.unwrap_or(if args.quick { 64 } else { 1024 });
    let scenes_count = scenes.len();
    let (mut depth_first_differences, mut pixels_compared) = (0, 0);
    let mut covered_everywhere = true;
    for kind in scenes {
        let scene = kind.build(ground)?;
        let shared = RayTracedScene::with_layout(&vk, &gl, &scene, TlasFlags::STATIC, args.blas)?;
        // What the scene's memory turned out to be (`--scene-memory device` is a preference).
        let memory = &shared.buffers.instances.vk.memory;
        report.set("scene_memory_flags", format!("{:?}", memory.property_flags));
        report.set("scene_memory_type", memory.memory_type_index);
        // Which types an exportable buffer may live in at all: `--scene-memory device` can only
        // choose among these.
        let allowed: Vec<u32> = (0..32).filter(|i| memory.allowed_types & (1 << i) != 0).collect();
        report.set("scene_memory_types_allowed", allowed);
        if kind == SceneKind::Large {
            report.set("large_scene", acceleration_report(&scene, &shared));
        }
        for &size in &sizes {
            let extent = vk::Extent2D { width: size.width, height: size.height };
            // One set of images per mode: each mode hands its images over its own way, with
            // its own layouts, from the first frame to the last.
            let mut frames = Vec::new();
            for mode in Mode::ALL {
                // The hand-over its frames will use hands its new images to GL too.
                let handoff = if mode == Mode::ZeroCopy { &zero_copy } else { &host };
                frames.push(Frame::new(&vk, &gl, handoff, &shared, &scene, extent, mode)?);
            }
            // Made after what the frames use: dropped first on an early return, it waits for
            // the last submission before the frames go.
            let commands = Commands::new(&vk)?;
            if args.depth_prepass {
                depth_first_differences += frames[0].depth_first_differences(&gl.gl);
            }
            let covered = frames[0].covered_pixels(&gl.gl);
            // No pixel on the scene: no ray to count, and no rate or comparison means anything.
            check_covered("--sizes", "bench", size, covered)?;
            pixels_compared += covered;
            covered_everywhere &= covered > 0;
            for &spp in &spps {
                let mut samples: Vec<Samples> = Mode::ALL.iter().map(|_| Samples::default()).collect();
                // Two rounds of every mode in turn: a clock or thermal drift touches all alike.
                for _round in 0..2 {
                    for (frame, samples) in frames.iter_mut().zip(&mut samples) {
                        let handoff = if frame.mode == Mode::ZeroCopy { &zero_copy } else { &host };
                        let setting =
                            Setting { spp, frames: frames_per_run, depth_prepass: args.depth_prepass };
                        let apis = Apis { vk: &vk, gl: &gl, handoff, commands: &commands };
                        frame.run(apis, setting, &stamps, (samples, &mut None))?;
                    }
                }
                for (mode, samples) in Mode::ALL.iter().zip(&samples) {
                    rows.push(samples.row(*mode, kind.name(), size, spp, covered));
                }
                // Chapter 12's frame at the same setting, as many frames as each mode ran.
                let out = args.out.join("fast-frame");
                rows.push(fast::row(kind, size, spp, 2 * frames_per_run, covered, &out)?);
                if spp <= 64 {
                    // Chapter 13's frame in each view of its path, as many frames again, at the
                    // rays a frame that reach chapter 12's error at this setting.
                    let out = args.out.join("temporal-reuse");
                    let run = (2 * frames_per_run, reference);
                    let (two, found) = fast::temporal_rows(kind, size, spp, run, &out)?;
                    rows.extend(two);
                    equal_error.push(found);
                }
                eprintln!("bench: {} {}x{} {spp} spp done", kind.name(), size.width, size.height);
            }
            unsafe { glow::HasContext::finish(&*gl.gl) };
            vk.wait_idle()?; // once: no owner below waits
            drop(commands);
            drop(frames); // each newest first: GL's objects, then the shared images
        }
        drop(shared);
    }
    if args.timeline > 0 {
        // Chapter 08's frame and chapter 12's, each on one clock: the last frames of as many as
        // a row measures, on the default scene at the ablation's setting.
        let (size, spp) = ablation_setting(&sizes, &spps);
        let scene = SceneKind::Default.build(ground)?;
        let shared = RayTracedScene::with_layout(&vk, &gl, &scene, TlasFlags::STATIC, args.blas)?;
        let extent = vk::Extent2D { width: size.width, height: size.height };
        let mut frame = Frame::new(&vk, &gl, &zero_copy, &shared, &scene, extent, Mode::ZeroCopy)?;
        let mut timeline = Some(Timeline::new(&gl.gl, args.timeline, ["gbuffer", "composite"])?);
        let commands = Commands::new(&vk)?; // made last: dropped first, it waits for its work
        let apis = Apis { vk: &vk, gl: &gl, handoff: &zero_copy, commands: &commands };
        let frames = (2 * frames_per_run).max(args.timeline);
        let setting = Setting { spp, frames, depth_prepass: args.depth_prepass };
        frame.run(apis, setting, &stamps, (&mut Samples::default(), &mut timeline))?;
        let timeline = timeline.take().expect("made above");
        report.set("timeline_08", timeline.finish(&vk, &commands, &stamps, &args.out.join("timeline-08"))?);
        unsafe { glow::HasContext::finish(&*gl.gl) };
        vk.wait_idle()?; // once: no owner below waits
        drop(commands);
        drop(frame);
        drop(shared);
        // Chapter 12's frame, from its library, drawn as its program draws it.
        let setting = (extent, spp);
        let out = args.out.join("timeline-12");
        let fast = probes::timeline(
            (&vk, &gl, &zero_copy, &stamps),
            &scene,
            setting,
            (frames, args.timeline),
            &out,
        )?;
        report.set("timeline_12", fast);
    }
    drop(stamps);
    report.check("every_scene_covers_pixels", covered_everywhere);
    report.check("hand_over_layouts_agreed", zero_copy.layouts_agreed() && host.layouts_agreed());
    // Every scene's buffers, images and memory objects were made and destroyed since the count:
    // none may be left holding an fd.
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(host);
    drop(zero_copy); // the semaphores, if any
    gl.check_error("the bench")?;

    // 4. What the rows say, in every form
    if args.depth_prepass {
        // Ties in depth are rare: a few pixels in a thousand would mean the two passes disagree
        // on depth itself (NVIDIA's first H100 run differed; this counts by how much).
        report.set("depth_prepass_pixels_differing", depth_first_differences);
        report.set("depth_prepass_pixels_compared", pixels_compared);
        let fraction = depth_first_differences as f64 / pixels_compared.max(1) as f64;
        report.check("depth_prepass_draws_the_same_gbuffers_but_for_ties", fraction <= 1e-3);
    }
    // Per setting: chapter 08's three modes and chapter 12's row, and chapter 13's two (one per
    // view of its path) where it takes the ray count (at most 64 a frame).
    let temporal = 2 * spps.iter().filter(|&&spp| spp <= 64).count();
    checks(report, &rows, scenes_count * sizes.len() * ((Mode::ALL.len() + 1) * spps.len() + temporal));
    // The ablation: chapter 12 with its choices undone one at a time, on the default scene at
    // the largest size, at 16 rays (or the most asked for, if fewer).
    let (size, spp) = ablation_setting(&sizes, &spps);
    let steps = fast::ablation(size, spp, 2 * frames_per_run, reference, &args.out.join("fast-frame"))?;
    let chapter_08 = rows.iter().find(|r| {
        (r.mode, r.scene, r.width, r.height, r.spp)
            == (Mode::ZeroCopy, "default", size.width, size.height, spp)
    });
    let ablation = fast::table(chapter_08, &steps);
    let equal = fast::equal_error_table(&equal_error);
    report.check(
        "temporal_rows_measured_at_chapter_12s_error",
        equal_error.iter().all(|e| e.error.is_finite() && e.chapter_12_error.is_finite()),
    );
    report.set("temporal_equal_error", &equal_error);
    report.set("ablation", serde_json::json!({ "size": format!("{}x{}", size.width, size.height), "spp": spp, "reference_rays": reference, "steps": steps }));
    outputs::write(&args.out, &rows, &vk.info.name, &vk.info.driver, (&ablation, &equal))?;
    if !args.json {
        eprintln!("{}\n{ablation}\n{equal}", outputs::table(&rows));
    }
    report.set("rows", &rows);
    Ok(())
}

/// The ablation's (and the timelines') setting: the largest size, at 16 rays per pixel, or the
/// most asked for if fewer.
fn ablation_setting(sizes: &[Size], spps: &[u32]) -> (Size, u32) {
    let size = *sizes.iter().max_by_key(|s| s.width as u64 * s.height as u64).expect("a size");
    (size, if spps.contains(&16) { 16 } else { *spps.iter().max().expect("a ray count") })
}

/// The BLAS/TLAS numbers of the large scene.
fn acceleration_report(scene: &Scene, shared: &RayTracedScene) -> serde_json::Value {
    let stats = &shared.structures.stats;
    serde_json::json!({
        "triangles": scene.triangles(),
        "blas_count": stats.blas_count,
        "blas_bytes": stats.blas_bytes,
        "compacted_bytes": stats.compacted_bytes,
        "tlas_bytes": stats.tlas_bytes,
        "blas_build_ms": stats.blas_build_ms,
        "compaction_ms": stats.compaction_ms,
        "tlas_build_ms": stats.tlas_build_ms,
    })
}

/// The shape of the results, which no speed can change: every row measured, every pass timed.
fn checks(report: &mut Report, rows: &[Row], expected: usize) {
    let finite = |r: &Row| {
        [r.frame_ms, r.p95_ms, r.raster_ms, r.handoff_ms, r.ao_ms, r.composite_ms, r.grays_per_s]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
    };
    report.check("every_row_has_finite_times", !rows.is_empty() && rows.iter().all(finite));
    report.check(
        "every_pass_was_timed",
        rows.iter().all(|r| r.raster_ms > 0.0 && r.ao_ms > 0.0 && r.composite_ms > 0.0),
    );
    report.check("every_setting_has_a_row_per_mode", rows.len() == expected);
}
