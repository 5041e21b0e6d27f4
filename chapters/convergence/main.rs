//! `convergence`: error against run time for the ambient occlusion of chapters 07-08.
//!
//! For each case it traces a sweep of rays per pixel per frame and frames of accumulation, times
//! each run on the GPU (timestamps), and measures the error over the covered pixels against the
//! exact answer (two scenes of planes, computed on the CPU in f64) or against a long run of the
//! same tracer (the default scene). It writes a CSV, a markdown table and a log-log plot.
//!
//! Run: `cargo run --release --bin convergence -- [--json] [--out DIR] [--quick]`.
//!
//! `convergence temporal [FLAGS]` measures chapter 13's frame along its path instead: error
//! against time per method, and what each of the chapter's choices buys (`temporal/mod.rs`).

mod cases;
mod exact;
mod outputs;
mod temporal;

use anyhow::{Result, ensure};
use ash::vk;
use cases::{Case, Placement};
use clap::Parser;
use common::base::commands::Commands;
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::clocks::timestamps::Timestamps;
use common::instruments::output;
use common::interop::handoff::{Apis, Handoff};
use common::rt::RayTracedScene;
use common::rt::ao::{AoRays, AoTracer};
use common::scene::gbuffer::GBuffers;
use common::{Print, RAY_TRACED_INTEROP, Report, VulkanContext};
use glam::DVec3;
use serde::Serialize;
use std::process::ExitCode;

/// Error against run time for the ray-traced ambient occlusion.
#[derive(Parser)]
#[command(after_help = COMMANDS)]
struct Args {
    /// Print one JSON report on stdout; everything human-readable goes to stderr.
    #[arg(long)]
    json: bool,
    /// Where the CSV, the markdown table and the plot go [default: out/convergence/].
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Small images and few rays: for tests on the software stack.
    #[arg(long)]
    quick: bool,
    /// Scale the exact cases by this factor (1e-4 to 1e4).
    #[arg(long, default_value_t = 1.0, value_parser = common::base::cli::number::<f64>(1e-4..=1e4), allow_negative_numbers = true)]
    scale: f64,
    /// Move the exact cases this many times their own size from the origin (0 to 1e4).
    #[arg(long, default_value_t = 0.0, value_parser = common::base::cli::number::<f64>(0.0..=1e4), allow_negative_numbers = true)]
    offset: f64,
    /// Only the exact cases (no default scene).
    #[arg(long)]
    exact_only: bool,
}

/// The command `main` takes instead of this program's flags, listed in `--help` as clap lists
/// its own (`convergence temporal --help` lists its flags).
const COMMANDS: &str = "Commands:
  temporal  Chapter 13's frame along its path, its choices varied: error and time per method";

/// One measurement: `spp` rays per pixel in each of `frames` frames.
#[derive(Serialize, Clone)]
pub struct Row {
    pub spp: u32,
    pub frames: u32,
    /// GPU time of all the frames' traces (timestamps).
    pub gpu_ms: f64,
    /// Over the evaluated pixels, against the reference.
    pub rmse: f64,
    pub max_abs: f64,
    /// The mean of (estimate − reference), and its standard error: a bias shows as a mean many
    /// standard errors from 0.
    pub mean_error: f64,
    pub standard_error: f64,
    /// What independent random directions would give on average, sqrt(mean(v (1 − v)) / N) for
    /// N rays and exact visibility v (cases with an exact answer): what the R2 sequence buys.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub independent_rmse: Option<f64>,
}

#[derive(Serialize)]
pub struct CaseReport {
    pub scene: &'static str,
    pub reference: &'static str,
    /// Pixels compared with the reference.
    pub pixels: usize,
    /// The slope of log(rmse) against log(rays per pixel): -1/2 for independent samples.
    pub slope: f64,
    pub rows: Vec<Row>,
}

fn main() -> ExitCode {
    // `convergence temporal ...`: chapter 13's frame along its path (`temporal/mod.rs`). The
    // word may come after flags every chapter takes (`--json --out DIR temporal ...`).
    let mut all: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let word = (1..all.len()).find(|&i| all[i] == "temporal" && all[i - 1] != "--out");
    if let Some(i) = word {
        all.remove(i);
        return temporal::main(all);
    }
    let args = Args::parse();
    let mut report = Report::new("convergence");
    if let Err(error) = common::base::chapter::accounted(|| run(&args, &mut report)) {
        eprintln!("error: {error:#}");
        return ExitCode::from(2);
    }
    common::finish(report, if args.json { Print::Json } else { Print::Summary })
}

fn run(args: &Args, report: &mut Report) -> Result<()> {
    ensure!((1e-4..=1e4).contains(&args.scale), "--scale {}: choose between 1e-4 and 1e4", args.scale);
    ensure!((0.0..=1e4).contains(&args.offset), "--offset {}: choose between 0 and 1e4", args.offset);
    let extent = if args.quick {
        vk::Extent2D { width: 64, height: 48 }
    } else {
        vk::Extent2D { width: 320, height: 240 }
    };
    // Rays per pixel per frame, and frames: every combination is one row.
    let (spps, frame_counts): (&[u32], &[u32]) =
        if args.quick { (&[1, 4], &[1, 4, 16]) } else { (&[1, 4, 16, 64], &[1, 4, 16, 64]) };
    let grid = Grid { extent, spps, frame_counts, quick: args.quick };
    let place = Placement { scale: args.scale, offset: args.offset };
    let aspect = extent.width as f32 / extent.height as f32;
    let mut cases = vec![cases::parallel_planes(place)?, cases::floor_and_wall(place)?];
    if !args.exact_only {
        cases.push(cases::default_scene_case(if args.quick { 300 } else { 10_000 }, aspect));
    }

    let vk = VulkanContext::new(&RAY_TRACED_INTEROP)?;
    let gl = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    common::connect(report, &vk, &gl)?;
    common::scene::gbuffer::check_size(&vk, &gl, extent)?;
    let handoff = Handoff::new(&vk, &gl)?;
    report.sync = Some(handoff.name());
    let timestamps = Timestamps::new(&vk)?;
    let mut results = Vec::new();
    for case in &cases {
        results.push(measure(&vk, &gl, &handoff, timestamps.as_ref(), case, &grid)?);
    }
    drop(timestamps);
    drop(handoff);

    for case in &results {
        let last = case.rows.last().expect("every case has rows");
        // Finite planes stand in for infinite ones only a radius or more from their edges.
        let judged = if case.reference == "analytic" { "at least R from every edge" } else { "covered" };
        eprintln!(
            "{}: {} pixels judged ({judged}), slope {:.2}, rmse {:.4} after {} rays per pixel",
            case.scene,
            case.pixels,
            case.slope,
            last.rmse,
            last.spp * last.frames
        );
        if case.reference == "analytic" {
            report.check(&format!("{}_error_falls_with_rays", case.scene), case.slope < -0.25);
            // The mean error of the longest run, against its standard error: unbiased means near 0.
            report.check(
                &format!("{}_unbiased", case.scene),
                last.mean_error.abs() <= 4.0 * last.standard_error + 1e-4,
            );
        }
    }
    let out = args.out.clone().unwrap_or_else(|| "out/convergence".into());
    outputs::write(&out, &results, &vk.info.name)?;
    report.set("size", [extent.width, extent.height]);
    report.set("placement", [args.scale, args.offset]);
    report.set("cases", &results);
    gl.check_error("convergence")?;
    Ok(())
}

/// What every case measures: each number of rays per pixel per frame for each number of
/// frames, at one size; `quick` leaves out the long reference run.
struct Grid<'a> {
    extent: vk::Extent2D,
    spps: &'a [u32],
    frame_counts: &'a [u32],
    quick: bool,
}

/// Every row of one case: the scene shared and built once, each row traced from zero.
fn measure(
    vk: &VulkanContext,
    gl: &GlContext,
    handoff: &Handoff,
    timestamps: Option<&Timestamps>,
    case: &Case,
    grid: &Grid,
) -> Result<CaseReport> {
    let &Grid { extent, spps, frame_counts, quick } = grid;
    let shared = RayTracedScene::new(vk, gl, &case.scene)?;
    let gbuffers = GBuffers::new(vk, gl, handoff, &shared.buffers, extent, vk::ImageUsageFlags::STORAGE)?;
    let mut tracer = AoTracer::new(vk, gl, &shared.allocator, *shared.structures.tlas.handle, &gbuffers)?;
    // Made after what the traces use: dropped first on an early return, it waits for the last.
    let commands = Commands::new(vk)?;
    let scene_scale = cases::scene_scale(&case.scene);
    let rays = |samples| AoRays { samples, accumulated: 0, radius: case.radius, scene_scale };

    // Runs `frames` frames of `spp` rays from zero; returns the GPU time and GL's AO image.
    let mut run = |spp: u32, frames: u32| -> Result<(f64, Vec<f32>)> {
        tracer.reset();
        let mut gpu_ms = 0.0;
        for _ in 0..frames {
            gbuffers.draw(&gl.gl, &case.scene, &case.camera);
            tracer.trace(Apis { vk, gl, handoff, commands: &commands }, &gbuffers, rays(spp), timestamps)?;
            if let Some(t) = timestamps {
                // A measurement: wait for this frame's rays to read their GPU time.
                commands.wait(vk, "vkWaitForFences for a measured trace")?;
                gpu_ms += t.read_ms(vk)?;
            }
        }
        let ao =
            output::read_texture_f32(&gl.gl, *tracer.image.texture.texture, extent.width, extent.height, 1);
        Ok((gpu_ms, ao))
    };

    // Once before measuring: the first trace pays for compiling the pipeline's shaders.
    run(1, 1)?;
    let positions = {
        gbuffers.draw(&gl.gl, &case.scene, &case.camera);
        output::read_texture_f32(&gl.gl, gbuffers.textures()[0], extent.width, extent.height, 4)
    };
    // ANCHOR: reference
    // The reference at every covered pixel: exact, or a long run of the same tracer (64 times
    // the largest row's rays, so its own noise is an eighth of that row's).
    let (reference_name, reference): (_, Vec<Option<f64>>) = match &case.exact {
        Some(exact) => {
            let at =
                |p: &[f32]| (p[3] > 0.0).then(|| exact(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)))?;
            ("analytic", positions.chunks_exact(4).map(at).collect())
        }
        None => {
            let most = spps.iter().max().unwrap() * frame_counts.iter().max().unwrap();
            let frames = (64 * most).div_ceil(256);
            let (_, long) = run(256, frames)?;
            eprintln!("{}: reference of {} rays per pixel", case.name, 256 * frames);
            let covered = positions.chunks_exact(4).map(|p| p[3] > 0.0);
            ("high-spp", covered.zip(long).map(|(c, v)| c.then_some(v as f64)).collect())
        }
    };
    // ANCHOR_END: reference
    let pixels = reference.iter().flatten().count();
    ensure!(pixels > 0, "{}: no pixel to compare (the camera sees nothing evaluable)", case.name);

    let mut rows = Vec::new();
    for &spp in spps {
        for &frames in frame_counts {
            let (gpu_ms, ao) = run(spp, frames)?;
            let mut row = errors(spp, frames, gpu_ms, &ao, &reference);
            if case.exact.is_some() {
                let variance = reference.iter().flatten().map(|v| v * (1.0 - v)).sum::<f64>() / pixels as f64;
                row.independent_rmse = Some((variance / (spp * frames) as f64).sqrt());
            }
            rows.push(row);
        }
    }
    if !quick {
        eprintln!("{}: {} rows", case.name, rows.len());
    }
    vk.wait_idle()?; // once: no owner below waits
    drop(commands);
    drop(tracer);
    drop(gbuffers);
    drop(shared);
    let slope = slope(&rows);
    Ok(CaseReport { scene: case.name, reference: reference_name, pixels, slope, rows })
}

/// RMSE, largest error, mean error and its standard error, over the pixels with a reference.
fn errors(spp: u32, frames: u32, gpu_ms: f64, ao: &[f32], reference: &[Option<f64>]) -> Row {
    let differences: Vec<f64> =
        ao.iter().zip(reference).filter_map(|(&a, r)| r.map(|r| a as f64 - r)).collect();
    let n = differences.len() as f64;
    let mean = differences.iter().sum::<f64>() / n;
    let squares = differences.iter().map(|d| d * d).sum::<f64>() / n;
    let variance = differences.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    Row {
        spp,
        frames,
        gpu_ms,
        rmse: squares.sqrt(),
        max_abs: differences.iter().fold(0.0, |m, d| m.max(d.abs())),
        mean_error: mean,
        standard_error: (variance / n).sqrt(),
        independent_rmse: None,
    }
}

/// Least-squares slope of log(rmse) against log(rays per pixel).
pub fn slope(rows: &[Row]) -> f64 {
    let points: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.rmse > 0.0)
        .map(|r| (((r.spp * r.frames) as f64).ln(), r.rmse.ln()))
        .collect();
    let n = points.len() as f64;
    let (mx, my) = (points.iter().map(|p| p.0).sum::<f64>() / n, points.iter().map(|p| p.1).sum::<f64>() / n);
    let covariance: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let spread: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    covariance / spread
}
