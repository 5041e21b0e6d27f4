//! Would Vulkan composite faster than GL? `bench --probe vulkan-composite --rounds N`: after the frames,
//! Vulkan takes the surface from GL and runs the same composite (`composite_tile.glsl`) as a
//! Vulkan compute shader N times, each between two timestamps, into a picture of its own, which
//! must match GL's. Either way the picture goes to GL afterwards (GL draws the overlays with its
//! depth, and shows it), so a Vulkan composite saves no hand-over: only the difference between
//! the two dispatches could pay.

use super::Frame;
use anyhow::{Context as _, Result};
use ash::vk;
use common::base::commands::{Commands, HostBuffer, copy_image_to_buffer, first_use, transfers_to_host};
use common::base::compute::ComputePipeline;
use common::clocks::timestamps::Timestamps;
use common::interop::handoff::Apis;
use common::interop::{acquire_from_gl, release_to_gl};
use common::rt::accel::GpuAllocator;
use common::rt::raytrace::StorageImage;
use fast_frame::composite::Uniforms;
use fast_frame::visibility::Targets;

const SPIRV: &[u8] = include_bytes!("../../../shaders/fast_composite.comp.spv");

/// `fast_composite.comp`'s push constants: the composite's uniforms, as GL's shader has them.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push {
    blur_radius: i32,
    depth_tolerance: f32,
    normal_tolerance: f32,
    power: f32,
    view: i32,
    far_depth: f32,
}

/// What the measurement found: the dispatch's median GPU time, and Vulkan's picture (RGBA8,
/// rows in memory order, as GL's `read_picture` returns GL's).
pub struct Measured {
    pub median_ms: f64,
    pub picture: Vec<u8>,
}

/// `rounds` dispatches of Vulkan's composite over the surface GL holds after the frames.
pub fn measure(
    apis: Apis,
    allocator: &GpuAllocator,
    targets: &Targets,
    u: &Uniforms,
    rounds: u32,
) -> Result<Measured> {
    let Apis { vk, gl, handoff, .. } = apis;
    let extent = targets.extent;
    let push = Push {
        blur_radius: u.blur_radius,
        depth_tolerance: u.depth_tolerance,
        normal_tolerance: u.normal_tolerance,
        power: u.power,
        view: u.view as i32,
        far_depth: u.far_depth,
    };
    let push = bytemuck::bytes_of(&push);
    let pipeline = ComputePipeline::new(vk, SPIRV, 2, push.len() as u32)?;
    let format = vk::Format::R8G8B8A8_UNORM;
    let picture = StorageImage::new(vk, allocator, format, vk::ImageUsageFlags::TRANSFER_SRC, extent)?;
    let bytes = extent.width as u64 * extent.height as u64 * 4;
    let read_back = HostBuffer::new(vk, bytes, vk::BufferUsageFlags::TRANSFER_DST)?;
    let stamps = Timestamps::with_count(vk, 2 * rounds)?
        .with_context(|| format!("--probe vulkan-composite: {} writes no timestamps", vk.info.name))?;
    let commands = &Commands::new(vk)?; // made last: dropped first, it waits for its submission
    pipeline.write_images(vk, &[*targets.surface.view, *picture.view]);

    // The surface: GL sampled it last; Vulkan reads it as a storage image, and gives it back.
    let read_only = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL;
    let layouts = handoff.hand_over(read_only, read_only);
    let (to_vulkan, to_gl) = layouts.gl();
    let texture = [*targets.surface.texture.texture];
    handoff.gl_release(gl, &texture, &[to_vulkan]);
    let cb = commands.begin(vk)?;
    let (general, compute) = (vk::ImageLayout::GENERAL, vk::PipelineStageFlags::COMPUTE_SHADER);
    let (read, write) = (vk::AccessFlags::SHADER_READ, vk::AccessFlags::SHADER_WRITE);
    let none = vk::DependencyFlags::empty();
    unsafe {
        vk.device.cmd_reset_query_pool(cb, *stamps.pool, 0, 2 * rounds);
        let take = [
            acquire_from_gl(vk, &targets.surface, layouts.to_vulkan, general, read),
            first_use(*picture.image, general, write),
        ];
        // From the stage the submission waits for GL at: the acquire follows GL's release.
        vk.device.cmd_pipeline_barrier(cb, compute, compute, none, &[], &[], &take);
        // ANCHOR: rounds
        for round in 0..rounds {
            // The start waits for the previous dispatch (all earlier commands at this stage).
            stamps.write(vk, cb, compute, 2 * round);
            pipeline.dispatch(vk, cb, push, extent);
            stamps.write(vk, cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, 2 * round + 1);
            // Each round writes the picture again: after the last one's writes.
            let again = vk::MemoryBarrier::default().src_access_mask(write).dst_access_mask(write);
            vk.device.cmd_pipeline_barrier(cb, compute, compute, none, &[again], &[], &[]);
        }
        // ANCHOR_END: rounds
        let source = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
        let to_copy = common::base::commands::image_barrier(
            *picture.image,
            (general, source),
            (write, vk::AccessFlags::TRANSFER_READ),
            (vk::QUEUE_FAMILY_IGNORED, vk::QUEUE_FAMILY_IGNORED),
        );
        let transfer = vk::PipelineStageFlags::TRANSFER;
        vk.device.cmd_pipeline_barrier(cb, compute, transfer, none, &[], &[], &[to_copy]);
        copy_image_to_buffer(vk, cb, *picture.image, source, extent, *read_back.buffer);
        transfers_to_host(vk, cb);
        // Back to GL: nothing written, nothing to make available.
        let give = release_to_gl(vk, &targets.surface, general, layouts.to_gl, vk::AccessFlags::NONE);
        vk.device.cmd_pipeline_barrier(
            cb,
            compute,
            vk::PipelineStageFlags::BOTTOM_OF_PIPE,
            none,
            &[],
            &[],
            &[give],
        );
    }
    commands.submit(vk, handoff.vulkan_waits_on().map(|s| (s, compute)), handoff.vulkan_signals())?;
    handoff.gl_acquire(vk, gl, *commands.fence, &texture, &[to_gl])?;
    commands.wait(vk, "vkWaitForFences after the Vulkan composite")?;
    let times: Vec<f64> =
        (0..rounds).map(|round| stamps.between_ms(vk, 2 * round, 2 * round + 1)).collect::<Result<_>>()?;
    let median_ms = common::clocks::timestamps::median_p95(&times).0;
    let measured = Measured { median_ms, picture: read_back.bytes().to_vec() };
    drop(stamps);
    drop(read_back);
    drop(picture);
    drop(pipeline);
    Ok(measured)
}

/// [`measure`], then GL's composite of the same surface with the same uniforms: Vulkan's
/// median time, and the largest difference of any channel between the two pictures (in 1/255),
/// which must be rounding.
pub fn compare(
    apis: Apis,
    allocator: &GpuAllocator,
    frame: &Frame,
    u: &Uniforms,
    rounds: u32,
) -> Result<(f64, u8)> {
    let measured = measure(apis, allocator, &frame.targets, u, rounds)?;
    let gl = &apis.gl.gl;
    frame.composite.draw(gl, &frame.targets, u);
    let drawn = fast_frame::check::read_picture(gl, &frame.targets);
    let largest = measured.picture.iter().zip(&drawn).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(0);
    Ok((measured.median_ms, largest))
}
