//! Vulkan's turn in each of chapter 03's frames: the barriers and copies between its acquire
//! from GL and its release back.

use ash::vk;
use common::VulkanContext;
use common::base::commands::{COLOR_LAYERS, COLOR_RANGE, HostBuffer};
use common::clocks::timestamps::Timestamps;
use common::interop::handoff::HandOver;

// ANCHOR: vulkan_turn
/// Copy GL's pixels out, write Vulkan's pattern in. Every barrier says which earlier work must
/// finish (src) before which later work may start (dst), and moves the image between layouts.
pub fn record_vulkan_turn(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    (image, extent): (vk::Image, vk::Extent2D),
    layouts: HandOver,
    (pattern, readback): (&HostBuffer, &HostBuffer),
    timestamps: Option<&Timestamps>,
) {
    let barrier = |old, new, src_access, dst_access, src_family, dst_family| {
        vk::ImageMemoryBarrier::default()
            .image(image)
            .subresource_range(COLOR_RANGE)
            .old_layout(old)
            .new_layout(new)
            .src_access_mask(src_access)
            .dst_access_mask(dst_access)
            .src_queue_family_index(src_family)
            .dst_queue_family_index(dst_family)
    };
    let (external, ours) = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
    let region = vk::BufferImageCopy::default().image_subresource(COLOR_LAYERS).image_extent(vk::Extent3D {
        width: extent.width,
        height: extent.height,
        depth: 1,
    });
    let device = &vk.device;
    unsafe {
        // Acquire from GL: ownership moves from "outside Vulkan" to our queue family, and the
        // image from the layout GL left it in (its signal's; on the host path GENERAL, where
        // Vulkan's last release left it) to the one the copy wants. The semaphore wait (or
        // glFinish) already made GL's writes available: no source access to wait for.
        let acquire = barrier(
            layouts.to_vulkan,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            vk::AccessFlags::NONE,
            vk::AccessFlags::TRANSFER_READ,
            external,
            ours,
        );
        // From TRANSFER, the stage the submission waits for GL at (step 4): a barrier chains after
        // a semaphore wait only through the stages they share, so an acquire from an earlier
        // stage could change the layout before GL has signalled.
        let transfer = vk::PipelineStageFlags::TRANSFER;
        let none = vk::DependencyFlags::empty();
        device.cmd_pipeline_barrier(cb, transfer, transfer, none, &[], &[], &[acquire]);
        if let Some(t) = timestamps {
            t.start(vk, cb, transfer);
        }
        let transfer_src = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
        device.cmd_copy_image_to_buffer(cb, image, transfer_src, *readback.buffer, &[region]);
        // The copy's reads must finish before the image is overwritten: a write-after-read hazard,
        // so an execution dependency is enough, plus the move to TRANSFER_DST for the write.
        let to_write = barrier(
            transfer_src,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            vk::AccessFlags::NONE,
            vk::AccessFlags::TRANSFER_WRITE,
            ours,
            ours,
        );
        device.cmd_pipeline_barrier(cb, transfer, transfer, none, &[], &[], &[to_write]);
        device.cmd_copy_buffer_to_image(
            cb,
            *pattern.buffer,
            image,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            &[region],
        );
        // Release to GL: make the write available, move to the layout GL will wait with (on the
        // host path, GENERAL: the layout the next frame's acquire starts from), and hand ownership
        // back outside Vulkan. GL's wait on our semaphore (or the fence) does the rest.
        let release = barrier(
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            layouts.to_gl,
            vk::AccessFlags::TRANSFER_WRITE,
            vk::AccessFlags::NONE,
            ours,
            external,
        );
        let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
        device.cmd_pipeline_barrier(cb, transfer, bottom, none, &[], &[], &[release]);
        // The CPU reads `readback` after the fence: make the copy's writes visible to the host.
        let to_host = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ);
        device.cmd_pipeline_barrier(cb, transfer, vk::PipelineStageFlags::HOST, none, &[to_host], &[], &[]);
        if let Some(t) = timestamps {
            t.end(vk, cb);
        }
    }
}
// ANCHOR_END: vulkan_turn
