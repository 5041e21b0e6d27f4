//! Chapter 03: semaphores.
//!
//! GL and Vulkan now share an image and take turns with it every frame: GL draws into it, Vulkan
//! reads what GL drew and writes its own pattern, GL reads that. Two exported semaphores order the
//! turns on the GPU; where the driver cannot share semaphores (lavapipe, llvmpipe) the CPU waits
//! for each side instead. Each frame's colours are new, so a turn taken too early would see the
//! previous frame's colours, and the checks would fail.
//!
//! Run: `cargo run --bin 03-semaphores -- --frames 60` (add `--unsynchronised` to see it break).

use anyhow::Result;
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::{COLOR_RANGE, Commands, HostBuffer};
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::base::output;
use common::base::timestamps::{Timestamps, median_p95};
use common::base::timing::{GlPassTimer, PassTimes};
use common::interop::handoff::{HandOver, Handoff, SEMAPHORE_EXTENSION};
use common::interop::{self, SharedFormat, SharedImage};
use common::{CommonArgs, Report, Requirements, VulkanContext, ms_since};
use glow::HasContext;
use std::ffi::CStr;
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "03-semaphores";
/// Any size: nothing checked here depends on how many pixels there are.
const SMALLEST: Smallest = Smallest::ANY;
const REQUIRED: &[&CStr] = &[ash::khr::external_memory_fd::NAME];
/// Without it the chapter still runs, synchronising on the host.
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];

/// Chapter 03: GL and Vulkan take turns with a shared image, ordered by shared semaphores.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Skip every wait (semaphore or host) to see the checks fail: the order is real.
    #[arg(long)]
    unsynchronised: bool,
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, |args: &Args| &args.common, run)
}

fn run(args: &Args, report: &mut Report) -> Result<()> {
    SMALLEST.check(CHAPTER, args.common.size)?;
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
    let image = SharedImage::new(&vk, &gl_context, SharedFormat::RGBA8, usage, extent)?;
    // GL draws into it first: Vulkan moves it out of UNDEFINED and hands it over before that.
    interop::hand_new_images_to_gl(&vk, &[&image])?;
    // ANCHOR_END: shared_image
    let framebuffer =
        common::base::gl::create(gl, "glCreateFramebuffers", |gl| unsafe { gl.create_named_framebuffer() })?;
    let texture = Some(*image.texture.texture);
    unsafe { gl.named_framebuffer_texture(Some(*framebuffer), glow::COLOR_ATTACHMENT0, texture, 0) };

    // 2. Share two semaphores, or fall back to the host
    // ANCHOR: sync
    let handoff = Handoff::new(&vk, &gl_context)?;
    report.sync = Some(if args.unsynchronised { "none" } else { handoff.name() });
    // ANCHOR_END: sync
    // ANCHOR: layouts
    // Where GL leaves the image for Vulkan: ready to be copied from. Where Vulkan leaves it for GL:
    // ready to be a framebuffer attachment, which is how GL both reads Vulkan's pattern and draws
    // the next frame. With semaphores, GL makes both transitions as part of its signal and wait;
    // on the host path GL makes none, and `hand_over` answers GENERAL for both.
    let layouts =
        handoff.hand_over(vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL);
    let (signal_layout, wait_layout) = layouts.gl(); // the same two, as GL's signal and wait name them
    // ANCHOR_END: layouts

    let pixels = (extent.width * extent.height) as usize;
    let timestamps = Timestamps::new(&vk)?;
    let transfer = vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
    let mut vulkan_pattern = HostBuffer::new(&vk, pixels as u64 * 4, transfer)?;
    let gl_pixels_seen_by_vulkan = HostBuffer::new(&vk, pixels as u64 * 4, transfer)?;
    // Made after everything its submissions use, so that an early return drops it first: its
    // Drop waits for the last submission before anything that submission uses is destroyed.
    let commands = Commands::new(&vk)?;

    let (mut vulkan_saw_gl, mut gl_saw_vulkan) = (true, true);
    // Each frame's GL clear and Vulkan copies (GPU), handshake and whole frame (CPU): common::base::timing.
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
        if !args.unsynchronised {
            handoff.gl_release(&gl_context, &[*image.texture.texture], &[signal_layout]);
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
        record_vulkan_turn(&vk, cb, &image, layouts, buffers, timestamps.as_ref());
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
        if !args.unsynchronised {
            let texture = *image.texture.texture;
            handoff.gl_acquire(&vk, &gl_context, *commands.fence, &[texture], &[wait_layout])?;
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
    output::save_rgba8(
        report,
        &args.common.out_dir(CHAPTER),
        CHAPTER,
        (extent.width, extent.height),
        &last_seen_by_gl,
    )?;
    let from_gl = gl_pixels_seen_by_vulkan.bytes().to_vec();
    output::save_rgba8(
        report,
        &args.common.out_dir(CHAPTER),
        &format!("{CHAPTER}-gl"),
        (extent.width, extent.height),
        &from_gl,
    )?;
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
    drop(image); // GL's texture and memory object, then Vulkan's view, memory and image
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    // Every fd (image memory, two semaphores) went to GL and was released with its object.
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

// ANCHOR: vulkan_turn
/// Copy GL's pixels out, write Vulkan's pattern in. Every barrier says which earlier work must
/// finish (src) before which later work may start (dst), and moves the image between layouts.
fn record_vulkan_turn(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    image: &SharedImage,
    layouts: HandOver,
    (pattern, readback): (&HostBuffer, &HostBuffer),
    timestamps: Option<&Timestamps>,
) {
    let barrier = |old, new, src_access, dst_access, src_family, dst_family| {
        vk::ImageMemoryBarrier::default()
            .image(*image.image)
            .subresource_range(COLOR_RANGE)
            .old_layout(old)
            .new_layout(new)
            .src_access_mask(src_access)
            .dst_access_mask(dst_access)
            .src_queue_family_index(src_family)
            .dst_queue_family_index(dst_family)
    };
    let (external, ours) = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
    let region = vk::BufferImageCopy::default()
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_extent(vk::Extent3D { width: image.extent.width, height: image.extent.height, depth: 1 });
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
        device.cmd_copy_image_to_buffer(cb, *image.image, transfer_src, *readback.buffer, &[region]);
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
            *image.image,
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

/// Colours no earlier frame used: GL's for the frame, and Vulkan's.
fn frame_colours(frame: u32) -> ([u8; 3], [u8; 3]) {
    let step = (40 + 50 * (frame % 4)) as u8;
    let shade = (frame * 23 % 200) as u8 + 40;
    ([shade, step, 230], [230, shade, step])
}

/// Vulkan's pattern: a checkerboard of `colour` and black, in 16-pixel squares.
fn checkerboard(bytes: &mut [u8], extent: vk::Extent2D, colour: [u8; 3]) {
    for (i, pixel) in bytes.chunks_exact_mut(4).enumerate() {
        let (x, y) = (i as u32 % extent.width, i as u32 / extent.width);
        let lit = (x / 16 + y / 16) % 2 == 0;
        let [r, g, b] = if lit { colour } else { [0, 0, 0] };
        pixel.copy_from_slice(&[r, g, b, 255]);
    }
}

/// Does the image Vulkan copied out start with GL's colour? (Its first square is all GL's.)
fn first_pixel_is(readback: &HostBuffer, colour: [u8; 3]) -> bool {
    readback.bytes()[..3].iter().zip(colour).all(|(&a, b)| a.abs_diff(b) <= 1)
}
