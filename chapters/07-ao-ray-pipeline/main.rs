//! Chapter 07: the ambient-occlusion ray pipeline.
//!
//! Every frame GL rasterises the G-buffers into Vulkan-owned images and hands them over; a ray
//! generation shader reads each pixel's position and normal, casts short rays over the
//! hemisphere, and folds the fraction that escape into a running mean, stored in an R32F image
//! that GL reads back. Frames accumulate until the camera or a parameter changes.
//!
//! Run: `cargo run --release --bin 07-ao-ray-pipeline -- --frames 16`.

use anyhow::Result;
use ash::vk;
use common::base::cli::{Smallest, check_covered};
use common::base::commands::Commands;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{self, GlPassTimer, PassTimes};
use common::instruments::output;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::ao::{AoArgs, AoRays, AoTracer};
use common::scene::gbuffer::{self, GBuffers};
use common::scene::{Camera, SceneArgs};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glow::HasContext as _;
use std::process::ExitCode;

const CHAPTER: &str = "07-ao-ray-pipeline";
/// Any size: the one check that counts pixels, `accumulation_reduces_noise`, is made only where
/// enough of them lie on the scene (`NOISE_PAIRS`), and the chapter says so where they do not. A
/// size the scene covers no pixel of (16384x1) is refused once GL has drawn it.
const SMALLEST: Smallest = Smallest::ANY;
/// Pairs of neighbouring pixels on the scene that the noise check needs: with fewer, the
/// difference between two frames' noise is itself mostly chance (a 24x24 picture fails it).
const NOISE_PAIRS: usize = 512;

/// Chapter 07: ray-traced ambient occlusion from GL's G-buffers.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    ao: AoArgs,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    // 1. Load the scene, and choose a radius that suits its size
    let scene = args.scene.load()?;
    let camera = Camera::framing(scene.bounds, args.common.size.aspect());
    let radius = args.ao.radius(&scene)?;

    // 2. Create both contexts, share the scene, build its acceleration structures (05, 06)
    let (vk, gl_context, handoff) =
        gbuffer::contexts(CHAPTER, report, &RAY_TRACED_INTEROP, args.common.size)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    let shared = RayTracedScene::new(&vk, &gl_context, &scene)?;

    // 3. Share the G-buffers, and make the AO tracer with its shared image
    // ANCHOR: tracer
    let extent = args.common.size.extent();
    // The ray tracer reads the G-buffers as storage images.
    let gbuffers =
        GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, extent, vk::ImageUsageFlags::STORAGE)?;
    let mut tracer =
        AoTracer::new(&vk, &gl_context, &shared.allocator, *shared.structures.tlas.handle, &gbuffers)?;
    // ANCHOR_END: tracer

    // 4. Every frame: GL draws, Vulkan traces and accumulates, GL reads
    // Each pass's GPU time (common::clocks::timing): GL's read when they arrive, the trace's just before
    // the next trace, which waits for the previous one's fence anyway.
    let (mut gl_timer, mut times, timestamps) =
        (GlPassTimer::new(gl)?, PassTimes::new(), Timestamps::new(&vk)?);
    // Made after everything the traces use: an early return drops it first, and its Drop waits
    // for the last trace before the tracer or the G-buffers are destroyed.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let (mut trace_pending, mut rays) = (false, 0u64);
    let mut first_noise = None;
    let (mut positions, mut covered_pixels) = (Vec::new(), 0u64);
    let nothing_to_trace = common::rt::ao::nothing_to_trace(args.ao.samples, radius);
    if let Some(reason) = nothing_to_trace {
        eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
        report.set("ao_skipped", reason);
        tracer.fill_unoccluded(&vk, &gl_context, &handoff)?;
    }
    for frame in 0..args.common.headless_frames() {
        // ANCHOR: loop
        gl_timer.time(gl, "gbuffer", || gbuffers.draw(gl, &scene, &camera))?;
        let samples = args.ao.samples.min(args.ao.max_samples.saturating_sub(tracer.accumulated));
        // Nothing left to add once converged (a viewer would just show it), or nothing to trace.
        let traced = samples > 0 && nothing_to_trace.is_none();
        if traced {
            let params = AoRays { samples, accumulated: 0, radius, scene_scale: scene.size() / 2.0 };
            if std::mem::take(&mut trace_pending) {
                timing::read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
            }
            tracer.trace(apis, &gbuffers, params, timestamps.as_ref())?;
            trace_pending = timestamps.is_some();
        }
        gl_timer.end_frame(gl, &mut times);
        times.frame_done();
        // ANCHOR_END: loop
        if frame == 0 {
            // For the checks, once: GL reads the first frame's AO and the positions back (the
            // CPU waits for them). The last frame's AO is read after the loop.
            let ao =
                output::read_texture_f32(gl, *tracer.image.texture.texture, extent.width, extent.height, 1);
            positions = output::read_texture_f32(gl, gbuffers.textures()[0], extent.width, extent.height, 4);
            // No pixel on the scene: no ray traced, and the mean and checks below would be over none.
            covered_pixels = positions.chunks_exact(4).filter(|p| p[3] > 0.0).count() as u64;
            check_covered("--size", CHAPTER, args.common.size, covered_pixels)?;
            first_noise = Some(noise(&ao, &positions, extent.width as usize).0);
        }
        if traced {
            rays += covered_pixels * samples as u64;
        }
    }
    if trace_pending {
        timing::read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
    }
    gl_timer.finish(gl, &mut times);
    times.record(report);
    gl_context.check_error("the frame loop")?;
    let visibility =
        output::read_texture_f32(gl, *tracer.image.texture.texture, extent.width, extent.height, 1);

    // 5. Check the occlusion, and show it
    let covered: Vec<usize> = (0..visibility.len()).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
    let shown: Vec<f32> = visibility.iter().map(|v| v.powf(args.ao.power)).collect();
    let mean = covered.iter().map(|&i| shown[i] as f64).sum::<f64>() / covered.len().max(1) as f64;
    let min = covered.iter().map(|&i| visibility[i]).fold(1.0f32, f32::min);
    report.check("ao_within_0_and_1", visibility.iter().all(|v| (0.0..=1.0).contains(v)));
    let mut background = (0..visibility.len()).filter(|&i| positions[i * 4 + 3] <= 0.0);
    report.check("background_unoccluded", background.all(|i| visibility[i] == 1.0));
    if nothing_to_trace.is_some() {
        report.check("untraced_means_visibility_1", visibility.iter().all(|&v| v == 1.0));
    }
    let (last_noise, pairs) = noise(&visibility, &positions, extent.width as usize);
    report.set("noise_pairs", pairs);
    let enough = pairs >= NOISE_PAIRS;
    if first_noise.is_some() && tracer.accumulated > args.ao.samples && !enough {
        eprintln!(
            "noise: {pairs} pairs of neighbouring pixels lie on the scene, fewer than {NOISE_PAIRS}: \
             accumulation_reduces_noise is not checked at this size"
        );
    }
    if let Some(first) = first_noise.filter(|_| tracer.accumulated > args.ao.samples && enough) {
        eprintln!(
            "noise between neighbours: {first:.4} after one frame, {last_noise:.4} after {} rays",
            tracer.accumulated
        );
        report
            .check("accumulation_reduces_noise", last_noise <= first && (first < 1e-3 || last_noise < first));
    }
    report.set("ao_mean", (mean * 1e4).round() / 1e4);
    report.set("ao_min", (min as f64 * 1e4).round() / 1e4);
    report.set("samples_per_pixel", tracer.accumulated);
    report.set("radius", radius);
    report.set("rays_traced", rays);
    let trace_ms: f64 = times.samples("ao_trace").iter().sum();
    if timestamps.is_some() && rays > 0 {
        report.time_ms("trace_gpu_total", trace_ms);
        report.set("mrays_per_s", ((rays as f64 / (trace_ms / 1e3)) / 1e6 * 10.0).round() / 10.0);
    }
    let prefix = args.scene.picture_name(CHAPTER);
    let out = args.common.out_dir(CHAPTER);
    output::save_gl_rgba8(report, &out, &prefix, (extent.width, extent.height), &output::grey(&shown))?;

    common::interop::report_handoff(report, &handoff);
    // 6. Clean up, newest first
    // ANCHOR: cleanup
    // The wait before teardown (the book's "Waiting before teardown"): GL, then Vulkan, once.
    unsafe { gl.finish() };
    vk.wait_idle()?;
    drop(commands);
    drop(timestamps);
    drop(gl_timer);
    drop(tracer); // the AO image (GL's side, then Vulkan's), then the pipeline
    drop(gbuffers);
    drop(shared); // the structures, then the shared buffers; the allocator with its last handle
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

/// Mean absolute difference between horizontally neighbouring covered pixels: edges add a fixed
/// amount, sampling noise the rest, which accumulation must shrink. And how many pairs there were.
fn noise(visibility: &[f32], positions: &[f32], width: usize) -> (f64, usize) {
    let covered = |i: usize| positions[i * 4 + 3] > 0.0;
    let pairs: Vec<f64> = (0..visibility.len() - 1)
        .filter(|&i| (i + 1) % width != 0 && covered(i) && covered(i + 1))
        .map(|i| (visibility[i] - visibility[i + 1]).abs() as f64)
        .collect();
    (pairs.iter().sum::<f64>() / pairs.len().max(1) as f64, pairs.len())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
