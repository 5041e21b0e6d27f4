//! Chapter 07: the ambient-occlusion ray pipeline.
//!
//! Every frame GL rasterises the G-buffers into Vulkan-owned images and hands them over; a ray
//! generation shader reads each pixel's position and normal, casts short rays over the
//! hemisphere, and folds the fraction that escape into a running mean, stored in an R32F image
//! that GL reads back. Frames accumulate until the camera or a parameter changes.
//!
//! Run: `cargo run --release --bin 07-ao-ray-pipeline -- --frames 16`.

use anyhow::{Result, ensure};
use ash::vk;
use common::accel;
use common::commands::{COLOR_RANGE, Commands, Timestamps};
use common::gbuffer::{GBuffers, SceneBuffers};
use common::gl::{GlContext, MEMORY_EXTENSIONS, ensure_same_device, layout};
use common::interop::{SharedImage, acquire_from_gl, release_to_gl};
use common::raytrace::{AoRays, RayPipeline, push_bytes};
use common::scene::{self, Camera, Normals};
use common::sync::{SEMAPHORE_EXTENSION, Sync};
use common::{
    CommonArgs, RAY_TRACING_EXTENSIONS, Report, Requirements, VulkanContext, open_fd_count, output,
};
use std::ffi::CStr;
use std::path::PathBuf;
use std::process::ExitCode;

const CHAPTER: &str = "07-ao-ray-pipeline";
const REQUIRED: [&CStr; 4] = [
    ash::khr::external_memory_fd::NAME,
    RAY_TRACING_EXTENSIONS[0],
    RAY_TRACING_EXTENSIONS[1],
    RAY_TRACING_EXTENSIONS[2],
];
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];
const RAYGEN: &[u8] = include_bytes!("../../shaders/ao.rgen.spv");
const MISS: &[u8] = include_bytes!("../../shaders/miss.rmiss.spv");

/// Chapter 07: ray-traced ambient occlusion from GL's G-buffers.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// An OBJ file to use instead of the default scene.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Normals for an OBJ file that has none.
    #[arg(long, value_enum, default_value = "smooth")]
    normals: Normals,
    /// Tetrahedra in the default scene.
    #[arg(long, default_value_t = 10_000)]
    instances: u32,
    /// AO rays per pixel per frame.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=256))]
    samples: u32,
    /// How far an occluder counts, in world units [default: 5% of the scene's diagonal].
    #[arg(long)]
    radius: Option<f32>,
    /// Contrast: the picture shows visibility to this power.
    #[arg(long, default_value_t = 2.0)]
    power: f32,
    /// Stop accumulating once a pixel has this many rays.
    #[arg(long, default_value_t = 4096)]
    max_samples: u32,
}

impl AsRef<CommonArgs> for Args {
    fn as_ref(&self) -> &CommonArgs {
        &self.common
    }
}

fn main() -> ExitCode {
    common::run_chapter::<Args>(CHAPTER, run)
}

fn run(args: &Args, report: &mut Report) -> Result<()> {
    let extent = vk::Extent2D { width: args.common.size.width, height: args.common.size.height };
    let aspect = extent.width as f32 / extent.height as f32;
    ensure!((1.0..=3.0).contains(&args.power), "--power {}: choose between 1 and 3", args.power);

    // 1. Load the scene, and choose a radius that suits its size
    let scene = match &args.scene {
        Some(path) => scene::load_obj(path, args.normals)?,
        None => scene::default_scene(args.instances, 1),
    };
    let camera = Camera::framing(scene.bounds, aspect);
    // ANCHOR: radius
    // A fixed radius suits one scene only: the bunny is 0.15 units tall, the default scene 20 wide.
    let radius = args.radius.unwrap_or(0.05 * scene.size());
    ensure!(radius > 0.0 && radius.is_finite(), "--radius {radius}: must be a positive distance");
    // ANCHOR_END: radius

    // 2. Create both contexts, share the scene, build its acceleration structures (05, 06)
    let requirements =
        Requirements { extensions: &REQUIRED, optional_extensions: OPTIONAL, ray_tracing: true };
    let vk = VulkanContext::new(&requirements)?;
    let gl_context = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    report.vulkan = Some(vk.report());
    report.gl = Some(gl_context.report());
    report.uuids_match = Some(common::gl::uuids_match(&vk.info, &gl_context));
    ensure_same_device(&vk.info, &gl_context)?;
    let sync = Sync::new(&vk, &gl_context)?;
    report.sync = Some(sync.name());
    let open_fds_before = open_fd_count()?;
    let mut allocator = accel::allocator(&vk)?;
    let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
        | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
    let buffers = SceneBuffers::share(&vk, &gl_context, &scene, usage)?;
    let commands = Commands::new(&vk)?;
    let structures = accel::build(&vk, &mut allocator, &commands, &scene, &buffers)?;

    // 3. Share the G-buffers and the AO image
    // ANCHOR: images
    // The ray tracer reads the G-buffers as storage images.
    let gbuffers = GBuffers::new(&vk, &gl_context, &buffers, extent, vk::ImageUsageFlags::STORAGE)?;
    // One float per pixel: the running mean of visibility. Vulkan writes it (STORAGE), GL
    // samples it (SAMPLED; chapter 08 composites with it).
    let ao_usage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
    let ao = SharedImage::new(&vk, &gl_context, vk::Format::R32_SFLOAT, glow::R32F, ao_usage, extent)?;
    // ANCHOR_END: images

    // 4. The AO pipeline: ray generation and miss, no hit group
    // ANCHOR: pipeline
    let binding = |binding, ty| {
        vk::DescriptorSetLayoutBinding::default()
            .binding(binding)
            .descriptor_type(ty)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::RAYGEN_KHR)
    };
    let bindings = [
        binding(0, vk::DescriptorType::ACCELERATION_STRUCTURE_KHR),
        binding(1, vk::DescriptorType::STORAGE_IMAGE), // positions
        binding(2, vk::DescriptorType::STORAGE_IMAGE), // normals
        binding(3, vk::DescriptorType::STORAGE_IMAGE), // AO
    ];
    let pipeline =
        RayPipeline::new(&vk, &mut allocator, RAYGEN, MISS, &bindings, size_of::<AoRays>() as u32)?;
    pipeline.write_tlas(&vk, 0, structures.tlas.handle);
    pipeline.write_storage_image(&vk, 1, gbuffers.images[0].view);
    pipeline.write_storage_image(&vk, 2, gbuffers.images[1].view);
    pipeline.write_storage_image(&vk, 3, ao.view);
    // ANCHOR_END: pipeline

    // 5. Every frame: GL draws, Vulkan traces and accumulates, GL reads
    let timestamps = Timestamps::new(&vk)?;
    let gbuffer_textures = gbuffers.textures();
    let mut accumulated = 0u32;
    let (mut trace_ms, mut rays) = (0.0, 0u64);
    let mut first_noise = None;
    let (mut visibility, mut positions) = (Vec::new(), Vec::new());
    for frame in 0..args.common.frames.max(1) {
        gbuffers.draw(gl, &scene, &camera);
        if accumulated >= args.max_samples {
            continue; // converged: nothing left to trace (a real viewer would just show it)
        }
        // ANCHOR: frame
        let samples = args.samples.min(args.max_samples - accumulated);
        // GL hands over positions and normals in GENERAL, the layout storage images need. The AO
        // image has been GL's since the previous frame (it sampled it); frame 0 it never was.
        let mut textures = gbuffer_textures[..2].to_vec();
        let mut layouts = vec![layout::GENERAL; 2];
        if frame > 0 {
            textures.push(ao.texture.texture);
            layouts.push(layout::SHADER_READ_ONLY);
        }
        sync.gl_release(&gl_context, &textures, &layouts);
        let cb = commands.begin(&vk)?;
        let push = AoRays { samples, accumulated, radius };
        unsafe { record_frame(&vk, cb, &gbuffers, &ao, frame == 0, &pipeline, &push, timestamps.as_ref()) };
        let rays_stage = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
        commands.submit(&vk, sync.vulkan_waits_on().map(|s| (s, rays_stage)), sync.vulkan_signals())?;
        let textures = [gbuffer_textures[0], gbuffer_textures[1], ao.texture.texture];
        let layouts = [layout::COLOR_ATTACHMENT, layout::COLOR_ATTACHMENT, layout::SHADER_READ_ONLY];
        sync.gl_acquire(&vk, &gl_context, commands.fence, &textures, &layouts)?;
        accumulated += samples;
        // ANCHOR_END: frame
        // GL reads back what Vulkan accumulated (the CPU waits here: this is for the checks).
        visibility = output::read_texture_f32(gl, ao.texture.texture, extent.width, extent.height, 1);
        if frame == 0 {
            positions = output::read_texture_f32(gl, gbuffer_textures[0], extent.width, extent.height, 4);
            first_noise = Some(noise(&visibility, &positions, extent.width as usize));
        }
        unsafe { vk.device.wait_for_fences(&[commands.fence], true, u64::MAX) }?;
        if let Some(t) = &timestamps {
            trace_ms += t.read_ms(&vk)?;
        }
        rays += positions.chunks_exact(4).filter(|p| p[3] > 0.0).count() as u64 * samples as u64;
    }
    gl_context.check_error("the frame loop")?;

    // 6. Check the occlusion, and show it
    let covered: Vec<usize> = (0..visibility.len()).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
    let shown: Vec<f32> = visibility.iter().map(|v| v.powf(args.power)).collect();
    let mean = covered.iter().map(|&i| shown[i] as f64).sum::<f64>() / covered.len().max(1) as f64;
    let min = covered.iter().map(|&i| visibility[i]).fold(1.0f32, f32::min);
    report.check("ao_within_0_and_1", visibility.iter().all(|v| (0.0..=1.0).contains(v)));
    report.check(
        "background_unoccluded",
        (0..visibility.len()).all(|i| covered.contains(&i) || visibility[i] == 1.0),
    );
    let last_noise = noise(&visibility, &positions, extent.width as usize);
    if let Some(first) = first_noise.filter(|_| accumulated > args.samples) {
        eprintln!(
            "noise between neighbours: {first:.4} after one frame, {last_noise:.4} after {accumulated} rays"
        );
        report
            .check("accumulation_reduces_noise", last_noise <= first && (first < 1e-3 || last_noise < first));
    }
    report.set("ao_mean", (mean * 1e4).round() / 1e4);
    report.set("ao_min", (min as f64 * 1e4).round() / 1e4);
    report.set("samples_per_pixel", accumulated);
    report.set("radius", radius);
    report.set("rays_traced", rays);
    if timestamps.is_some() {
        report.time_ms("trace_gpu_total", trace_ms);
        report.set("mrays_per_s", ((rays as f64 / (trace_ms / 1e3)) / 1e6 * 10.0).round() / 10.0);
    }
    let prefix = match args.scene.as_ref().and_then(|p| p.file_stem()) {
        Some(stem) => format!("{CHAPTER}-{}", stem.to_string_lossy()),
        None => CHAPTER.to_owned(),
    };
    let upright = output::flip_rows(&output::grey(&shown), extent.width, extent.height);
    output::save_rgba8(
        report,
        &args.common.out_dir(CHAPTER),
        &prefix,
        extent.width,
        extent.height,
        &upright,
    )?;

    // 7. Clean up, newest first
    // ANCHOR: cleanup
    if let Some(t) = timestamps {
        t.destroy(&vk);
    }
    pipeline.destroy(&vk, &mut allocator);
    ao.destroy(&vk, &gl_context);
    gbuffers.destroy(&vk, &gl_context);
    structures.destroy(&vk, &mut allocator);
    commands.destroy(&vk);
    drop(allocator);
    buffers.destroy(&vk, &gl_context);
    sync.destroy(&vk, &gl_context);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", open_fd_count()? == open_fds_before);
    Ok(())
}

// ANCHOR: record_frame
/// Take the G-buffers and the AO image from GL, trace, give them back.
#[allow(clippy::too_many_arguments)]
unsafe fn record_frame(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    gbuffers: &GBuffers,
    ao: &SharedImage,
    first_frame: bool,
    pipeline: &RayPipeline,
    push: &AoRays,
    timestamps: Option<&Timestamps>,
) {
    let general = vk::ImageLayout::GENERAL;
    let (read, write) = (vk::AccessFlags::SHADER_READ, vk::AccessFlags::SHADER_WRITE);
    let mut acquire: Vec<_> =
        gbuffers.images[..2].iter().map(|i| acquire_from_gl(vk, i, general, general, read)).collect();
    acquire.push(if first_frame {
        // Never GL's yet: its contents are undefined, and the first frame overwrites them all.
        vk::ImageMemoryBarrier::default()
            .image(ao.image)
            .subresource_range(COLOR_RANGE)
            .old_layout(vk::ImageLayout::UNDEFINED)
            .new_layout(general)
            .dst_access_mask(read | write)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
    } else {
        // GL sampled it; its contents are the running mean so far, which the shader reads.
        acquire_from_gl(vk, ao, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL, general, read | write)
    });
    // Back to GL: G-buffers as attachments to draw the next frame into (nothing written here),
    // the AO image to sample, its writes made available.
    let attachment = vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL;
    let mut release: Vec<_> = gbuffers.images[..2]
        .iter()
        .map(|i| release_to_gl(vk, i, general, attachment, vk::AccessFlags::NONE))
        .collect();
    release.push(release_to_gl(vk, ao, general, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL, write));
    let rays = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
    let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
    let none = vk::DependencyFlags::empty();
    unsafe {
        if let Some(t) = timestamps {
            t.reset(vk, cb);
        }
        // From the stage the submission waits for GL at: the layout changes must come after GL's signal.
        vk.device.cmd_pipeline_barrier(cb, rays, rays, none, &[], &[], &acquire);
        if let Some(t) = timestamps {
            t.start(vk, cb, rays);
        }
        pipeline.trace(vk, cb, push_bytes(push), gbuffers.extent);
        if let Some(t) = timestamps {
            t.end(vk, cb);
        }
        vk.device.cmd_pipeline_barrier(cb, rays, bottom, none, &[], &[], &release);
    }
}
// ANCHOR_END: record_frame

/// Mean absolute difference between horizontally neighbouring covered pixels: edges add a fixed
/// amount, sampling noise the rest, which accumulation must shrink.
fn noise(visibility: &[f32], positions: &[f32], width: usize) -> f64 {
    let covered = |i: usize| positions[i * 4 + 3] > 0.0;
    let pairs: Vec<f64> = (0..visibility.len() - 1)
        .filter(|&i| (i + 1) % width != 0 && covered(i) && covered(i + 1))
        .map(|i| (visibility[i] - visibility[i + 1]).abs() as f64)
        .collect();
    pairs.iter().sum::<f64>() / pairs.len().max(1) as f64
}
