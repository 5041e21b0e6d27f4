//! Chapter 15: wgpu and GL.
//!
//! wgpu, the graphics library most Rust programs draw with, renders chapter 02's triangle into
//! two images whose memory this chapter allocated and exported: the picture, and its depth as a
//! colour image. GL imports both, shows the picture and draws a line over it that wgpu's depth
//! hides where the triangle is nearer. wgpu makes its own device, allocates its own memory and
//! records its own barriers; what it does not do for sharing (export memory, enable the
//! extensions, hand images to and from another API) is done here, in wgpu-hal calls.
//!
//! Run: `cargo run --release --bin 15-wgpu` (a window; `--headless` writes out/15-wgpu/*.png).

mod check;
mod device;
mod draw;
mod shared;
mod show;

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::cli::{Largest, Size, Smallest};
use common::base::gl::{GlContext, MEMORY_EXTENSIONS, ensure_same_device, uuids_match};
use common::base::window::{self, Key, NamedKey, Window};
use common::instruments::output;
use common::{Flags, Report, open_fd_count};
use glow::HasContext;
use shared::{DESTROYED_IN_USE, RELEASED, SharedImage, WRAPPED, share_image};
use std::process::ExitCode;
use std::sync::atomic::Ordering;

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
    /// Every K frames, make both shared images anew at half, three quarters, then full size (a
    /// leak test of who destroys what).
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
    let raw_semaphores = semaphores.as_ref().map(|[a, b]| [*a.vk, *b.vk]);

    // 4. Share the two images: memory this chapter allocates, wgpu draws into, GL imports
    // ANCHOR: images
    let share = |size: Size| -> Result<[SharedImage; 2]> {
        let extent = vk::Extent2D { width: size.width, height: size.height };
        let picture = share_image(&wgpu.device, &gl_context, draw::PICTURE, extent)?;
        Ok([picture, share_image(&wgpu.device, &gl_context, draw::DEPTH, extent)?])
    };
    let mut images = share(size)?;
    // ANCHOR_END: images

    // 5. wgpu's pipeline, and GL's programs and target
    let pipeline = draw::pipeline(&wgpu.device)?;
    let mut show = show::Show::new(gl, (size.width, size.height))?;

    let (mut frame, mut resizes, mut last) = (0, 0, None);
    let (mut gl_had_them, mut gl_signalled) = (false, false);
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
            // Both sides done with the old images; then wgpu lets go of them (its drop callbacks),
            // GL deletes its side, and the chapter destroys the images and frees their memory.
            unsafe { gl.finish() };
            let fresh = share(new)?;
            drop(std::mem::replace(&mut images, fresh)); // as in step 10
            show.resize(gl, (new.width, new.height))?;
            (size, gl_had_them, resizes) = (new, false, resizes + 1);
        }
        // ANCHOR_END: resize
        let is_last = frame + 1 == frames; // a window's last frame too, with --frames

        // 7. wgpu draws, and releases the images to GL
        let wgpu_frame = draw::Frame {
            images: [&images[0], &images[1]],
            gl_had_them,
            read_back: is_last,
            semaphores: raw_semaphores,
            gl_signalled,
        };
        let readbacks = draw::frame(&wgpu.device, &wgpu.queue, &pipeline, wgpu_frame)?;

        // 8. GL acquires them, shows them, draws the line, and releases them to wgpu
        // ANCHOR: gl_turn
        let textures = shared::gl_textures(&images);
        match &semaphores {
            Some([wgpu_done, _]) => shared::gl_semaphore(&gl_context, wgpu_done, textures, false)?,
            // The host path: the CPU waits until wgpu's submission is done.
            None => {
                wgpu.device.poll(wgpu::PollType::wait_indefinitely()).context("wgpu: Device::poll")?;
            }
        }
        show.draw(gl, textures, true);
        // ANCHOR_END: gl_turn
        if is_last {
            let [picture, depth] = [&readbacks[0], &readbacks[1]].map(|r| r.bytes(&wgpu.device));
            let saw = check::WgpuSaw { picture: picture?, depth: depth? };
            last = Some((check::last_frame(gl, &show, textures, &saw, (size.width, size.height)), saw));
        }
        // ANCHOR: gl_release
        match &semaphores {
            Some([_, gl_done]) => shared::gl_semaphore(&gl_context, gl_done, textures, true)?,
            None => unsafe { gl.finish() },
        }
        // ANCHOR_END: gl_release
        (gl_had_them, gl_signalled) = (true, true);
        gl_context.check_error("GL's turn")?;
        if let Some(window) = &window {
            show.blit(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        frame += 1;
    }

    // 9. The checks, made on the last frame while GL held the images
    if let Some(((checks, with_line), saw)) = last {
        for (name, ok) in checks {
            report.check(name, ok);
        }
        let out_dir = args.common.out_dir(CHAPTER);
        output::save_rgba8(report, &out_dir, CHAPTER, (size.width, size.height), &with_line)?;
        output::save_rgba8(
            report,
            &out_dir,
            &format!("{CHAPTER}-wgpu"),
            (size.width, size.height),
            &saw.picture,
        )?;
    }
    report.set("frames", frame);
    if resizes > 0 {
        report.set("resizes", resizes);
    }

    // 10. Clean up: wgpu lets go first, then GL, then what the chapter allocated
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    wgpu.device.poll(wgpu::PollType::wait_indefinitely()).context("wgpu: Device::poll")?;
    drop(show);
    drop(images); // each: wgpu's texture destroyed and polled for, GL's side, the image, its memory
    let (wrapped, released) = (WRAPPED.load(Ordering::SeqCst), RELEASED.load(Ordering::SeqCst));
    let in_use = DESTROYED_IN_USE.load(Ordering::SeqCst); // destroyed before wgpu let go
    drop(semaphores); // GL's side, then Vulkan's: no submission uses them now
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
    common::run_chapter(CHAPTER, SMALLEST, run)
}
