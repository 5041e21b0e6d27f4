//! Vulkan memory seen by GL: importing an exported fd as a GL memory object, and a buffer (taught
//! in chapter 02) or a 2D texture (chapter 03) stored in it.

use crate::commands::image_barrier;
use crate::exportable::{self, Dedicated, ExportableMemory};
use crate::gl::{
    DEDICATED_MEMORY_OBJECT_EXT, HANDLE_TYPE_OPAQUE_FD_EXT, OPTIMAL_TILING_EXT, TEXTURE_TILING_EXT,
};
use crate::{GlContext, VulkanContext};
use anyhow::{Context as _, Result};
use ash::vk;
use glow::HasContext;
use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};

/// A GL buffer whose storage is Vulkan memory.
pub struct SharedBuffer {
    pub buffer: glow::Buffer,
    pub memory_object: u32,
}

/// A GL texture whose storage is a Vulkan image's dedicated memory.
pub struct SharedTexture {
    pub texture: glow::Texture,
    pub memory_object: u32,
}

// ANCHOR: import_memory
/// Imports an exported fd as a GL memory object of `size` bytes (the Vulkan `allocationSize`).
/// On success GL owns the fd; on failure it is closed here.
pub fn import_memory(gl: &GlContext, fd: OwnedFd, size: u64, dedicated: bool) -> Result<u32> {
    let ext = gl.memory_fns()?;
    let mut memory_object = 0;
    unsafe { (ext.CreateMemoryObjectsEXT)(1, &mut memory_object) };
    crate::resources::created("gl_memory_object", 0); // its bytes are Vulkan's allocation
    if dedicated {
        // Must match how Vulkan allocated it, and must be said before the import.
        let yes = glow::TRUE as i32;
        unsafe { (ext.MemoryObjectParameterivEXT)(memory_object, DEDICATED_MEMORY_OBJECT_EXT, &yes) };
    }
    unsafe { (ext.ImportMemoryFdEXT)(memory_object, size, HANDLE_TYPE_OPAQUE_FD_EXT, fd.as_raw_fd()) };
    // Some drivers list the extension yet fail the import: always look.
    if let Err(error) = gl.check_error("glImportMemoryFdEXT") {
        unsafe { (ext.DeleteMemoryObjectsEXT)(1, &memory_object) };
        crate::resources::destroyed("gl_memory_object");
        return Err(error); // `fd` is dropped, and so closed: the failed import did not take it.
    }
    // SAFETY: the import succeeded, so the fd is GL's now; closing it too would be a double close.
    let _ = fd.into_raw_fd();
    Ok(memory_object)
}
// ANCHOR_END: import_memory

// ANCHOR: import_buffer
/// A GL buffer of `bytes` bytes stored at offset 0 of the exported `memory`.
pub fn import_buffer(
    gl: &GlContext,
    memory: &ExportableMemory,
    fd: OwnedFd,
    bytes: u64,
) -> Result<SharedBuffer> {
    let memory_object = import_memory(gl, fd, memory.size, false)?;
    let buffer =
        unsafe { gl.gl.create_named_buffer() }.map_err(anyhow::Error::msg).context("glCreateBuffers")?;
    crate::resources::created("gl_buffer_imported", 0);
    // Like glNamedBufferStorage, but the storage already exists: it is the memory object.
    let ext = gl.memory_fns()?;
    unsafe { (ext.NamedBufferStorageMemEXT)(buffer.0.get(), bytes as isize, memory_object, 0) };
    let shared = SharedBuffer { buffer, memory_object };
    if let Err(error) = gl.check_error("glNamedBufferStorageMemEXT") {
        shared.delete(gl);
        return Err(error);
    }
    Ok(shared)
}
// ANCHOR_END: import_buffer

/// Vulkan makes a buffer holding `data` and exports it; GL imports it. Vulkan and GL now see the
/// same bytes: `exported.mapped` from the CPU, `shared.buffer` from GL.
pub fn share_buffer(
    vk: &VulkanContext,
    gl: &GlContext,
    data: &[u8],
    usage: vk::BufferUsageFlags,
) -> Result<(exportable::ExportedBuffer, SharedBuffer)> {
    let exported = exportable::ExportedBuffer::new(vk, data, usage)?;
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    let shared = exportable::export_fd(&fd_loader, exported.memory.memory)
        .and_then(|fd| import_buffer(gl, &exported.memory, fd, exported.bytes));
    match shared {
        Ok(shared) => Ok((exported, shared)),
        Err(error) => {
            exported.destroy(vk);
            Err(error)
        }
    }
}

// ANCHOR: import_texture_2d
/// A GL 2D texture (one mip level) stored in an image's dedicated, exported `memory`.
/// `internal_format` must be the GL twin of the Vulkan format (GL_RGBA8 for R8G8B8A8_UNORM).
pub fn import_texture_2d(
    gl: &GlContext,
    memory: &ExportableMemory,
    fd: OwnedFd,
    internal_format: u32,
    width: u32,
    height: u32,
) -> Result<SharedTexture> {
    let memory_object = import_memory(gl, fd, memory.size, true)?;
    let texture = unsafe { gl.gl.create_named_texture(glow::TEXTURE_2D) }
        .map_err(anyhow::Error::msg)
        .context("glCreateTextures")?;
    crate::resources::created("gl_texture_imported", 0);
    let ext = gl.memory_fns()?;
    unsafe {
        // The Vulkan image was created with VK_IMAGE_TILING_OPTIMAL: the driver's private layout.
        gl.gl.texture_parameter_i32(texture, TEXTURE_TILING_EXT, OPTIMAL_TILING_EXT as i32);
        (ext.TextureStorageMem2DEXT)(
            texture.0.get(),
            1,
            internal_format,
            width as i32,
            height as i32,
            memory_object,
            0,
        );
    }
    let shared = SharedTexture { texture, memory_object };
    if let Err(error) = gl.check_error("glTextureStorageMem2DEXT") {
        shared.delete(gl);
        return Err(error);
    }
    Ok(shared)
}
// ANCHOR_END: import_texture_2d

impl SharedBuffer {
    /// Deletes the buffer, then the memory object (which releases GL's hold on the memory).
    pub fn delete(self, gl: &GlContext) {
        unsafe {
            gl.gl.delete_buffer(self.buffer);
            crate::resources::destroyed("gl_buffer_imported");
            if let Some(ext) = &gl.memory {
                (ext.DeleteMemoryObjectsEXT)(1, &self.memory_object);
                crate::resources::destroyed("gl_memory_object");
            }
        }
    }
}

impl SharedTexture {
    /// Deletes the texture, then the memory object.
    pub fn delete(self, gl: &GlContext) {
        unsafe {
            gl.gl.delete_texture(self.texture);
            crate::resources::destroyed("gl_texture_imported");
            if let Some(ext) = &gl.memory {
                (ext.DeleteMemoryObjectsEXT)(1, &self.memory_object);
                crate::resources::destroyed("gl_memory_object");
            }
        }
    }
}

/// A Vulkan image with its own exported memory and a view, and the GL texture that is the same
/// memory (taught in chapter 03). Resizing means destroying it and making a new one.
pub struct SharedImage {
    pub image: vk::Image,
    pub memory: ExportableMemory,
    pub view: vk::ImageView,
    pub texture: SharedTexture,
    pub extent: vk::Extent2D,
}

impl SharedImage {
    /// `gl_format` is GL's name for the same `format` (GL_RGBA8 for R8G8B8A8_UNORM).
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        format: vk::Format,
        gl_format: u32,
        usage: vk::ImageUsageFlags,
        extent: vk::Extent2D,
    ) -> Result<Self> {
        let image = exportable::create_image(vk, format, usage, extent)?;
        let requirements = unsafe { vk.device.get_image_memory_requirements(image) };
        let memory = match exportable::allocate(
            vk,
            &requirements,
            vk::MemoryPropertyFlags::DEVICE_LOCAL,
            Dedicated::Image(image),
        ) {
            Ok(memory) => memory,
            Err(error) => {
                unsafe { vk.device.destroy_image(image, None) };
                crate::resources::destroyed("vk_image_exportable");
                return Err(error);
            }
        };
        let destroy_vulkan = |view: Option<vk::ImageView>| unsafe {
            if let Some(view) = view {
                vk.device.destroy_image_view(view, None);
            }
            vk.device.free_memory(memory.memory, None);
            vk.device.destroy_image(image, None);
            crate::resources::destroyed("vk_memory_exportable");
            crate::resources::destroyed("vk_image_exportable");
        };
        if let Err(error) = unsafe { vk.device.bind_image_memory(image, memory.memory, 0) } {
            destroy_vulkan(None);
            return Err(error).context("vkBindImageMemory");
        }
        let view_info = vk::ImageViewCreateInfo::default()
            .image(image)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(format)
            .subresource_range(crate::commands::COLOR_RANGE);
        let view = match unsafe { vk.device.create_image_view(&view_info, None) } {
            Ok(view) => view,
            Err(error) => {
                destroy_vulkan(None);
                return Err(error).context("vkCreateImageView");
            }
        };
        let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
        let texture = exportable::export_fd(&fd_loader, memory.memory)
            .and_then(|fd| import_texture_2d(gl, &memory, fd, gl_format, extent.width, extent.height));
        match texture {
            Ok(texture) => Ok(SharedImage { image, memory, view, texture, extent }),
            Err(error) => {
                destroy_vulkan(Some(view));
                Err(error)
            }
        }
    }

    /// GL's side first (texture, memory object), then Vulkan's (view, memory, image). Vulkan must
    /// be idle with respect to the image.
    pub fn destroy(self, vk: &VulkanContext, gl: &GlContext) {
        self.texture.delete(gl);
        unsafe {
            vk.device.destroy_image_view(self.view, None);
            vk.device.free_memory(self.memory.memory, None);
            vk.device.destroy_image(self.image, None);
            crate::resources::destroyed("vk_memory_exportable");
            crate::resources::destroyed("vk_image_exportable");
        }
    }
}

// ANCHOR: ownership
/// The barrier that takes `image` over from GL: ownership moves from outside Vulkan
/// (`VK_QUEUE_FAMILY_EXTERNAL`) to our queue family, from the layout GL's release promised. The
/// semaphore (or the host wait) already made GL's writes available: no source access.
pub fn acquire_from_gl<'a>(
    vk: &VulkanContext,
    image: &SharedImage,
    from_gl: vk::ImageLayout,
    layout: vk::ImageLayout,
    access: vk::AccessFlags,
) -> vk::ImageMemoryBarrier<'a> {
    let families = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
    image_barrier(image.image, (from_gl, layout), (vk::AccessFlags::NONE, access), families)
}

/// The barrier that hands `image` back to GL in `for_gl`, the layout GL's acquire will name,
/// making the writes in `access` available first.
pub fn release_to_gl<'a>(
    vk: &VulkanContext,
    image: &SharedImage,
    layout: vk::ImageLayout,
    for_gl: vk::ImageLayout,
    access: vk::AccessFlags,
) -> vk::ImageMemoryBarrier<'a> {
    let families = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
    image_barrier(image.image, (layout, for_gl), (access, vk::AccessFlags::NONE), families)
}
// ANCHOR_END: ownership
