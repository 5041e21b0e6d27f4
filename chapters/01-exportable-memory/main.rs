//! Chapter 01: exportable memory.
//!
//! Before OpenGL can use Vulkan memory, Vulkan must hand that memory out. This chapter asks the
//! driver what it can share, creates a buffer and an image whose memory can leave the process's
//! Vulkan world as a file descriptor, exports both, proves a descriptor really is the memory by
//! importing it back, and closes what it owns. GL imports these descriptors in chapter 02.
//!
//! Run: `cargo run --bin 01-exportable-memory` (add `-- --json` for the report).

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::cli::{Largest, Smallest};
use common::base::image::image_info;
use common::base::owned::create;
use common::instruments::fail;
use common::instruments::report::uuid_hex;
use common::interop::exportable::{BUFFER_IMPORT_SLACK, HANDLE_TYPE};
use common::{Flags, Report, Requirements, VulkanContext, ms_since, open_fd_count};
use serde_json::json;
use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::process::ExitCode;
use std::time::Instant;

mod describe;

use describe::{describe_support, fd_target, is_open, memory_json, requirements_json, support_json};

const CHAPTER: &str = "01-exportable-memory";
/// Any size: nothing checked here depends on how many pixels there are.
const SMALLEST: Smallest = Smallest::ANY;

// ANCHOR: extensions
/// Exporting memory as a POSIX fd is the only device extension this chapter needs.
/// (`VK_KHR_external_memory` and dedicated allocations are core since Vulkan 1.1.)
const DEVICE_EXTENSIONS: &[&CStr] = &[ash::khr::external_memory_fd::NAME];
// ANCHOR_END: extensions

// ANCHOR: resources
/// One triangle of (x, y, u, v) vertices: what chapter 02 will draw from this buffer.
const TRIANGLE: [[f32; 4]; 3] = [[0.0, 0.8, 0.5, 0.0], [-0.8, -0.8, 0.0, 1.0], [0.8, -0.8, 1.0, 1.0]];
const BUFFER_BYTES: u64 = std::mem::size_of::<[[f32; 4]; 3]>() as u64;
/// The image a compute shader will write and GL will sample (chapter 04).
const IMAGE_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
// ANCHOR_END: resources

/// Chapter 01: export Vulkan memory as file descriptors, ready for OpenGL.
#[derive(clap::Parser)]
struct Args {} // no flags of its own: `args.common` holds those every chapter takes

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let started = Instant::now();
    // ANCHOR: usage
    // What the buffer and the image will be used for. Export support is asked for, and
    // granted, per usage: ask for exactly what the resource will do.
    let buffer_usage = vk::BufferUsageFlags::VERTEX_BUFFER
        | vk::BufferUsageFlags::TRANSFER_SRC
        | vk::BufferUsageFlags::TRANSFER_DST;
    let image_usage = vk::ImageUsageFlags::STORAGE
        | vk::ImageUsageFlags::SAMPLED
        | vk::ImageUsageFlags::COLOR_ATTACHMENT
        | vk::ImageUsageFlags::TRANSFER_SRC
        | vk::ImageUsageFlags::TRANSFER_DST;
    // ANCHOR_END: usage

    // 1. Create a device that can export memory
    // ANCHOR: context
    let ctx = VulkanContext::new(&Requirements { extensions: DEVICE_EXTENSIONS, ..Default::default() })?;
    report.vulkan = Some(ctx.report());
    eprintln!(
        "device UUID {}, driver UUID {}",
        uuid_hex(&ctx.info.device_uuid),
        uuid_hex(&ctx.info.driver_uuid)
    );
    // ANCHOR_END: context
    report.time_ms("create_context", ms_since(started));
    let open_fds_before = open_fd_count()?;
    let started = Instant::now();

    // 2. Ask what the driver can share
    // ANCHOR: query_buffer
    let buffer_query =
        vk::PhysicalDeviceExternalBufferInfo::default().usage(buffer_usage).handle_type(HANDLE_TYPE);
    let mut buffer_support = vk::ExternalBufferProperties::default();
    unsafe {
        ctx.instance.get_physical_device_external_buffer_properties(
            ctx.physical_device,
            &buffer_query,
            &mut buffer_support,
        )
    };
    let buffer_support = buffer_support.external_memory_properties;
    // ANCHOR_END: query_buffer
    // ANCHOR: query_image
    let mut external_query = vk::PhysicalDeviceExternalImageFormatInfo::default().handle_type(HANDLE_TYPE);
    let image_query = vk::PhysicalDeviceImageFormatInfo2::default()
        .format(IMAGE_FORMAT)
        .ty(vk::ImageType::TYPE_2D)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(image_usage)
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT) // as the image will be created, below
        .push_next(&mut external_query);
    let mut external_support = vk::ExternalImageFormatProperties::default();
    let mut image_format = vk::ImageFormatProperties2::default().push_next(&mut external_support);
    // VK_ERROR_FORMAT_NOT_SUPPORTED when no such image can be exported at all.
    fail::call("vkGetPhysicalDeviceImageFormatProperties2", || unsafe {
        ctx.instance.get_physical_device_image_format_properties2(
            ctx.physical_device,
            &image_query,
            &mut image_format,
        )
    })
    .context("this device cannot make an exportable RGBA8 storage image")?;
    let max_extent = image_format.image_format_properties.max_extent;
    let image_support = external_support.external_memory_properties;
    // ANCHOR_END: query_image
    describe_support("buffer", &buffer_support);
    describe_support("image", &image_support);
    let exportable = vk::ExternalMemoryFeatureFlags::EXPORTABLE;
    report.check("buffer_exportable", buffer_support.external_memory_features.contains(exportable));
    report.check("image_exportable", image_support.external_memory_features.contains(exportable));
    let size = args.common.size;
    let largest = Largest {
        width: max_extent.width,
        height: max_extent.height,
        pixels: u64::MAX, // nothing is read back
        limits: format!("{}: the maxExtent of an exportable RGBA8 storage image", ctx.info.name),
    };
    largest.check(CHAPTER, size)?;

    // 3. Create a buffer and an image that may be exported
    // ANCHOR: create
    let mut buffer_external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE_TYPE);
    let buffer_info = vk::BufferCreateInfo::default()
        .size(BUFFER_BYTES)
        .usage(buffer_usage)
        .push_next(&mut buffer_external);
    // `create`: the call, as a step `VKGL_FAIL_AT` can make fail, its error named; and the new
    // buffer owned from the moment it exists: any early return from here on destroys it.
    let buffer =
        create(&ctx.device, "vkCreateBuffer", || unsafe { ctx.device.create_buffer(&buffer_info, None) })?
            .counted("vk_buffer_exportable", 0); // for the report's list of resources

    // The image likewise, with the same format, tiling, usage and flags step 2 asked about.
    let mut image_external = vk::ExternalMemoryImageCreateInfo::default().handle_types(HANDLE_TYPE);
    let extent = vk::Extent2D { width: size.width, height: size.height };
    let image_info = image_info(IMAGE_FORMAT, image_usage, extent)
        // Some drivers corrupt shared images unless views of other formats are allowed.
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT)
        .push_next(&mut image_external);
    let image = create(&ctx.device, "vkCreateImage (exportable, R8G8B8A8_UNORM)", || unsafe {
        ctx.device.create_image(&image_info, None)
    })?
    .counted("vk_image_exportable", 0);
    // ANCHOR_END: create

    // 4. Ask whether each needs memory of its own
    // ANCHOR: requirements
    let mut buffer_dedicated = vk::MemoryDedicatedRequirements::default();
    let mut buffer_requirements = vk::MemoryRequirements2::default().push_next(&mut buffer_dedicated);
    let info = vk::BufferMemoryRequirementsInfo2::default().buffer(*buffer);
    unsafe { ctx.device.get_buffer_memory_requirements2(&info, &mut buffer_requirements) };
    let buffer_requirements = buffer_requirements.memory_requirements;

    let mut image_dedicated = vk::MemoryDedicatedRequirements::default();
    let mut image_requirements = vk::MemoryRequirements2::default().push_next(&mut image_dedicated);
    let info = vk::ImageMemoryRequirementsInfo2::default().image(*image);
    unsafe { ctx.device.get_image_memory_requirements2(&info, &mut image_requirements) };
    let image_requirements = image_requirements.memory_requirements;
    // ANCHOR_END: requirements
    let dedicated_only = vk::ExternalMemoryFeatureFlags::DEDICATED_ONLY;
    // A driver that calls the image's export "dedicated only" must also require dedicated memory.
    report.check(
        "dedicated_only_implies_required",
        !image_support.external_memory_features.contains(dedicated_only)
            || image_dedicated.requires_dedicated_allocation == vk::TRUE,
    );

    // 5. Allocate exportable memory and bind at offset 0
    // ANCHOR: allocate
    // The buffer is host-visible so that we can write the triangle into it from the CPU. Its
    // allocation gets BUFFER_IMPORT_SLACK extra bytes, which llvmpipe's GL import needs.
    let host_visible = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
    let buffer_type = ctx.find_memory_type(buffer_requirements.memory_type_bits, host_visible)?;
    let buffer_size = buffer_requirements.size + BUFFER_IMPORT_SLACK;
    // The promise on the memory: this allocation will be exported as an opaque fd.
    let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE_TYPE);
    let info = vk::MemoryAllocateInfo::default()
        .allocation_size(buffer_size)
        .memory_type_index(buffer_type)
        .push_next(&mut export);
    let buffer_memory = create(&ctx.device, "vkAllocateMemory for the buffer (exportable)", || unsafe {
        ctx.device.allocate_memory(&info, None)
    })?
    .counted("vk_memory_exportable", buffer_size);

    // Images always get a dedicated allocation, of exactly the required size: the only kind
    // every driver can share, and GL is told so on import (GL_DEDICATED_MEMORY_OBJECT_EXT).
    let image_type =
        ctx.find_memory_type(image_requirements.memory_type_bits, vk::MemoryPropertyFlags::DEVICE_LOCAL)?;
    let image_size = image_requirements.size;
    let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE_TYPE);
    let mut dedicated = vk::MemoryDedicatedAllocateInfo::default().image(*image);
    let info = vk::MemoryAllocateInfo::default()
        .allocation_size(image_size)
        .memory_type_index(image_type)
        .push_next(&mut export)
        .push_next(&mut dedicated);
    let image_memory =
        create(&ctx.device, "vkAllocateMemory for the image (exportable, dedicated)", || unsafe {
            ctx.device.allocate_memory(&info, None)
        })?
        .counted("vk_memory_exportable", image_size);
    // Offset 0, always: llvmpipe ignores offsets into imported memory.
    fail::call("vkBindBufferMemory", || unsafe {
        ctx.device.bind_buffer_memory(*buffer, *buffer_memory, 0)
    })?;
    fail::call("vkBindImageMemory", || unsafe { ctx.device.bind_image_memory(*image, *image_memory, 0) })?;
    // ANCHOR_END: allocate
    report.check("buffer_memory_has_import_slack", buffer_size >= buffer_requirements.size + 48);
    report.check("image_memory_is_exact", image_size == image_requirements.size);

    // 6. Export file descriptors
    // ANCHOR: export
    // An extension function: it comes from a loader made for the device, not from ash::Device.
    let fd_loader = ash::khr::external_memory_fd::Device::new(&ctx.instance, &ctx.device);
    let export_fd = |memory: vk::DeviceMemory| -> Result<OwnedFd> {
        let info = vk::MemoryGetFdInfoKHR::default().memory(memory).handle_type(HANDLE_TYPE);
        let fd = fail::call("vkGetMemoryFdKHR", || unsafe { fd_loader.get_memory_fd(&info) })?;
        // SAFETY: a new fd that nothing else owns; until an import takes it, dropping closes it.
        Ok(unsafe { OwnedFd::from_raw_fd(fd) })
    };
    let buffer_fd = export_fd(*buffer_memory)?;
    let image_fd = export_fd(*image_memory)?;
    // ANCHOR_END: export
    eprintln!("buffer fd {} -> {}", buffer_fd.as_raw_fd(), fd_target(&buffer_fd));
    eprintln!("image  fd {} -> {}", image_fd.as_raw_fd(), fd_target(&image_fd));
    report.check("fds_are_valid", is_open(&buffer_fd) && is_open(&image_fd));
    report.check("fds_are_distinct", buffer_fd.as_raw_fd() != image_fd.as_raw_fd());
    report.set("fds", json!({ "buffer": buffer_fd.as_raw_fd(), "image": image_fd.as_raw_fd() }));
    report.time_ms("query_create_export", ms_since(started));

    // 7. Prove the descriptor is the memory: import it back and read the triangle through it
    // ANCHOR: reimport
    let mapped = fail::call("vkMapMemory for the exported buffer", || unsafe {
        ctx.device.map_memory(*buffer_memory, 0, BUFFER_BYTES, vk::MemoryMapFlags::empty())
    })?;
    // SAFETY: the mapping is BUFFER_BYTES long and host-coherent; nothing else uses it.
    unsafe {
        std::ptr::copy_nonoverlapping(
            TRIANGLE.as_ptr().cast::<u8>(),
            mapped.cast::<u8>(),
            BUFFER_BYTES as usize,
        )
    };
    unsafe { ctx.device.unmap_memory(*buffer_memory) };

    // Same size and memory type as the export: for OPAQUE_FD the importer must match both.
    let mut import = vk::ImportMemoryFdInfoKHR::default().handle_type(HANDLE_TYPE).fd(buffer_fd.as_raw_fd());
    let import_info = vk::MemoryAllocateInfo::default()
        .allocation_size(buffer_size)
        .memory_type_index(buffer_type)
        .push_next(&mut import);
    // Freeing the imported allocation (when `imported` is dropped) releases the fd the driver
    // took over.
    let imported = create(&ctx.device, "vkAllocateMemory importing the buffer's fd", || unsafe {
        ctx.device.allocate_memory(&import_info, None)
    })?;
    // SAFETY: the import succeeded, so the fd now belongs to the driver; it must not be closed.
    let _ = buffer_fd.into_raw_fd();

    let view = fail::call("vkMapMemory for the imported memory", || unsafe {
        ctx.device.map_memory(*imported, 0, BUFFER_BYTES, vk::MemoryMapFlags::empty())
    })?;
    // SAFETY: BUFFER_BYTES of host-coherent mapped memory.
    let read_back: [[f32; 4]; 3] = unsafe { std::ptr::read_unaligned(view.cast()) };
    unsafe { ctx.device.unmap_memory(*imported) };
    // ANCHOR_END: reimport
    report.check("reimported_fd_reads_the_triangle", read_back == TRIANGLE);

    report.set(
        "buffer",
        json!({
            "bytes": BUFFER_BYTES,
            "usage": format!("{buffer_usage:?}"),
            "external": support_json(&buffer_support),
            "requirements": requirements_json(&buffer_requirements, &buffer_dedicated),
            "memory": memory_json(&ctx, buffer_size, buffer_type),
        }),
    );
    report.set(
        "image",
        json!({
            "format": format!("{IMAGE_FORMAT:?}"),
            "width": size.width,
            "height": size.height,
            "usage": format!("{image_usage:?}"),
            "external": support_json(&image_support),
            "requirements": requirements_json(&image_requirements, &image_dedicated),
            "memory": memory_json(&ctx, image_size, image_type),
        }),
    );

    // 8. Clean up, newest first
    // ANCHOR: cleanup
    // Nothing was submitted, so nothing is in flight: no wait first. Each drop makes its owner's call.
    drop(image_fd); // nobody imported the image's fd: it is still ours to close
    drop(imported); // vkFreeMemory: releases the buffer's fd, which the driver took over
    drop(image_memory); // vkFreeMemory
    drop(buffer_memory); // vkFreeMemory
    drop(image); // vkDestroyImage
    drop(buffer); // vkDestroyBuffer
    // ANCHOR_END: cleanup
    let open_fds_after = common::settled_fd_count(open_fds_before)?;
    eprintln!("open fds: {open_fds_before} before exporting, {open_fds_after} after cleaning up");
    report.check("no_fd_leaked", open_fds_after == open_fds_before);
    Ok(())
}

/// Every chapter ends the same way: `run_chapter` parses the flags (the chapter's `Args`, and
/// `args.common`, those every chapter takes), refuses a `--size` below `SMALLEST`, calls `run`,
/// prints the report and turns its checks into the exit code.
fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
