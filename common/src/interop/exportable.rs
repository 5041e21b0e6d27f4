//! Vulkan memory that another API can import (taught in chapter 01).
//!
//! gpu-allocator cannot do this (it has no way to chain `VkExportMemoryAllocateInfo`), so every
//! shared resource gets its own plain `vkAllocateMemory`, bound at offset 0.

use crate::base::image::image_info;
use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::{Context as _, Result};
use ash::vk;
use std::os::fd::{FromRawFd, OwnedFd};

// ANCHOR: handle_type
/// The one handle type this tutorial shares memory through: a POSIX file descriptor whose
/// contents only the same driver understands.
pub const HANDLE_TYPE: vk::ExternalMemoryHandleTypeFlags = vk::ExternalMemoryHandleTypeFlags::OPAQUE_FD;
// ANCHOR_END: handle_type

// ANCHOR: slack
/// Extra bytes given to every exported buffer allocation. llvmpipe over-allocates GL buffers and
/// refuses `glNamedBufferStorageMemEXT` with GL_OUT_OF_MEMORY unless the memory object is at least
/// 48 bytes larger than the buffer. Elsewhere the slack is harmless.
pub const BUFFER_IMPORT_SLACK: u64 = 256;
// ANCHOR_END: slack

// ANCHOR: dedicated
/// What the memory is for. Dedicated memory belongs to one image or buffer; Vulkan requires its
/// size to be exactly that resource's `VkMemoryRequirements::size`, so it gets no slack.
#[derive(Clone, Copy, Debug)]
pub enum Dedicated {
    No,
    Buffer(vk::Buffer),
    Image(vk::Image),
}
// ANCHOR_END: dedicated

/// One exportable allocation, freed when dropped (with its count in `instruments::resources`).
#[derive(Debug)]
pub struct ExportableMemory {
    pub memory: Owned<vk::DeviceMemory>,
    /// `allocationSize`: what the importer must be told the memory object's size is.
    pub size: u64,
    pub memory_type_index: u32,
    pub property_flags: vk::MemoryPropertyFlags,
    /// The memory types the resource allowed (`memoryTypeBits`): bit i set, type i allowed.
    pub allowed_types: u32,
    /// Whether it was allocated for one buffer or image alone (`VkMemoryDedicatedAllocateInfo`):
    /// an importer must say the same.
    pub dedicated: bool,
}

/// What an importer must be told of exported memory, and all it needs: its size and whether it
/// is one buffer's or image's alone. A process that receives the fd builds it from the message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryTerms {
    pub size: u64,
    pub dedicated: bool,
}

impl ExportableMemory {
    /// What GL's import must say of this memory.
    pub fn terms(&self) -> MemoryTerms {
        MemoryTerms { size: self.size, dedicated: self.dedicated }
    }
}

// ANCHOR: allocate_whole
// ANCHOR: allocate
/// Allocates memory for `requirements` that can be exported as an opaque fd.
pub fn allocate(
    ctx: &VulkanContext,
    requirements: &vk::MemoryRequirements,
    properties: vk::MemoryPropertyFlags,
    dedicated: Dedicated,
) -> Result<ExportableMemory> {
    let memory_type_index = ctx.find_memory_type(requirements.memory_type_bits, properties)?;
    let size = match dedicated {
        Dedicated::No => requirements.size + BUFFER_IMPORT_SLACK,
        Dedicated::Buffer(_) | Dedicated::Image(_) => requirements.size,
    };
    // This is the whole difference from an ordinary allocation: a promise, made now, that the
    // memory will be exported with this handle type. Drivers may place it differently for that.
    let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE_TYPE);
    let mut dedicated_info = match dedicated {
        Dedicated::No => None,
        Dedicated::Buffer(buffer) => Some(vk::MemoryDedicatedAllocateInfo::default().buffer(buffer)),
        Dedicated::Image(image) => Some(vk::MemoryDedicatedAllocateInfo::default().image(image)),
    };
    let mut info = vk::MemoryAllocateInfo::default()
        .allocation_size(size)
        .memory_type_index(memory_type_index)
        .push_next(&mut export);
    if let Some(dedicated_info) = dedicated_info.as_mut() {
        info = info.push_next(dedicated_info);
    }
    // ANCHOR_END: allocate
    // ANCHOR: device_address
    // With ray tracing on, buffers may need GPU addresses (acceleration-structure inputs).
    let mut flags = vk::MemoryAllocateFlagsInfo::default().flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
    if ctx.device_addresses && !matches!(dedicated, Dedicated::Image(_)) {
        info = info.push_next(&mut flags);
    }
    // ANCHOR_END: device_address
    // ANCHOR: allocate_memory
    let what = format!("vkAllocateMemory: {size} bytes of exportable memory ({properties:?})");
    let memory = create(&ctx.device, &what, || unsafe { ctx.device.allocate_memory(&info, None) })?
        .counted("vk_memory_exportable", size);
    let property_flags = ctx.memory_properties.memory_types[memory_type_index as usize].property_flags;
    let allowed_types = requirements.memory_type_bits;
    let dedicated = !matches!(dedicated, Dedicated::No);
    Ok(ExportableMemory { memory, size, memory_type_index, property_flags, allowed_types, dedicated })
}
// ANCHOR_END: allocate_memory
// ANCHOR_END: allocate_whole

// ANCHOR: create_image
/// A 2D image, one mip level, whose memory may be exported. Every image this tutorial shares
/// with GL is made here.
pub fn create_image(
    ctx: &VulkanContext,
    format: vk::Format,
    usage: vk::ImageUsageFlags,
    extent: vk::Extent2D,
) -> Result<Owned<vk::Image>> {
    // Ask first (VUID-VkImageCreateInfo-pNext-00990): can the driver export an image like this one,
    // this large? Chapter 01 asks the same, step by step.
    let mut external_query = vk::PhysicalDeviceExternalImageFormatInfo::default().handle_type(HANDLE_TYPE);
    let query = vk::PhysicalDeviceImageFormatInfo2::default()
        .format(format)
        .ty(vk::ImageType::TYPE_2D)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(usage)
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT)
        .push_next(&mut external_query);
    let mut external = vk::ExternalImageFormatProperties::default();
    let mut properties = vk::ImageFormatProperties2::default().push_next(&mut external);
    let device = &ctx.info.name;
    fail::call("vkGetPhysicalDeviceImageFormatProperties2", || unsafe {
        ctx.instance.get_physical_device_image_format_properties2(
            ctx.physical_device,
            &query,
            &mut properties,
        )
    })
    .with_context(|| format!("{device} cannot make a {format:?} image with usage {usage:?} to share"))?;
    let max = properties.image_format_properties.max_extent;
    let features = external.external_memory_properties.external_memory_features;
    anyhow::ensure!(
        features.contains(vk::ExternalMemoryFeatureFlags::EXPORTABLE),
        "{device} cannot export a {format:?} image with usage {usage:?} as an fd"
    );
    anyhow::ensure!(
        extent.width <= max.width && extent.height <= max.height,
        "{}x{}: {device} exports {format:?} images of at most {}x{}",
        extent.width,
        extent.height,
        max.width,
        max.height
    );
    let mut external = vk::ExternalMemoryImageCreateInfo::default().handle_types(HANDLE_TYPE);
    let info = image_info(format, usage, extent)
        // Some drivers corrupt shared images unless views of other formats are allowed.
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT)
        .push_next(&mut external);
    let what = format!("vkCreateImage (exportable, {format:?})");
    create(&ctx.device, &what, || unsafe { ctx.device.create_image(&info, None) })
        .map(|image| image.counted("vk_image_exportable", 0))
}
// ANCHOR_END: create_image

// ANCHOR: export_fd
/// Exports `memory` as a new file descriptor. Each call makes a new fd, owned by the caller until
/// an import (GL's or Vulkan's) succeeds and takes it over.
pub fn export_fd(loader: &ash::khr::external_memory_fd::Device, memory: vk::DeviceMemory) -> Result<OwnedFd> {
    let info = vk::MemoryGetFdInfoKHR::default().memory(memory).handle_type(HANDLE_TYPE);
    let fd = fail::call("vkGetMemoryFdKHR", || unsafe { loader.get_memory_fd(&info) })?;
    // SAFETY: vkGetMemoryFdKHR returned a fresh fd that nothing else owns.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}
// ANCHOR_END: export_fd

/// A buffer in exportable, host-visible memory, mapped for its lifetime (taught in chapters 01
/// and 02): Vulkan's side of every buffer GL imports. Destroyed when dropped (the buffer, then its
/// memory, which unmaps it); the GPU, and GL, must be done with it.
pub struct ExportedBuffer {
    pub buffer: Owned<vk::Buffer>,
    pub memory: ExportableMemory,
    /// Vulkan's view of the bytes, coherent with the GPU's.
    pub mapped: *mut u8,
    pub bytes: u64,
}

impl ExportedBuffer {
    // ANCHOR: exported_buffer
    /// A buffer of `data.len()` bytes holding `data`.
    pub fn new(ctx: &VulkanContext, data: &[u8], usage: vk::BufferUsageFlags) -> Result<Self> {
        let bytes = data.len() as u64;
        let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE_TYPE);
        let info = vk::BufferCreateInfo::default().size(bytes).usage(usage).push_next(&mut external);
        // Can the driver export such a buffer, and must it have memory of its own (chapter 01)?
        let query = vk::PhysicalDeviceExternalBufferInfo::default().usage(usage).handle_type(HANDLE_TYPE);
        let mut support = vk::ExternalBufferProperties::default();
        unsafe {
            ctx.instance.get_physical_device_external_buffer_properties(
                ctx.physical_device,
                &query,
                &mut support,
            )
        };
        let features = support.external_memory_properties.external_memory_features;
        anyhow::ensure!(
            features.contains(vk::ExternalMemoryFeatureFlags::EXPORTABLE),
            "{} cannot export a buffer with usage {usage:?} as an fd",
            ctx.info.name
        );
        // Each object is owned as it is made: a failed allocation, bind or map below destroys
        // what was made before it.
        let buffer = create(&ctx.device, "vkCreateBuffer (exportable)", || unsafe {
            ctx.device.create_buffer(&info, None)
        })?
        .counted("vk_buffer_exportable", 0);
        let requirements = unsafe { ctx.device.get_buffer_memory_requirements(*buffer) };
        let host = buffer_memory_properties(ctx, requirements.memory_type_bits);
        let dedicated = if features.contains(vk::ExternalMemoryFeatureFlags::DEDICATED_ONLY) {
            Dedicated::Buffer(*buffer)
        } else {
            Dedicated::No
        };
        let memory = allocate(ctx, &requirements, host, dedicated)?;
        fail::call("vkBindBufferMemory (exportable)", || unsafe {
            ctx.device.bind_buffer_memory(*buffer, *memory.memory, 0)
        })?;
        let mapped = fail::call("vkMapMemory (exportable)", || unsafe {
            ctx.device.map_memory(*memory.memory, 0, bytes, vk::MemoryMapFlags::empty())
        })?
        .cast::<u8>();
        // SAFETY: `mapped` is `bytes` long, coherent, and nothing else uses it yet.
        unsafe { std::ptr::copy_nonoverlapping(data.as_ptr(), mapped, data.len()) };
        Ok(ExportedBuffer { buffer, memory, mapped, bytes })
    }
    // ANCHOR_END: exported_buffer

    /// The buffer's GPU address (needs SHADER_DEVICE_ADDRESS usage and a context with
    /// `Requirements::ray_tracing`).
    pub fn device_address(&self, ctx: &VulkanContext) -> vk::DeviceAddress {
        let info = vk::BufferDeviceAddressInfo::default().buffer(*self.buffer);
        unsafe { ctx.device.get_buffer_device_address(&info) }
    }
}

/// Where exported buffers live (`bench --scene-memory`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SceneMemory {
    /// Every chapter: the first host-visible, coherent type. The simplest to explain, but on a
    /// discrete GPU it is usually system memory, which GL then reads over PCIe every frame.
    Host,
    /// Device-local as well as host-visible, where the GPU offers such a type (resizable-BAR
    /// GPUs do); else as `Host`.
    Device,
}

/// The [`SceneMemory`] choice in force: `Host` until [`set_scene_memory`] says otherwise.
static PREFER_DEVICE_LOCAL: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Chooses where exported buffers made after the call live.
pub fn set_scene_memory(memory: SceneMemory) {
    PREFER_DEVICE_LOCAL.store(memory == SceneMemory::Device, std::sync::atomic::Ordering::Relaxed);
}

// ANCHOR: scene_memory
/// Host-visible and coherent (the CPU writes the data in place), and device-local too when
/// preferred and some allowed type has all three.
fn buffer_memory_properties(ctx: &VulkanContext, type_bits: u32) -> vk::MemoryPropertyFlags {
    let host = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
    let both = host | vk::MemoryPropertyFlags::DEVICE_LOCAL;
    let prefer = PREFER_DEVICE_LOCAL.load(std::sync::atomic::Ordering::Relaxed);
    if prefer && ctx.find_memory_type(type_bits, both).is_ok() { both } else { host }
}
// ANCHOR_END: scene_memory
