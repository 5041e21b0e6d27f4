//! Chapter 06: BLAS and TLAS.
//!
//! Vulkan builds one bottom-level acceleration structure per mesh straight from the vertex and
//! index buffers GL draws from, compacts them, and builds the top level from the very instance
//! buffer GL's instanced draws read. Then it proves the structures hold what GL rasterised: one
//! primary ray per pixel must hit exactly where the G-buffers are covered.
//!
//! Run: `cargo run --release --bin 06-blas-tlas` (or `-- --scene assets/bunny.obj`).

use anyhow::Result;
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::{
    Commands, HostBuffer, copy_image_to_buffer, first_use, image_barrier, transfers_to_host,
};
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::instruments::output;
use common::interop::handoff::{HandOver, SEMAPHORE_EXTENSION};
use common::interop::{acquire_from_gl, release_to_gl};
use common::rt::accel;
use common::rt::raytrace::{PrimaryRays, RayPipeline, RayShaders, StorageImage};
use common::scene::gbuffer::{self, GBuffers, SceneBuffers};
use common::scene::{Camera, SceneArgs};
use common::{Flags, RAY_TRACING_EXTENSIONS, Report, Requirements, VulkanContext, open_fd_count};
use glow::HasContext as _;
use std::ffi::CStr;
use std::process::ExitCode;

const CHAPTER: &str = "06-blas-tlas";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 4,
    height: 4,
    why: "rays must hit the scene somewhere, and a single row can pass below or above it",
    shape: Some((16.0, 16.0, "framed wider or taller, the rays can miss the scene")),
};
const REQUIRED: [&CStr; 4] = [
    ash::khr::external_memory_fd::NAME,
    RAY_TRACING_EXTENSIONS[0],
    RAY_TRACING_EXTENSIONS[1],
    RAY_TRACING_EXTENSIONS[2],
];
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];
const RAYGEN: &[u8] = include_bytes!("../../shaders/primary.rgen.spv");
const MISS: &[u8] = include_bytes!("../../shaders/miss.rmiss.spv");

/// Chapter 06: acceleration structures from the buffers GL draws, checked against GL's picture.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    scene: SceneArgs,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    // 1. Load the scene (chapter 05)
    let scene = args.scene.load()?;
    let camera = Camera::framing(scene.bounds, args.common.size.aspect());

    // 2. Create both contexts, with ray tracing
    // ANCHOR: context
    let requirements = Requirements {
        extensions: &REQUIRED,
        optional_extensions: OPTIONAL,
        ray_tracing: true,
        ..Default::default()
    };
    // As in chapter 05: the G-buffers' size checked, and the hand-off between the two APIs.
    let (vk, gl_context, handoff) = gbuffer::contexts(CHAPTER, report, &requirements, args.common.size)?;
    // ANCHOR_END: context
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    let allocator = accel::allocator(&vk)?;

    // 3. Share the scene's buffers, readable by acceleration-structure builds
    // ANCHOR: share
    // Build inputs are read through device addresses.
    let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
        | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
    let buffers = SceneBuffers::share(&vk, &gl_context, &scene, usage)?;
    // ANCHOR_END: share

    // 4. Build the acceleration structures
    // ANCHOR: build
    let commands = Commands::new(&vk)?;
    let structures = accel::build(&vk, &allocator, &commands, &scene, &buffers)?;
    drop(commands); // each build waited for its submission: nothing is in flight
    // ANCHOR_END: build
    report.set("instances", scene.instances.len());
    report.set("triangles", scene.triangles());
    report.set("acceleration_structures", &structures.stats);
    let stats = &structures.stats;
    let timings = [
        ("blas_build_gpu", stats.blas_build_ms),
        ("compaction_gpu", stats.compaction_ms),
        ("tlas_build_gpu", stats.tlas_build_ms),
    ];
    for (name, ms) in timings {
        ms.inspect(|&ms| report.time_ms(name, ms));
    }
    eprintln!(
        "BLAS: {} bytes built, {} compacted; TLAS: {} bytes",
        stats.blas_bytes, stats.compacted_bytes, stats.tlas_bytes
    );
    report.check("compaction_did_not_grow", stats.compacted_bytes <= stats.blas_bytes);

    // 5. GL draws the G-buffers (chapter 05)
    let extent = args.common.size.extent();
    let gbuffers =
        GBuffers::new(&vk, &gl_context, &handoff, &buffers, extent, vk::ImageUsageFlags::TRANSFER_SRC)?;
    let mut gl_timer = GlPassTimer::new(gl)?; // common::clocks::timing, as in chapter 05
    gl_timer.time(gl, "gbuffer", || gbuffers.draw(gl, &scene, &camera))?;
    gl_context.check_error("drawing the G-buffers")?;

    // 6. Trace one primary ray per pixel
    // ANCHOR: pipeline
    let stage = vk::ShaderStageFlags::RAYGEN_KHR;
    let bindings = [
        vk::DescriptorSetLayoutBinding::default()
            .binding(0)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .descriptor_count(1)
            .stage_flags(stage),
        vk::DescriptorSetLayoutBinding::default()
            .binding(1)
            .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
            .descriptor_count(1)
            .stage_flags(stage),
    ];
    let push = PrimaryRays::new(&camera, args.common.size.aspect());
    let shaders = RayShaders { raygen: RAYGEN, miss: MISS };
    let pipeline = RayPipeline::new(&vk, &allocator, shaders, &bindings, size_of::<PrimaryRays>() as u32)?;
    let mask = StorageImage::new(
        &vk,
        &allocator,
        vk::Format::R8G8B8A8_UNORM,
        vk::ImageUsageFlags::TRANSFER_SRC,
        extent,
    )?;
    pipeline.write_tlas(&vk, 0, *structures.tlas.handle);
    pipeline.write_storage_image(&vk, 1, *mask.view);
    // ANCHOR_END: pipeline
    let pixels = (extent.width * extent.height) as u64;
    let hits = HostBuffer::new(&vk, pixels * 4, vk::BufferUsageFlags::TRANSFER_DST)?;
    let coverage = HostBuffer::new(&vk, pixels * 16, vk::BufferUsageFlags::TRANSFER_DST)?;
    let timestamps = Timestamps::new(&vk)?;
    // The trace's command buffer, made after everything the trace uses: an early return drops it
    // first, and its Drop waits for the trace before any of those is destroyed.
    let commands = Commands::new(&vk)?;
    let textures = gbuffers.textures();
    // As in chapter 05: copied from, then given back as attachments (GENERAL on the host path).
    let layouts =
        handoff.hand_over(vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL);
    let (signal_layout, wait_layout) = layouts.gl(); // as GL names them
    handoff.gl_release(&gl_context, &textures, &[signal_layout; 3]);
    let cb = commands.begin(&vk)?;
    unsafe {
        let trace = Trace {
            gbuffers: &gbuffers,
            layouts,
            pipeline: &pipeline,
            mask: &mask,
            push: &push,
            hits: &hits,
            coverage: &coverage,
        };
        trace.record(&vk, cb, timestamps.as_ref())
    };
    let wait = handoff.vulkan_waits_on().map(|s| (s, vk::PipelineStageFlags::TRANSFER));
    commands.submit(&vk, wait, handoff.vulkan_signals())?;
    handoff.gl_acquire(&vk, &gl_context, *commands.fence, &textures, &[wait_layout; 3])?;
    commands.wait(&vk, "vkWaitForFences for the trace")?;
    if let Some(t) = &timestamps {
        report.time_ms("trace_gpu", t.read_ms(&vk)?);
    }
    // The raster's time, read now that the trace has waited for it (reading earlier would wait).
    let mut times = PassTimes::new();
    gl_timer.finish(gl, &mut times);
    times.record(report);

    // 7. Compare what the rays hit with what GL covered
    // ANCHOR: compare
    let hit: Vec<bool> = hits.bytes().chunks_exact(4).map(|p| p[0] > 127).collect();
    let covered: Vec<bool> = coverage.rgba32f().iter().map(|p| p[3] > 0.0).collect();
    let (w, h) = (extent.width as usize, extent.height as usize);
    // A silhouette pixel has both covered and uncovered pixels among its 3x3 neighbours: there,
    // sampling differences between the rasteriser and the rays may legitimately disagree.
    let silhouette = |i: usize| {
        let (x, y) = (i % w, i / w);
        let around = (y.saturating_sub(1)..(y + 2).min(h))
            .flat_map(|v| (x.saturating_sub(1)..(x + 2).min(w)).map(move |u| v * w + u));
        around.map(|j| covered[j]).collect::<std::collections::HashSet<_>>().len() == 2
    };
    let mismatched: Vec<usize> = (0..w * h).filter(|&i| hit[i] != covered[i]).collect();
    let fraction = mismatched.len() as f64 / (w * h) as f64;
    // ANCHOR_END: compare
    eprintln!(
        "rays and raster disagree on {} of {} pixels ({:.3}%)",
        mismatched.len(),
        w * h,
        fraction * 100.0
    );
    report.set("mismatch_fraction", (fraction * 1e5).round() / 1e5);
    report.set(
        "covered_fraction",
        (covered.iter().filter(|&&c| c).count() as f64 / (w * h) as f64 * 1e3).round() / 1e3,
    );
    report.check("rays_hit_where_gl_drew", covered.iter().any(|&c| c) && fraction < 0.01);
    report.check("mismatches_only_on_silhouettes", mismatched.iter().all(|&i| silhouette(i)));

    // White: both; black: neither; red: only the rays hit; blue: only GL drew.
    let picture: Vec<u8> = hit
        .iter()
        .zip(&covered)
        .flat_map(|(&hit, &covered)| match (hit, covered) {
            (true, true) => [255, 255, 255, 255],
            (false, false) => [0, 0, 0, 255],
            (true, false) => [255, 0, 0, 255],
            (false, true) => [0, 80, 255, 255],
        })
        .collect();
    let prefix = args.scene.picture_name(CHAPTER);
    let out = args.common.out_dir(CHAPTER);
    output::save_gl_rgba8(report, &out, &prefix, (extent.width, extent.height), &picture)?;

    common::interop::report_handoff(report, &handoff);
    // 8. Clean up, newest first
    // ANCHOR: cleanup
    // The wait before teardown (the book's "Waiting before teardown"): GL, then Vulkan, once.
    unsafe { gl.finish() };
    vk.wait_idle()?;
    drop(commands);
    drop(timestamps);
    drop(coverage);
    drop(hits);
    drop(mask); // view and image, then its memory goes back to the allocator
    drop(pipeline); // descriptors, pipeline, layouts, then the shader binding table
    drop(gl_timer);
    drop(gbuffers); // GL's objects, then each image, GL's side first
    drop(structures); // the TLAS, then the BLASes it refers to
    // (Every allocation holds a handle to the allocator, which frees its memory blocks when the
    // last handle goes: `allocator`, at the end of `run`, before the device. Never by hand.)
    drop(buffers); // never from the allocator: each GL side, then Vulkan's
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

// ANCHOR: record_trace
/// What one frame's trace reads and writes.
struct Trace<'a> {
    gbuffers: &'a GBuffers,
    /// The G-buffers' layouts at the hand-overs (`Handoff::hand_over`).
    layouts: HandOver,
    pipeline: &'a RayPipeline,
    /// Where the rays write what they hit, and the host buffer it is copied into.
    mask: &'a StorageImage,
    hits: &'a HostBuffer,
    push: &'a PrimaryRays,
    /// Where GL's position G-buffer is copied: which pixels GL covered.
    coverage: &'a HostBuffer,
}

impl Trace<'_> {
    /// Take the position G-buffer from GL and copy it out (GL's coverage); trace the rays into the
    /// mask and copy that out; give the G-buffers back.
    unsafe fn record(&self, vk: &VulkanContext, cb: vk::CommandBuffer, timestamps: Option<&Timestamps>) {
        let Trace { gbuffers, layouts, pipeline, mask, hits, push, coverage } = *self;
        let device = &vk.device;
        let none = vk::DependencyFlags::empty();
        let (transfer_src, general) = (vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::GENERAL);
        let (top, transfer, rays) = (
            vk::PipelineStageFlags::TOP_OF_PIPE,
            vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR,
        );
        let acquire: Vec<_> = gbuffers
            .images
            .iter()
            .map(|i| acquire_from_gl(vk, i, layouts.to_vulkan, transfer_src, vk::AccessFlags::TRANSFER_READ))
            .collect();
        let release: Vec<_> = gbuffers
            .images
            .iter()
            .map(|i| release_to_gl(vk, i, transfer_src, layouts.to_gl, vk::AccessFlags::NONE))
            .collect();
        unsafe {
            if let Some(t) = timestamps {
                t.reset(vk, cb);
            }
            // From TRANSFER, the stage the submission waits for GL at: the acquire comes after GL's signal.
            device.cmd_pipeline_barrier(cb, transfer, transfer, none, &[], &[], &acquire);
            copy_image_to_buffer(
                vk,
                cb,
                *gbuffers.images[0].image,
                transfer_src,
                gbuffers.extent,
                *coverage.buffer,
            );
            device.cmd_pipeline_barrier(
                cb,
                transfer,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                none,
                &[],
                &[],
                &release,
            );

            // The mask starts undefined (its old contents do not matter) and becomes a storage image.
            let to_storage = first_use(*mask.image, general, vk::AccessFlags::SHADER_WRITE);
            device.cmd_pipeline_barrier(cb, top, rays, none, &[], &[], &[to_storage]);
            if let Some(t) = timestamps {
                t.start(vk, cb, rays);
            }
            pipeline.trace(vk, cb, bytemuck::bytes_of(push), mask.extent);
            if let Some(t) = timestamps {
                t.end(vk, cb);
            }
            // The shader's writes finish before the copy reads them.
            let (layouts, accesses) =
                ((general, transfer_src), (vk::AccessFlags::SHADER_WRITE, vk::AccessFlags::TRANSFER_READ));
            let ignored = (vk::QUEUE_FAMILY_IGNORED, vk::QUEUE_FAMILY_IGNORED);
            let to_copy = image_barrier(*mask.image, layouts, accesses, ignored);
            device.cmd_pipeline_barrier(cb, rays, transfer, none, &[], &[], &[to_copy]);
            copy_image_to_buffer(vk, cb, *mask.image, transfer_src, mask.extent, *hits.buffer);
            transfers_to_host(vk, cb);
        }
    }
}
// ANCHOR_END: record_trace

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
