//! Chapter 15: wgpu and GL, both ways.
//!
//! wgpu, the graphics library most Rust programs draw with, renders chapter 02's triangle into
//! two images whose memory this chapter allocated and exported: the picture, and its depth as a
//! colour image. GL imports both and draws the picture with a line over it, which wgpu's depth
//! hides where the triangle is nearer, into a third shared image. A wgpu compute pass outlines
//! that one into a fourth, which GL shows. wgpu makes its own device, allocates its own memory and
//! records its own barriers; what it does not do for sharing (export memory, enable the
//! extensions, hand images to and from another API) is done here, in wgpu-hal calls.
//!
//! Run: `cargo run --release --bin 15-wgpu` (a window; `--headless` writes out/15-wgpu/*.png).

mod check;
mod device;
mod draw;
mod outline;
mod shared;
mod show;
mod turns;

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::cli::{Largest, Size, Smallest};
use common::base::gl::{GlContext, MEMORY_EXTENSIONS, ensure_same_device, uuids_match};
use common::base::window::{self, Key, NamedKey, Window};
use common::clocks::timestamps::median_p95;
use common::instruments::census::ResizeCensus;
use common::instruments::output;
use common::{Flags, Report, open_fd_count};
use glow::HasContext;
use shared::{DESTROYED_IN_USE, RELEASED, SharedImage, WRAPPED, share_image};
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use turns::Turns;

const CHAPTER: &str = "15-wgpu";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 16,
    height: 16,
    why: "the line's probes need a pixel either side of them, behind the triangle, in front of it and \
          in the open",
    shape: None,
};

/// Chapter 15: wgpu renders into memory GL imports; GL draws over it with wgpu's depth.
#[derive(clap::Parser)]
struct Args {
    /// Every K frames, make all four shared images anew at three quarters, full, then half size
    /// (a leak test of who destroys what).
    #[arg(long, value_name = "K", value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    resize_every: Option<u32>,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let mut size = args.common.size;
    let windowed = !args.common.headless && window::display_available();
    if !args.common.headless && !windowed {
        eprintln!("no display (DISPLAY and WAYLAND_DISPLAY are unset): running headless");
    }
    let frames = if windowed { args.common.window_frames() } else { args.common.headless_frames() };

    // 1. A wgpu device GL can share with
    // ANCHOR: device
    // wgpu made the instance, and its messenger hands the validation layer's messages to `log`.
    if log::set_logger(&device::LayerMessages).is_ok() {
        log::set_max_level(log::LevelFilter::Warn);
    }
    let wgpu = device::open(device::instance()?)?;
    // ANCHOR_END: device
    eprintln!("vulkan: wgpu on {} ({})", wgpu.info.name, wgpu.info.driver);

    // 2. GL, on the same device: in a window when there is a display, headless otherwise
    // ANCHOR: gl
    let (mut window, gl_context) = match windowed {
        true => Window::open(CHAPTER, size, &MEMORY_EXTENSIONS).map(|(w, gl)| (Some(w), gl))?,
        false => (None, GlContext::headless(&wgpu.info, &MEMORY_EXTENSIONS)?),
    };
    let gl = &gl_context.gl;
    report.uuids_match = Some(uuids_match(&wgpu.info, &gl_context));
    ensure_same_device(&wgpu.info, &gl_context)?;
    // ANCHOR_END: gl
    report.vulkan = Some(wgpu.info.report(wgpu.extensions.clone()));
    report.gl = Some(gl_context.report());
    report.set("window", windowed);
    largest_size(&wgpu, gl).check(CHAPTER, size)?;
    let open_fds_before = open_fd_count()?;

    // 3. How the two take turns: semaphores in wgpu's submissions, or the CPU waiting
    // Made before the images: dropped after them, once their drop has waited for wgpu's queue.
    let semaphores = shared::share_semaphores(&wgpu.device, &gl_context, wgpu.semaphores)?;
    report.sync = Some(if semaphores.is_some() { "semaphores" } else { "host" });
    let mut turns = Turns::new(semaphores);

    // 4. Share the four images: memory this chapter allocates, wgpu and GL both use
    // ANCHOR: images
    // wgpu's picture and depths, GL's picture of them, and wgpu's outline of GL's.
    let kinds = [&draw::PICTURE, &draw::DEPTH, &outline::GL_PICTURE, &outline::OUTLINE];
    let share = |size: Size| -> Result<[SharedImage; 4]> {
        let extent = vk::Extent2D { width: size.width, height: size.height };
        let [a, b, c, d] = kinds.map(|kind| share_image(&wgpu.device, &gl_context, kind, extent));
        Ok([a?, b?, c?, d?])
    };
    let mut images = share(size)?;
    // ANCHOR_END: images

    // 5. wgpu's pipelines, and GL's programs and framebuffers
    let render_pipeline = draw::pipeline(&wgpu.device)?;
    let outline_pipeline = outline::pipeline(&wgpu.device)?;
    let mut show = show::Show::new(gl, [&images[2], &images[3]], (size.width, size.height))?;
    // The compute pass's bind group: after the images (dropped before them), made anew with them.
    let mut outline_inputs = outline::bind(&wgpu.device, &outline_pipeline, [&images[2], &images[3]]);

    let (mut frame, mut resizes, mut census) = (0, 0, ResizeCensus::default());
    // The last frame's checks, and its pictures for the PNGs (top row first).
    let (mut checks, mut pictures) = (Vec::new(), Vec::new());
    let mut window_check = None; // the window against the outline, judged unless their sizes differ
    while frames == 0 || frame < frames {
        // 6. A new size: from the window, or every K frames headless
        let wanted = match window.as_mut() {
            Some(window) => {
                let keys: Vec<Key> = window.poll(&gl_context).collect();
                if window.close_requested() || keys.contains(&Key::Named(NamedKey::Escape)) {
                    break;
                }
                let (w, h) = window.size();
                let new = Size { width: w.max(SMALLEST.width), height: h.max(SMALLEST.height) };
                (new != size).then_some(new)
            }
            None => {
                common::frame::input::resize_every(args.resize_every, frame, args.common.size, SMALLEST.width)
            }
        };
        // ANCHOR: resize
        if let Some(new) = wanted {
            // Both sides done with the old images; GL's framebuffers and the compute pass's bind
            // group move to the new ones; then wgpu lets go of the old (its drop callbacks), GL
            // deletes its side, and the chapter destroys the images and frees their memory.
            unsafe { gl.finish() };
            let fresh = share(new)?;
            show.resize(gl, [&fresh[2], &fresh[3]], (new.width, new.height))?;
            outline_inputs = outline::bind(&wgpu.device, &outline_pipeline, [&fresh[2], &fresh[3]]);
            drop(std::mem::replace(&mut images, fresh)); // as in step 12
            (size, turns.gl_had_them, resizes) = (new, false, resizes + 1);
            census.count(&gl_context)?; // what exists after one resize must exist after every later one
        }
        // ANCHOR_END: resize
        let is_last = frame + 1 == frames; // a window's last frame too, with --frames
        let [picture, depth, drawn, outlined] = &images;
        let pixels = (size.width, size.height);

        // 7. wgpu draws the triangle and its depths, and hands every image to GL
        // ANCHOR: wgpu_draws
        let (commands, readbacks) = draw::render(&wgpu.device, &render_pipeline, [picture, depth], is_last);
        turns.wgpu(&wgpu, &images, commands)?;
        // ANCHOR_END: wgpu_draws

        // 8. GL draws wgpu's picture and the line into `drawn`, and hands every image back
        // ANCHOR: gl_draws
        turns.gl_acquire(&wgpu, &gl_context, &images)?;
        show.draw(gl, [picture, depth], true);
        if is_last {
            let (picture_seen, depth_seen) =
                (readbacks[0].bytes(&wgpu.device)?, readbacks[1].bytes(&wgpu.device)?);
            let saw = check::WgpuSaw { picture: picture_seen, depth: depth_seen };
            let (made, with_line) = check::wgpu_to_gl(gl, &show, [picture, depth], &saw, pixels);
            checks.extend(made);
            pictures.extend([(CHAPTER.to_owned(), with_line), (format!("{CHAPTER}-wgpu"), saw.picture)]);
        }
        gl_context.check_error("GL's turn")?;
        turns.gl_release(&gl_context, &images)?;
        // ANCHOR_END: gl_draws

        // 9. wgpu's compute pass outlines GL's picture, and hands every image to GL
        // ANCHOR: wgpu_reads
        let (commands, readbacks) =
            outline::record(&wgpu.device, &outline_pipeline, &outline_inputs, [drawn, outlined], is_last);
        turns.wgpu(&wgpu, &images, commands)?;
        // ANCHOR_END: wgpu_reads

        // 10. GL shows the outline, and hands every image back
        turns.gl_acquire(&wgpu, &gl_context, &images)?;
        if is_last {
            let seen = [readbacks[0].bytes(&wgpu.device)?, readbacks[1].bytes(&wgpu.device)?];
            let (made, outline) = check::gl_to_wgpu(gl, [drawn, outlined], [&seen[0], &seen[1]], pixels);
            checks.extend(made);
            pictures.push((format!("{CHAPTER}-outline"), outline));
        }
        if let Some(window) = &window {
            show.blit(gl, window.size());
            if let (true, Some((_, outline))) = (is_last, pictures.last()) {
                window_check = Some(check::window_shows(gl, outline, pixels, window.size()));
            }
        }
        gl_context.check_error("GL's turn")?;
        turns.gl_release(&gl_context, &images)?;
        if let Some(window) = &mut window {
            window.swap_buffers(&gl_context)?;
        }
        turns.times.frame_done();
        frame += 1;
    }

    // 11. The checks, made on the last frame while GL held the images; its pictures
    for (name, ok) in checks {
        report.check(name, ok);
    }
    if let Some((name, verdict)) = window_check {
        report.verdict(name, verdict);
    }
    let out_dir = args.common.out_dir(CHAPTER);
    for (name, pixels) in pictures {
        output::save_rgba8(report, &out_dir, &name, (size.width, size.height), &pixels)?;
    }
    // What a round trip (GL to wgpu and back) costs the CPU, as chapter 03 measures its own.
    turns.times.record(report);
    if frame > 0 {
        let (median, _) = median_p95(turns.times.samples("handshake_cpu"));
        let sync = report.sync.unwrap_or("host");
        eprintln!("{sync} handshake: the CPU spends {median:.3} ms a round trip in it (median, two a frame)");
    }
    report.set("frames", frame);
    if resizes > 0 {
        report.set("resizes", resizes);
    }
    census.check(&gl_context, report)?;

    // 12. Clean up: wgpu lets go first, then GL, then what the chapter allocated
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    wgpu.device.poll(wgpu::PollType::wait_indefinitely()).context("wgpu: Device::poll")?;
    drop(show);
    drop(outline_inputs);
    drop(images); // each: wgpu's texture destroyed and polled for, GL's side, the image, its memory
    let (wrapped, released) = (WRAPPED.load(Ordering::SeqCst), RELEASED.load(Ordering::SeqCst));
    let in_use = DESTROYED_IN_USE.load(Ordering::SeqCst); // destroyed before wgpu let go
    drop(turns); // the semaphores, GL's side then Vulkan's: no submission uses them now
    // ANCHOR_END: cleanup
    report.set("wgpu_released", format!("{released} of {wrapped} images"));
    report.check("wgpu_let_go_of_every_image", released == wrapped && in_use == 0);
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}

/// The largest picture: wgpu's largest texture, GL's largest texture and renderbuffer.
fn largest_size(wgpu: &device::WgpuDevice, gl: &glow::Context) -> Largest {
    let wgpu_side = wgpu.device.limits().max_texture_dimension_2d;
    let (texture, renderbuffer) = unsafe {
        let size = |name| gl.get_parameter_i32(name).max(0) as u32;
        (size(glow::MAX_TEXTURE_SIZE), size(glow::MAX_RENDERBUFFER_SIZE))
    };
    let side = wgpu_side.min(texture).min(renderbuffer);
    Largest {
        width: side,
        height: side,
        pixels: i32::MAX as u64 / 4,
        limits: format!(
            "{}: wgpu max_texture_dimension_2d {wgpu_side}, GL_MAX_TEXTURE_SIZE {texture}, \
             GL_MAX_RENDERBUFFER_SIZE {renderbuffer}; GL reads back at most {} bytes in one call",
            wgpu.info.name,
            i32::MAX
        ),
    }
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
