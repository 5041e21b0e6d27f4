//! Chapter 14's picture, drawn by Vulkan alone: a clear and a copy, into one slot of the ring.

use anyhow::Result;
use ash::vk;
use common::VulkanContext;
use common::base::commands::{COLOR_LAYERS, COLOR_RANGE, Commands, HostBuffer, image_barrier};

// ANCHOR: draw
/// Frame `frame` into `image`: clear to the background, copy the white square in, and hand the
/// image back outside Vulkan, signalling `frame_written` if given. Waits for the fence: the
/// caller announces the frame only then.
pub fn draw(
    vk: &VulkanContext,
    commands: &Commands,
    image: vk::Image,
    square: &HostBuffer,
    (background, (x, y, side)): ([u8; 4], (u32, u32, u32)),
    frame_written: Option<vk::Semaphore>,
) -> Result<()> {
    let cb = commands.begin(vk)?;
    let (ours, external) = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
    let (transfer, none) = (vk::PipelineStageFlags::TRANSFER, vk::DependencyFlags::empty());
    let dst = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
    let write = vk::AccessFlags::TRANSFER_WRITE;
    unsafe {
        // Take the slot back from the viewer: from outside Vulkan, from GENERAL, where the last
        // release left it. The viewer's "slot free" came after its reads had finished: nothing
        // to wait for on the GPU, so from the top of the pipe.
        let acquire = image_barrier(
            image,
            (vk::ImageLayout::GENERAL, dst),
            (vk::AccessFlags::NONE, write),
            (external, ours),
        );
        let top = vk::PipelineStageFlags::TOP_OF_PIPE;
        vk.device.cmd_pipeline_barrier(cb, top, transfer, none, &[], &[], &[acquire]);
        let colour = vk::ClearColorValue { float32: background.map(|c| c as f32 / 255.0) };
        vk.device.cmd_clear_color_image(cb, image, dst, &colour, &[COLOR_RANGE]);
        // The clear and the copy write the same pixels: the copy must land after the clear.
        let after_clear = image_barrier(
            image,
            (dst, dst),
            (write, write),
            (vk::QUEUE_FAMILY_IGNORED, vk::QUEUE_FAMILY_IGNORED),
        );
        vk.device.cmd_pipeline_barrier(cb, transfer, transfer, none, &[], &[], &[after_clear]);
        let region = vk::BufferImageCopy::default()
            .image_subresource(COLOR_LAYERS)
            .image_offset(vk::Offset3D { x: x as i32, y: y as i32, z: 0 })
            .image_extent(vk::Extent3D { width: side, height: side, depth: 1 });
        vk.device.cmd_copy_buffer_to_image(cb, *square.buffer, image, dst, &[region]);
        // Release to the viewer: make the writes available, leave it in GENERAL, and hand
        // ownership outside Vulkan. GENERAL is what GL's wait on `frame_written` names (and, on
        // the host path, where GL names no layout, what GL finds and leaves).
        let release = image_barrier(
            image,
            (dst, vk::ImageLayout::GENERAL),
            (write, vk::AccessFlags::NONE),
            (ours, external),
        );
        let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
        vk.device.cmd_pipeline_barrier(cb, transfer, bottom, none, &[], &[], &[release]);
    }
    // With semaphores, the submission signals the slot's `frame_written` once the release is
    // done; GL's wait names the same layout. Nothing of the viewer's is ever waited on here.
    commands.submit(vk, None, frame_written)?;
    commands.wait(vk, "vkWaitForFences for the frame")
}
// ANCHOR_END: draw
