//! The `cpu-round-trip` mode: what a frame costs without external memory. Every frame the
//! G-buffers GL drew come down to the CPU and go up to Vulkan, and the AO comes down from Vulkan
//! and goes up to GL, each step waiting for the one before.
//!
//! The copies land in buffers and a texture of the bench's own, of the same sizes as the shared
//! images: the frame pays for every byte moved and every wait, while the trace and the composite
//! still use the shared images, so the picture stays chapter 08's and the validation layer sees
//! no ownership but the hand-overs it already knows.

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::commands::{Commands, HostBuffer, transfers_to_host};
use common::rt::accel::GpuAllocator;
use common::rt::accel::{BufferDesc, DeviceBuffer};
use common::scene::gbuffer::GBuffers;
use common::{GlContext, VulkanContext};
use glow::HasContext;
use gpu_allocator::MemoryLocation;

/// Dropped newest first (fields drop in order): the command buffer, once its last copy is done,
/// then GL's texture, then Vulkan's buffers.
pub struct RoundTrip {
    commands: Commands,
    /// GL's copy of the AO, uploaded from the read-back.
    texture: common::base::gl::Owned<glow::Texture>,
    readback: HostBuffer,
    /// The AO as Vulkan would hold it (R32F), and its read-back.
    ao: DeviceBuffer,
    /// Where Vulkan would trace from: device-local.
    gbuffers: DeviceBuffer,
    /// Positions then normals, as GL reads them back (RGBA32F, 32 bytes a pixel).
    upload: HostBuffer,
    extent: vk::Extent2D,
}

impl RoundTrip {
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        allocator: &GpuAllocator,
        extent: vk::Extent2D,
    ) -> Result<Self> {
        let pixels = extent.width as u64 * extent.height as u64;
        let transfer = vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
        let upload = HostBuffer::new(vk, 32 * pixels, transfer)?;
        let gbuffers = DeviceBuffer::new(
            vk,
            allocator,
            BufferDesc {
                name: "round-trip G-buffers",
                size: 32 * pixels,
                usage: transfer,
                location: MemoryLocation::GpuOnly,
            },
        )?;
        let ao = DeviceBuffer::new(
            vk,
            allocator,
            BufferDesc {
                name: "round-trip AO",
                size: 4 * pixels,
                usage: transfer,
                location: MemoryLocation::GpuOnly,
            },
        )?;
        let readback = HostBuffer::new(vk, 4 * pixels, transfer)?;
        let texture =
            common::base::gl::create(&gl.gl, "glCreateTextures for the round trip's AO", |g| unsafe {
                g.create_named_texture(glow::TEXTURE_2D)
            })?;
        unsafe {
            gl.gl.texture_storage_2d(*texture, 1, glow::R32F, extent.width as i32, extent.height as i32)
        };
        // Made after what its copies use: dropped first, it waits for the last of them.
        let commands = Commands::new(vk)?;
        Ok(RoundTrip { commands, upload, gbuffers, ao, readback, texture, extent })
    }

    // ANCHOR: copies
    /// GL -> CPU -> Vulkan: positions and normals read into mapped Vulkan memory (GL finishes its
    /// drawing first: `glGetTexImage` waits for it), then copied to device-local memory.
    pub fn gbuffers_to_vulkan(
        &mut self,
        vk: &VulkanContext,
        gl: &GlContext,
        gbuffers: &GBuffers,
    ) -> Result<()> {
        let half = self.upload.size as usize / 2;
        let bytes = self.upload.bytes_mut();
        for (texture, target) in gbuffers.textures().into_iter().zip(bytes.chunks_exact_mut(half)) {
            unsafe {
                gl.gl.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
                gl.gl.bind_texture(glow::TEXTURE_2D, Some(texture));
                let data = glow::PixelPackData::Slice(Some(target));
                gl.gl.get_tex_image(glow::TEXTURE_2D, 0, glow::RGBA, glow::FLOAT, data);
                gl.gl.bind_texture(glow::TEXTURE_2D, None);
            }
        }
        // Host writes before the submission are visible to it (vkQueueSubmit's guarantee).
        let region = vk::BufferCopy::default().size(self.upload.size);
        self.commands.run_once(vk, |cb| unsafe {
            vk.device.cmd_copy_buffer(cb, *self.upload.buffer, *self.gbuffers.buffer, &[region])
        })
    }

    /// Vulkan -> CPU -> GL: the AO copied into mapped memory, waited for, then uploaded to GL.
    pub fn ao_to_gl(&mut self, vk: &VulkanContext, gl: &GlContext) -> Result<()> {
        let region = vk::BufferCopy::default().size(self.readback.size);
        self.commands.run_once(vk, |cb| unsafe {
            vk.device.cmd_copy_buffer(cb, *self.ao.buffer, *self.readback.buffer, &[region]);
            // TRANSFER writes -> HOST reads: the CPU reads them after the fence.
            transfers_to_host(vk, cb);
        })?;
        let (width, height) = (self.extent.width as i32, self.extent.height as i32);
        unsafe {
            gl.gl.pixel_store_i32(glow::UNPACK_ALIGNMENT, 4);
            gl.gl.texture_sub_image_2d(
                *self.texture,
                0,
                0,
                0,
                width,
                height,
                glow::RED,
                glow::FLOAT,
                glow::PixelUnpackData::Slice(Some(self.readback.bytes())),
            );
        }
        gl.check_error("uploading the AO to GL").context("cpu-round-trip")
    }
    // ANCHOR_END: copies
}
