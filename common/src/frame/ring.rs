//! Chapter 14's frame, which `bench --probe one-process` draws too: a ring of exportable images
//! that Vulkan alone draws into (a clear and a copy, a picture each side can check), and GL's
//! reading of one slot (its wait for Vulkan's frame, the read, and the checks that what was read
//! is the frame announced).

use crate::base::commands::{COLOR_LAYERS, COLOR_RANGE, Commands, HostBuffer, image_barrier};
use crate::base::gl::{GlContext, Owned as GlOwned, Semaphore, layout};
use crate::base::owned::Owned;
use crate::base::vulkan::VulkanContext;
use crate::instruments::{fail, output};
use crate::interop::SharedTexture;
use crate::interop::exportable::{self, Dedicated, ExportableMemory};
use anyhow::{Result, bail};
use ash::vk;
use glow::HasContext;
use std::os::fd::OwnedFd;
use std::time::{Duration, Instant};

// ANCHOR: picture
/// Frame `frame`'s picture, which both processes know: a background colour no nearby frame
/// shares, and a white square (x, y, side) that moves one step a frame. A viewer that read a
/// slot too early, or the wrong slot, sees another frame's colour or square.
pub fn picture(frame: u64, width: u32, height: u32) -> ([u8; 4], (u32, u32, u32)) {
    let channel = |step: u64| (20 + frame * step % 200) as u8;
    let background = [channel(37), channel(91), channel(53), 255];
    let side = width.min(height) / 4;
    let x = (frame * 3 % (width - side + 1) as u64) as u32;
    (background, (x, (height - side) / 2, side))
}
// ANCHOR_END: picture

/// The ring: `slots` exportable RGBA8 images, each with memory of its own, and what draws into
/// them. Dropped in field order: the commands (waiting for their last submission), the square,
/// then each image and its memory.
pub struct Ring {
    commands: Commands,
    /// The white square's pixels, copied into each frame.
    square: HostBuffer,
    pub slots: Vec<(Owned<vk::Image>, ExportableMemory)>,
    fd_loader: ash::khr::external_memory_fd::Device,
    pub extent: vk::Extent2D,
}

impl Ring {
    pub fn new(vk: &VulkanContext, slots: u32, extent: vk::Extent2D) -> Result<Ring> {
        // ANCHOR: ring
        let usage = vk::ImageUsageFlags::TRANSFER_DST // Vulkan clears and copies into it
            | vk::ImageUsageFlags::COLOR_ATTACHMENT // a windowed viewer blits from a framebuffer on it
            | vk::ImageUsageFlags::SAMPLED; // GL reads it as a texture (glGetTexImage)
        let ring = (0..slots)
            .map(|_| -> Result<_> {
                let image = exportable::create_image(vk, vk::Format::R8G8B8A8_UNORM, usage, extent)?;
                let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
                let local = vk::MemoryPropertyFlags::DEVICE_LOCAL;
                let memory = exportable::allocate(vk, &requirements, local, Dedicated::Image(*image))?;
                fail::call("vkBindImageMemory (a ring slot)", || unsafe {
                    vk.device.bind_image_memory(*image, *memory.memory, 0)
                })?;
                Ok((image, memory)) // dropped in that order: the image, then its memory
            })
            .collect::<Result<Vec<_>>>()?;
        // ANCHOR_END: ring
        let side = picture(0, extent.width, extent.height).1.2;
        let mut square =
            HostBuffer::new(vk, side as u64 * side as u64 * 4, vk::BufferUsageFlags::TRANSFER_SRC)?;
        square.bytes_mut().fill(255); // white, opaque
        let commands = Commands::new(vk)?; // dropped first: it waits for its last submission
        // Every slot starts outside Vulkan, in GENERAL, as it is after each frame's release.
        commands.run_once(vk, |cb| unsafe {
            let to_general = (vk::ImageLayout::UNDEFINED, vk::ImageLayout::GENERAL);
            let none = vk::AccessFlags::NONE;
            let families = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
            let barriers: Vec<_> = ring
                .iter()
                .map(|(image, _)| image_barrier(**image, to_general, (none, none), families))
                .collect();
            let (top, bottom) = (vk::PipelineStageFlags::TOP_OF_PIPE, vk::PipelineStageFlags::BOTTOM_OF_PIPE);
            vk.device.cmd_pipeline_barrier(
                cb,
                top,
                bottom,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &barriers,
            );
        })?;
        let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
        Ok(Ring { commands, square, slots: ring, fd_loader, extent })
    }

    /// Each slot's `allocationSize`: what GL must be told its memory object's size is.
    pub fn memory_size(&self) -> u64 {
        self.slots[0].1.size
    }

    /// A new fd for slot `slot`'s memory, the caller's to send or import.
    pub fn memory_fd(&self, slot: usize) -> Result<OwnedFd> {
        exportable::export_fd(&self.fd_loader, *self.slots[slot].1.memory)
    }

    // ANCHOR: draw
    /// Frame `frame` into slot `slot`: clear to the background, copy the white square in, and
    /// hand the image back outside Vulkan, signalling `frame_written` if given. Waits for the
    /// fence: the caller announces the frame only then.
    pub fn draw(
        &self,
        vk: &VulkanContext,
        frame: u64,
        slot: usize,
        frame_written: Option<vk::Semaphore>,
    ) -> Result<()> {
        let (image, (width, height)) = (*self.slots[slot].0, (self.extent.width, self.extent.height));
        let (background, (x, y, side)) = picture(frame, width, height);
        let cb = self.commands.begin(vk)?;
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
            vk.device.cmd_copy_buffer_to_image(cb, *self.square.buffer, image, dst, &[region]);
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
        self.commands.submit(vk, None, frame_written)?;
        self.commands.wait(vk, "vkWaitForFences for the frame")
    }
    // ANCHOR_END: draw
}

// ANCHOR: read_slot
/// GL's queue waits for Vulkan's signal on `frame_written`, and takes `texture`'s image in the
/// layout Vulkan's release left it in: GENERAL. (The renderer announces a frame only once its
/// fence has signalled: this wait is already satisfied, and cannot be left hanging.)
pub fn wait_until_written(
    gl_context: &GlContext,
    texture: &SharedTexture,
    frame_written: &GlOwned<Semaphore>,
) {
    let ext = gl_context.semaphores.as_ref().expect("semaphores were negotiated with GL's");
    let (textures, layouts) = ([texture.texture.0.get()], [layout::GENERAL]);
    unsafe {
        (ext.WaitSemaphoreEXT)(
            frame_written.name.0,
            0,
            std::ptr::null(),
            1,
            textures.as_ptr(),
            layouts.as_ptr(),
        )
    };
}

/// The slot's pixels, row 0 first as Vulkan wrote it, once everything GL was asked so far is
/// done (or the renderer lied): waited on the CPU, with `timeout`, so that a wait that never
/// ends is an error rather than a hang.
pub fn read_slot(
    gl_context: &GlContext,
    texture: &SharedTexture,
    (width, height): (u32, u32),
    timeout: Duration,
) -> Result<Vec<u8>> {
    gl_finished(gl_context, timeout)?;
    // glGetTexImage returns when the pixels are in our memory: GL is done with the slot. (Not
    // glReadPixels through a framebuffer: on NVIDIA's driver that takes about 27 ms from an
    // imported texture, glGetTexImage a fraction of one.)
    let read = output::read_texture_rgba8(&gl_context.gl, *texture.texture, width, height);
    gl_context.check_error("reading a slot")?;
    Ok(output::flip_rows(&read, width, height))
}
// ANCHOR_END: read_slot

/// Waits, on the CPU, for every GL command issued so far (a fence, `glClientWaitSync`), for up
/// to `timeout`. GL takes a wait of at most about two seconds at a time: it is asked again.
pub fn gl_finished(gl_context: &GlContext, timeout: Duration) -> Result<()> {
    let gl = &gl_context.gl;
    let fence = crate::base::gl::create(gl, "glFenceSync", |gl| unsafe {
        gl.fence_sync(glow::SYNC_GPU_COMMANDS_COMPLETE, 0)
    })?;
    fail::step("glClientWaitSync")?;
    let started = Instant::now();
    loop {
        // FLUSH: the fence is sent to the GPU, or the wait could outlast every timeout.
        match unsafe { gl.client_wait_sync(*fence, glow::SYNC_FLUSH_COMMANDS_BIT, 100_000_000) } {
            glow::ALREADY_SIGNALED | glow::CONDITION_SATISFIED => return Ok(()),
            glow::TIMEOUT_EXPIRED if started.elapsed() < timeout => {}
            glow::TIMEOUT_EXPIRED => bail!("GL's work on a slot did not finish within {timeout:?}"),
            _ => bail!("glClientWaitSync failed (GL_WAIT_FAILED)"),
        }
    }
}

/// Is `pixels` (row 0 first, as Vulkan wrote it) frame `frame`'s picture? Probes the corner
/// (background), the square's centre (white) and the pixel left of it (background, if any).
pub fn is_picture_of(pixels: &[u8], frame: u64, width: u32, height: u32) -> bool {
    let (background, (x, y, side)) = picture(frame, width, height);
    let at = |px: u32, py: u32| &pixels[(py * width + px) as usize * 4..][..4];
    let close = |p: &[u8], q: [u8; 4]| p.iter().zip(q).all(|(&a, b)| a.abs_diff(b) <= 1);
    let left_ok = x == 0 || close(at(x - 1, y + side / 2), background);
    close(at(0, 0), background) && close(at(x + side / 2, y + side / 2), [255; 4]) && left_ok
}

/// Does the window's back buffer show frame `frame`? Its top-left pixel, the background, is
/// read (a window may be any size: the square lands elsewhere, the corner stays background).
pub fn window_shows(
    gl: &glow::Context,
    frame: u64,
    (width, height): (u32, u32),
    (ww, wh): (u32, u32),
) -> bool {
    if ww == 0 || wh == 0 {
        return true; // minimised: nothing to show
    }
    let mut pixel = [0u8; 4];
    unsafe {
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None);
        let data = glow::PixelPackData::Slice(Some(&mut pixel));
        gl.read_pixels(0, wh as i32 - 1, 1, 1, glow::RGBA, glow::UNSIGNED_BYTE, data);
    }
    let (background, _) = picture(frame, width, height);
    pixel[..3].iter().zip(&background[..3]).all(|(a, b)| a.abs_diff(*b) <= 1)
}
