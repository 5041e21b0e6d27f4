//! Vulkan memory seen by GL: importing an exported fd as a GL memory object, and a buffer (taught
//! in chapter 02) or a 2D texture (chapter 03) stored in it.

use crate::base::commands::image_barrier;
use crate::base::gl::{
    self, DEDICATED_MEMORY_OBJECT_EXT, GlContext, HANDLE_TYPE_OPAQUE_FD_EXT, OPTIMAL_TILING_EXT,
    TEXTURE_TILING_EXT,
};
use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use crate::interop::exportable::{self, Dedicated, ExportableMemory, MemoryTerms};
use crate::interop::handoff::Handoff;
use anyhow::Result;
use ash::vk;
use glow::HasContext;
use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};

/// A GL buffer whose storage is Vulkan memory. Fields drop in the order written: the buffer,
/// then the memory object it is stored in (which releases GL's hold on the memory).
pub struct SharedBuffer {
    pub buffer: gl::Owned<glow::Buffer>,
    pub memory_object: gl::Owned<gl::MemoryObject>,
}

/// A GL texture whose storage is a Vulkan image's dedicated memory. Fields drop in the order
/// written: the layout the host path recorded for it, the texture, then its memory object.
pub struct SharedTexture {
    /// First: a later texture may get this one's name, and must not inherit its layout.
    pub layout: crate::interop::handoff::LeftByVulkan,
    pub texture: gl::Owned<glow::Texture>,
    pub memory_object: gl::Owned<gl::MemoryObject>,
}

// ANCHOR: import_memory
/// Imports `fd`, exported from memory of these `terms`, as a GL memory object of the same size
/// (the Vulkan `allocationSize`). On success GL owns the fd; on failure it is closed here, and
/// the memory object deleted. (Taught in chapter 02, whose `main.rs` makes these calls itself.)
pub fn import_memory(
    gl: &GlContext,
    memory: MemoryTerms,
    fd: OwnedFd,
) -> Result<gl::Owned<gl::MemoryObject>> {
    let ext = gl.memory_fns()?;
    // Owned from here on: every early return deletes the memory object.
    let memory_object = gl::create(ext, "glCreateMemoryObjectsEXT", |ext| {
        let mut name = 0;
        unsafe { (ext.CreateMemoryObjectsEXT)(1, &mut name) };
        gl::made(name, "glCreateMemoryObjectsEXT").map(gl::MemoryObject)
    })?
    .counted("gl_memory_object", 0); // its bytes are Vulkan's allocation
    if memory.dedicated {
        // Must match how Vulkan allocated it, and must be said before the import.
        let yes = glow::TRUE as i32;
        unsafe { (ext.MemoryObjectParameterivEXT)(memory_object.0, DEDICATED_MEMORY_OBJECT_EXT, &yes) };
    }
    // A step that can fail as a driver that refuses the import would.
    fail::step("glImportMemoryFdEXT")?;
    // An error left by an earlier call would be read below as the import's own, and the fd then
    // closed although GL took it: report it now, while the fd is still only ours.
    gl.check_error("a GL call before glImportMemoryFdEXT")?;
    unsafe {
        (ext.ImportMemoryFdEXT)(memory_object.0, memory.size, HANDLE_TYPE_OPAQUE_FD_EXT, fd.as_raw_fd())
    };
    // Some drivers list the extension yet fail the import: always look. On failure `fd` is
    // dropped, and so closed: the failed import did not take it.
    gl.check_error("glImportMemoryFdEXT")?;
    // SAFETY: the import succeeded, so the fd is GL's now; closing it too would be a double close.
    let _ = fd.into_raw_fd();
    Ok(memory_object)
}
// ANCHOR_END: import_memory

// ANCHOR: import_buffer
/// A GL buffer of `bytes` bytes stored at offset 0 of the exported `memory` (taught in chapter
/// 02, whose `main.rs` makes these calls itself).
pub fn import_buffer(
    gl: &GlContext,
    memory: &ExportableMemory,
    fd: OwnedFd,
    bytes: u64,
) -> Result<SharedBuffer> {
    let memory_object = import_memory(gl, memory.terms(), fd)?;
    // A failure from here on drops what was made, newest first.
    let buffer = gl::create(&gl.gl, "glCreateBuffers (imported)", |gl| unsafe { gl.create_named_buffer() })?
        .counted("gl_buffer_imported", 0);
    // Like glNamedBufferStorage, but the storage already exists: it is the memory object.
    let ext = gl.memory_fns()?;
    fail::step("glNamedBufferStorageMemEXT")?;
    unsafe { (ext.NamedBufferStorageMemEXT)(buffer.0.get(), bytes as isize, memory_object.0, 0) };
    gl.check_error("glNamedBufferStorageMemEXT")?;
    Ok(SharedBuffer { buffer, memory_object })
}
// ANCHOR_END: import_buffer

/// One buffer seen by both APIs: GL's import and Vulkan's exported buffer. Fields drop in the
/// order written: GL lets go of the memory (buffer, then memory object) before Vulkan frees it.
pub struct BufferPair {
    /// GL's side, for drawing.
    pub gl: SharedBuffer,
    /// Vulkan's side: the mapped bytes, and what the acceleration structures read.
    pub vk: exportable::ExportedBuffer,
}

/// Vulkan makes a buffer holding `data` and exports it; GL imports it. Vulkan and GL now see the
/// same bytes: `pair.vk.mapped` from the CPU, `pair.gl.buffer` from GL.
pub fn share_buffer(
    vk: &VulkanContext,
    gl: &GlContext,
    data: &[u8],
    usage: vk::BufferUsageFlags,
) -> Result<BufferPair> {
    let exported = exportable::ExportedBuffer::new(vk, data, usage)?;
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    let fd = exportable::export_fd(&fd_loader, *exported.memory.memory)?;
    // On failure `exported` is dropped, which destroys it.
    let shared = import_buffer(gl, &exported.memory, fd, exported.bytes)?;
    Ok(BufferPair { gl: shared, vk: exported })
}

// ANCHOR: import_texture_2d
/// A GL 2D texture (one mip level) stored in an image's dedicated, exported `memory` (taught in
/// chapter 03, whose `main.rs` makes these calls itself).
/// `internal_format` must be the GL twin of the Vulkan format (GL_RGBA8 for R8G8B8A8_UNORM).
pub fn import_texture_2d(
    gl: &GlContext,
    memory: MemoryTerms,
    fd: OwnedFd,
    internal_format: u32,
    (width, height): (u32, u32),
) -> Result<SharedTexture> {
    let memory_object = import_memory(gl, memory, fd)?;
    // The import succeeded: a failure from here on must still delete the memory object, and
    // does, by dropping it.
    let texture = gl::create(&gl.gl, "glCreateTextures (imported)", |gl| unsafe {
        gl.create_named_texture(glow::TEXTURE_2D)
    })?
    .counted("gl_texture_imported", 0);
    let ext = gl.memory_fns()?;
    fail::step("glTextureStorageMem2DEXT")?;
    unsafe {
        // The Vulkan image was created with VK_IMAGE_TILING_OPTIMAL: the driver's private layout.
        gl.gl.texture_parameter_i32(*texture, TEXTURE_TILING_EXT, OPTIMAL_TILING_EXT as i32);
        (ext.TextureStorageMem2DEXT)(
            texture.0.get(),
            1,
            internal_format,
            width as i32,
            height as i32,
            memory_object.0,
            0,
        );
    }
    gl.check_error("glTextureStorageMem2DEXT")?; // on failure both are dropped, newest first
    Ok(SharedTexture::new(texture, memory_object))
}
// ANCHOR_END: import_texture_2d

impl SharedTexture {
    /// A texture stored in `memory_object`, in no layout Vulkan has recorded yet.
    pub fn new(texture: gl::Owned<glow::Texture>, memory_object: gl::Owned<gl::MemoryObject>) -> Self {
        let layout = crate::interop::handoff::LeftByVulkan::new(*texture);
        SharedTexture { layout, texture, memory_object }
    }
}

/// A Vulkan image with its own exported memory and a view, and the GL texture that is the same
/// memory (taught in chapter 03, whose `main.rs` makes the parts; one call from chapter 04 on).
/// Resizing means dropping it and making a new one. Dropped, its fields go in the order written:
/// GL's side first (texture, memory object), then Vulkan's (view, image, memory); the GPU must be
/// done with it.
pub struct SharedImage {
    /// First: GL lets go of the memory before Vulkan frees it.
    pub texture: SharedTexture,
    pub view: Owned<vk::ImageView>,
    pub image: Owned<vk::Image>,
    pub memory: ExportableMemory,
    pub extent: vk::Extent2D,
}

/// A Vulkan format and GL's name for the same texels, which a shared image is made with: the
/// two must agree, so they travel together.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SharedFormat {
    pub vk: vk::Format,
    /// The GL internal format (`GL_RGBA8` for `R8G8B8A8_UNORM`).
    pub gl: u32,
    pub bytes_per_pixel: u32,
}

impl SharedFormat {
    pub const RGBA8: SharedFormat =
        SharedFormat { vk: vk::Format::R8G8B8A8_UNORM, gl: glow::RGBA8, bytes_per_pixel: 4 };
    pub const RGBA32F: SharedFormat =
        SharedFormat { vk: vk::Format::R32G32B32A32_SFLOAT, gl: glow::RGBA32F, bytes_per_pixel: 16 };
    pub const R32F: SharedFormat =
        SharedFormat { vk: vk::Format::R32_SFLOAT, gl: glow::R32F, bytes_per_pixel: 4 };
    pub const R32UI: SharedFormat =
        SharedFormat { vk: vk::Format::R32_UINT, gl: glow::R32UI, bytes_per_pixel: 4 };
}

impl SharedImage {
    // ANCHOR: shared_image_new
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        format: SharedFormat,
        usage: vk::ImageUsageFlags,
        extent: vk::Extent2D,
    ) -> Result<Self> {
        // Each object is owned as it is made: a failure half-way destroys what exists, newest first.
        let image = exportable::create_image(vk, format.vk, usage, extent)?;
        let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
        let memory = exportable::allocate(
            vk,
            &requirements,
            vk::MemoryPropertyFlags::DEVICE_LOCAL,
            Dedicated::Image(*image),
        )?;
        fail::call("vkBindImageMemory (exportable)", || unsafe {
            vk.device.bind_image_memory(*image, *memory.memory, 0)
        })?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(*image)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(format.vk)
            .subresource_range(crate::base::commands::COLOR_RANGE);
        let view = create(&vk.device, "vkCreateImageView (exportable image)", || unsafe {
            vk.device.create_image_view(&view_info, None)
        })?;
        let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
        let fd = exportable::export_fd(&fd_loader, *memory.memory)?;
        let texture = import_texture_2d(gl, memory.terms(), fd, format.gl, (extent.width, extent.height))?;
        Ok(SharedImage { texture, view, image, memory, extent })
    }
    // ANCHOR_END: shared_image_new
}

// ANCHOR: hand_new_images_to_gl
/// Hands images nobody has used yet to GL, in `GENERAL`, before GL's first use: Vulkan moves
/// them out of `UNDEFINED` (which may initialise what the driver keeps beside the pixels) and
/// releases them to `VK_QUEUE_FAMILY_EXTERNAL`. For images GL uses first (chapter 03's, the
/// G-buffers): from here on each is in a layout both sides know, the one the host path hands it
/// over in (`Handoff::hand_over`). `images`: each image and its GL texture. Set-up work: the CPU
/// waits for Vulkan's part.
pub fn hand_new_images_to_gl(
    vk: &VulkanContext,
    gl: &GlContext,
    handoff: &Handoff,
    images: &[(vk::Image, glow::Texture)],
) -> Result<()> {
    let general = vk::ImageLayout::GENERAL;
    let families = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
    let none = vk::AccessFlags::NONE; // nothing written yet, nothing to make available
    let barriers: Vec<_> = images
        .iter()
        .map(|&(image, _)| {
            image_barrier(image, (vk::ImageLayout::UNDEFINED, general), (none, none), families)
        })
        .collect();
    let textures: Vec<glow::Texture> = images.iter().map(|&(_, texture)| texture).collect();
    let commands = crate::base::commands::Commands::new(vk)?;
    let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
    match handoff {
        Handoff::Host { .. } => {
            commands.run_once(vk, |cb| unsafe {
                let top = vk::PipelineStageFlags::TOP_OF_PIPE;
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
            // No layout travels with a fence: record where Vulkan left each, for the next acquire.
            for texture in &textures {
                crate::interop::handoff::vulkan_left(texture.0.get(), gl::layout::of(general));
            }
            Ok(())
        }
        Handoff::Semaphores { gl_done, vulkan_done } => {
            // A round trip, as a frame makes one, so that each binary semaphore is waited on
            // before it is signalled again (a resize makes new images between two frames). GL
            // signals first: it has not used these images, so its signal names none.
            handoff.gl_release(gl, &[], &[]);
            let cb = commands.begin(vk)?;
            // From ALL_COMMANDS, the stage the submission waits for GL at: the layout transition
            // comes after GL's signal. To BOTTOM_OF_PIPE: a release, nothing later here uses them.
            let all = vk::PipelineStageFlags::ALL_COMMANDS;
            let no_flags = vk::DependencyFlags::empty();
            unsafe { vk.device.cmd_pipeline_barrier(cb, all, bottom, no_flags, &[], &[], &barriers) };
            commands.submit(vk, Some((*gl_done.vk, all)), Some(*vulkan_done.vk))?;
            commands.wait(vk, "vkWaitForFences for one-shot work")?;
            // GL's half of the ownership transfer: the wait names each texture's layout, GENERAL,
            // before GL's first use. EXT_external_objects: "the current layout of the textures
            // must be specified to initialize internal GL state prior to using the textures after
            // an external access".
            let layouts = vec![gl::layout::GENERAL; textures.len()];
            handoff.gl_acquire(vk, gl, *commands.fence, &textures, &layouts)
        }
    }
}
// ANCHOR_END: hand_new_images_to_gl

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
    image_barrier(*image.image, (from_gl, layout), (vk::AccessFlags::NONE, access), families)
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
    image_barrier(*image.image, (layout, for_gl), (access, vk::AccessFlags::NONE), families)
}
// ANCHOR_END: ownership
