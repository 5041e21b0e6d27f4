//! Chapter 03: semaphores.
//!
//! GL and Vulkan now share an image and take turns with it every frame: GL draws into it, Vulkan
//! reads what GL drew and writes its own pattern, GL reads that. Two exported semaphores order the
//! turns on the GPU; where the driver cannot share semaphores (lavapipe, llvmpipe) the CPU waits
//! for each side instead. Each frame's colours are new, so a turn taken too early would see the
//! previous frame's colours, and the checks would fail.
//!
//! Run: `cargo run --bin 03-semaphores -- --frames 60` (add `--unsynchronised` to see it break).

mod pattern;
mod vulkan_turn;

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::{Commands, HostBuffer};
use common::base::gl::{
    GlContext, HANDLE_TYPE_OPAQUE_FD_EXT, MEMORY_EXTENSIONS, OPTIMAL_TILING_EXT, Semaphore,
    TEXTURE_TILING_EXT, made,
};
use common::base::owned::create;
use common::clocks::timestamps::{Timestamps, median_p95};
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::instruments::fail;
use common::instruments::output;
use common::interop::exportable::{self, Dedicated};
use common::interop::handoff::{Handoff, SEMAPHORE_EXTENSION, SharedSemaphore};
use common::interop::{self, SharedTexture};
use common::{Flags, Report, Requirements, VulkanContext, ms_since};
use glow::HasContext;
use pattern::{checkerboard, first_pixel_is, frame_colours};
use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::process::ExitCode;
use std::ptr::null;
use std::time::Instant;
use vulkan_turn::record_vulkan_turn;

const CHAPTER: &str = "03-semaphores";
/// Any size: nothing checked here depends on how many pixels there are.
const SMALLEST: Smallest = Smallest::ANY;
const REQUIRED: &[&CStr] = &[ash::khr::external_memory_fd::NAME];
/// Without it the chapter still runs, synchronising on the host.
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];

/// Chapter 03: GL and Vulkan take turns with a shared image, ordered by shared semaphores.
#[derive(clap::Parser)]
struct Args {
    /// Skip every wait (semaphore or host) to see the checks fail: the order is real.
    #[arg(long)]
    unsynchronised: bool,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let extent = vk::Extent2D { width: args.common.size.width, height: args.common.size.height };
    let frames = args.common.headless_frames();

    // 1. Create both contexts and a shared image
    let vk = VulkanContext::new(&Requirements {
        extensions: REQUIRED,
        optional_extensions: OPTIONAL,
        ..Default::default()
    })?;
    let gl_context = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    common::connect(report, &vk, &gl_context)?;
    common::largest_size(&vk, &gl_context).check(CHAPTER, args.common.size)?;
    let open_fds_before = common::open_fd_count()?;
    // ANCHOR: shared_image
    let usage = vk::ImageUsageFlags::COLOR_ATTACHMENT // GL draws into it
        | vk::ImageUsageFlags::TRANSFER_SRC // Vulkan copies GL's pixels out
        | vk::ImageUsageFlags::TRANSFER_DST; // Vulkan writes its own
    // Vulkan's side, as chapter 01 made it: an exportable image in dedicated memory, bound at 0.
    let image = exportable::create_image(&vk, vk::Format::R8G8B8A8_UNORM, usage, extent)?;
    let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
    let local = vk::MemoryPropertyFlags::DEVICE_LOCAL;
    let memory = exportable::allocate(&vk, &requirements, local, Dedicated::Image(*image))?;
    fail::call("vkBindImageMemory", || unsafe { vk.device.bind_image_memory(*image, *memory.memory, 0) })?;
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    let fd = exportable::export_fd(&fd_loader, *memory.memory)?;
    // GL's side: chapter 02's import (dedicated, so GL_DEDICATED_MEMORY_OBJECT_EXT is set first),
    // then a texture whose storage is the memory object, as chapter 02's buffer was.
    let memory_object = interop::import_memory(&gl_context, memory.terms(), fd)?;
    let what = "glCreateTextures (imported)";
    let texture =
        common::base::gl::create(gl, what, |gl| unsafe { gl.create_named_texture(glow::TEXTURE_2D) })?
            .counted("gl_texture_imported", 0);
    let ext = gl_context.memory_fns()?;
    fail::step("glTextureStorageMem2DEXT")?;
    unsafe {
        // Vulkan made the image VK_IMAGE_TILING_OPTIMAL, the driver's private layout: GL must be
        // told so before the storage exists.
        gl.texture_parameter_i32(*texture, TEXTURE_TILING_EXT, OPTIMAL_TILING_EXT as i32);
        // One level of GL_RGBA8, GL's R8G8B8A8_UNORM, at offset 0 of the memory object.
        let (width, height) = (extent.width as i32, extent.height as i32);
        (ext.TextureStorageMem2DEXT)(texture.0.get(), 1, glow::RGBA8, width, height, memory_object.0, 0);
    }
    gl_context.check_error("glTextureStorageMem2DEXT")?;
    // The texture and its memory object, to drop in that order (`SharedTexture`'s fields).
    let texture = SharedTexture::new(texture, memory_object);
    // ANCHOR_END: shared_image

    // 2. Share two semaphores, or fall back to the host
    // ANCHOR: sync
    let handoff = Handoff::with(&vk, &gl_context, share_semaphore)?;
    report.sync = Some(if args.unsynchronised { "none" } else { handoff.name() });
    // ANCHOR_END: sync
    // ANCHOR: first_hand_over
    // GL draws into the image first: Vulkan moves it out of UNDEFINED and hands it to GL, in
    // GENERAL, before that (with semaphores, GL's wait names GENERAL).
    interop::hand_new_images_to_gl(&vk, &gl_context, &handoff, &[(*image, *texture.texture)])?;
    // ANCHOR_END: first_hand_over
    let framebuffer =
        common::base::gl::create(gl, "glCreateFramebuffers", |gl| unsafe { gl.create_named_framebuffer() })?;
    let attached = Some(*texture.texture);
    unsafe { gl.named_framebuffer_texture(Some(*framebuffer), glow::COLOR_ATTACHMENT0, attached, 0) };
    // ANCHOR: layouts
    // Where GL leaves the image for Vulkan: ready to be copied from. Where Vulkan leaves it for GL:
    // ready to be a framebuffer attachment, which is how GL both reads Vulkan's pattern and draws
    // the next frame. With semaphores, GL makes both transitions as part of its signal and wait;
    // on the host path GL makes none, and `hand_over` answers GENERAL for both.
    let layouts =
        handoff.hand_over(vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL);
    let (signal_layout, wait_layout) = layouts.gl(); // the same two, as GL's signal and wait name them
    // ANCHOR_END: layouts
    let semaphore_fns = gl_context.semaphores; // GL_EXT_semaphore, when the driver has it
    let texture_name = texture.texture.0.get();

    let pixels = (extent.width * extent.height) as usize;
    let timestamps = Timestamps::new(&vk)?;
    let transfer = vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
    let mut vulkan_pattern = HostBuffer::new(&vk, pixels as u64 * 4, transfer)?;
    let gl_pixels_seen_by_vulkan = HostBuffer::new(&vk, pixels as u64 * 4, transfer)?;
    // Made after everything its submissions use, so that an early return drops it first: its
    // Drop waits for the last submission before anything that submission uses is destroyed.
    let commands = Commands::new(&vk)?;

    let (mut vulkan_saw_gl, mut gl_saw_vulkan) = (true, true);
    // Each frame's GL clear and Vulkan copies (GPU), handshake and whole frame (CPU): common::clocks::timing.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let mut last_seen_by_gl = Vec::new();
    for frame in 0..frames {
        let started = Instant::now();
        let (gl_colour, vulkan_colour) = frame_colours(frame);

        // 3. GL draws, then hands the image to Vulkan
        // ANCHOR: gl_turn
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*framebuffer));
            gl.viewport(0, 0, extent.width as i32, extent.height as i32);
            let [r, g, b] = gl_colour.map(|c| c as f32 / 255.0);
            gl.clear_color(r, g, b, 1.0);
        }
        gl_timer.time(gl, "gl_clear", || unsafe { gl.clear(glow::COLOR_BUFFER_BIT) })?;
        let handshake = Instant::now();
        match &handoff {
            _ if args.unsynchronised => {}
            Handoff::Semaphores { gl_done, .. } => unsafe {
                let ext = semaphore_fns.expect("Handoff::Semaphores implies GL semaphores");
                // Queued behind the clear: GL moves the texture to the layout Vulkan's acquire
                // names, makes its writes available, then signals. (No buffers: 0, null.)
                (ext.SignalSemaphoreEXT)(gl_done.gl.0, 0, null(), 1, &texture_name, &signal_layout);
                // The signal sits in GL's queue until flushed: without this, Vulkan could wait
                // for it for ever.
                gl.flush();
            },
            // glFinish: the CPU waits until the clear is in memory.
            Handoff::Host { .. } => handoff.gl_release(&gl_context, &[*texture.texture], &[signal_layout]),
        }
        let mut handshake_cpu = ms_since(handshake);
        // ANCHOR_END: gl_turn

        // 4. Vulkan waits, reads GL's pixels, writes its own, hands the image back
        // The CPU fills Vulkan's pattern; the previous frame's copy has finished (its fence).
        let cb = commands.begin(&vk)?;
        if frame > 0 {
            vulkan_saw_gl &= first_pixel_is(&gl_pixels_seen_by_vulkan, frame_colours(frame - 1).0);
            if let Some(t) = &timestamps {
                times.add("vulkan_gpu", t.read_ms(&vk)?);
            }
        }
        checkerboard(vulkan_pattern.bytes_mut(), extent, vulkan_colour);
        if let Some(t) = &timestamps {
            t.reset(&vk, cb);
        }
        let buffers = (&vulkan_pattern, &gl_pixels_seen_by_vulkan);
        record_vulkan_turn(&vk, cb, (*image, extent), layouts, buffers, timestamps.as_ref());
        let handshake = Instant::now();
        // ANCHOR: submit
        // Wait for GL's signal before the copy (TRANSFER) stage; nothing earlier touches the image.
        let (wait, signal) = match args.unsynchronised {
            false => (
                handoff.vulkan_waits_on().map(|s| (s, vk::PipelineStageFlags::TRANSFER)),
                handoff.vulkan_signals(),
            ),
            true => (None, None),
        };
        commands.submit(&vk, wait, signal)?;
        // ANCHOR_END: submit

        // 5. GL waits for Vulkan and reads its pattern
        // ANCHOR: gl_reads
        match &handoff {
            _ if args.unsynchronised => {}
            Handoff::Semaphores { vulkan_done, .. } => unsafe {
                let ext = semaphore_fns.expect("Handoff::Semaphores implies GL semaphores");
                // GL's queue, not the CPU, waits for Vulkan's signal. The texture is in the layout
                // Vulkan's release left it in: GL's half of that ownership transfer.
                (ext.WaitSemaphoreEXT)(vulkan_done.gl.0, 0, null(), 1, &texture_name, &wait_layout);
            },
            // The CPU waits for the submission's fence.
            Handoff::Host { .. } => {
                let fence = *commands.fence;
                handoff.gl_acquire(&vk, &gl_context, fence, &[*texture.texture], &[wait_layout])?;
            }
        }
        handshake_cpu += ms_since(handshake);
        let seen = output::read_gl_rgba8(gl, extent.width, extent.height);
        // ANCHOR_END: gl_reads
        // GL numbers rows from the bottom, Vulkan from the top: the image's first row in memory,
        // Vulkan's top row (a lit square), is GL's bottom row, which read_gl_rgba8 puts last.
        let memory_row_0 = (extent.height - 1) as usize * extent.width as usize * 4;
        gl_saw_vulkan &= seen[memory_row_0..memory_row_0 + 3] == vulkan_colour;
        times.add("handshake_cpu", handshake_cpu);
        times.add("frame", ms_since(started));
        gl_timer.end_frame(gl, &mut times);
        last_seen_by_gl = seen;
    }

    // The last frame's copy: wait for its fence (Commands::begin would) before reading it.
    commands.wait(&vk, "vkWaitForFences for the last frame's copy")?;
    vulkan_saw_gl &= first_pixel_is(&gl_pixels_seen_by_vulkan, frame_colours(frames - 1).0);
    if let Some(t) = &timestamps {
        times.add("vulkan_gpu", t.read_ms(&vk)?);
    }
    gl_timer.finish(gl, &mut times);
    report.check("vulkan_sees_each_frame_gl_drew", vulkan_saw_gl);
    report.check("gl_sees_each_frame_vulkan_wrote", gl_saw_vulkan);
    let out_dir = args.common.out_dir(CHAPTER);
    pattern::save_last_frame(report, &out_dir, CHAPTER, extent, &last_seen_by_gl, &gl_pixels_seen_by_vulkan)?;
    times.record(report);
    let (median, _) = median_p95(times.samples("handshake_cpu"));
    eprintln!("{} handshake: the CPU spends {median:.3} ms a frame in it (median)", handoff.name());
    report.set("frames", frames);

    // On the host path GL moves no image: each hand-over named the layout the image was in.
    report.check("hand_over_layouts_agree", handoff.layouts_agreed());
    // 6. Clean up, newest first
    // ANCHOR: cleanup
    // The wait before teardown (the book's "Waiting before teardown"): GL, then Vulkan, once.
    unsafe { gl.finish() };
    vk.wait_idle()?;
    drop(gl_timer); // its queries
    drop(commands); // the command pool and the fence
    drop(gl_pixels_seen_by_vulkan); // unmapped, freed, destroyed
    drop(vulkan_pattern);
    drop(timestamps);
    drop(handoff); // the semaphores, GL's first: it holds the imported payload
    drop(framebuffer);
    drop(texture); // GL's texture, then its memory object: releases the fd GL took over
    drop(memory); // vkFreeMemory
    drop(image); // vkDestroyImage
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    // Every fd (image memory, two semaphores) went to GL and was released with its object.
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

// ANCHOR: share_semaphore
/// A Vulkan semaphore exported as an fd and imported into GL, which then owns the fd. Each side
/// is owned as it is made: an early return deletes what exists, GL's first.
fn share_semaphore(vk: &VulkanContext, gl: &GlContext) -> Result<SharedSemaphore> {
    let ext = gl.semaphores.as_ref().context("GL has no GL_EXT_semaphore_fd")?;
    // The promise, at creation, that this semaphore's payload may leave Vulkan as an opaque fd.
    let handle_type = vk::ExternalSemaphoreHandleTypeFlags::OPAQUE_FD;
    let mut export = vk::ExportSemaphoreCreateInfo::default().handle_types(handle_type);
    let info = vk::SemaphoreCreateInfo::default().push_next(&mut export);
    let semaphore_vk = create(&vk.device, "vkCreateSemaphore (exportable)", || unsafe {
        vk.device.create_semaphore(&info, None)
    })?;
    common::instruments::resources::created("vk_semaphore_exportable", 0);
    let loader = ash::khr::external_semaphore_fd::Device::new(&vk.instance, &vk.device);
    let get = vk::SemaphoreGetFdInfoKHR::default().semaphore(*semaphore_vk).handle_type(handle_type);
    let fd = fail::call("vkGetSemaphoreFdKHR", || unsafe { loader.get_semaphore_fd(&get) })?;
    // SAFETY: a new fd that nothing else owns. Until the import succeeds, dropping it closes it.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    let semaphore_gl = common::base::gl::create(ext, "glGenSemaphoresEXT", |ext| {
        let mut name = 0;
        unsafe { (ext.GenSemaphoresEXT)(1, &mut name) };
        made(name, "glGenSemaphoresEXT").map(Semaphore)
    })?;
    fail::step("glImportSemaphoreFdEXT")?;
    unsafe { (ext.ImportSemaphoreFdEXT)(semaphore_gl.0, HANDLE_TYPE_OPAQUE_FD_EXT, fd.as_raw_fd()) };
    // On failure `fd` is dropped, and so closed: the failed import did not take it.
    gl.check_error("glImportSemaphoreFdEXT")?;
    // SAFETY: the import succeeded; the fd is GL's now.
    let _ = fd.into_raw_fd();
    Ok(SharedSemaphore { gl: semaphore_gl, vk: semaphore_vk })
}
// ANCHOR_END: share_semaphore

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
