//! Chapter 14's viewer: GL in a process of its own. It learns from the renderer's Hello which
//! device to open GL on, imports the ring's fds as textures, and for each "frame k is in slot i"
//! reads the slot back, checks it is frame k's picture, and answers "slot i is free".

use super::{Args, CHAPTER, picture, wire};
use anyhow::{Context as _, Result, bail, ensure};
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::base::output;
use common::base::vulkan::DeviceInfo;
use common::interop::{self, exportable::MemoryTerms};
use common::{Report, open_fd_count, settled_fd_count};
use glow::HasContext;
use std::os::fd::{FromRawFd, OwnedFd};
use std::time::Duration;
use wire::{Message, Received, Socket};

pub fn run(args: &Args, report: &mut Report) -> Result<()> {
    let socket = match (args.viewer_fd, &args.connect) {
        (Some(fd), _) => {
            // Is it open at all? A mistyped --viewer-fd must not become someone else's fd.
            let borrowed = unsafe { std::os::fd::BorrowedFd::borrow_raw(fd) };
            rustix::io::fcntl_getfd(borrowed).with_context(|| format!("--viewer-fd {fd} is not open"))?;
            // SAFETY: the renderer started us with this end of its socket pair, for us alone.
            Socket { fd: unsafe { OwnedFd::from_raw_fd(fd) } }
        }
        (None, Some(path)) => wire::connect(path)?,
        (None, None) => unreachable!("main runs the viewer only with --viewer-fd or --connect"),
    };
    let result = view(args, report, &socket);
    if let Err(error) = &result {
        // The renderer learns why, rather than only that we hung up (which it would survive).
        let _ = socket.send(&Message::Refused { reason: format!("{error:#}") }, &[]);
    }
    result
}

fn view(args: &Args, report: &mut Report, socket: &Socket) -> Result<()> {
    socket.set_timeout(Duration::from_secs_f64(args.timeout))?;
    // 1. Hear the renderer's Hello
    let hello = match socket.recv()? {
        Received::Message(Message::Hello(hello), _) => hello,
        Received::Message(other, _) => bail!("the renderer began with {}, not Hello", other.name()),
        Received::HungUp => bail!("the renderer hung up before saying Hello"),
        Received::TimedOut => bail!("the renderer said nothing for {} s", args.timeout),
    };
    let (width, height) = (hello.width, hello.height);

    // 2. Open GL on the renderer's device, or refuse
    // ANCHOR: same_device
    // The renderer's Vulkan device, as far as GL's choice of device and the UUID check need it.
    let vulkan = DeviceInfo {
        name: hello.device.clone(),
        driver: String::new(),
        api_version: 0,
        device_type: ash::vk::PhysicalDeviceType::OTHER,
        device_uuid: hello.device_uuid,
        driver_uuid: hello.driver_uuid,
    };
    let gl_context = GlContext::headless(&vulkan, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    report.gl = Some(gl_context.report());
    report.uuids_match = Some(common::base::gl::uuids_match(&vulkan, &gl_context));
    // Another device's fd would import as garbage, or crash the driver: refuse, naming both.
    common::base::gl::ensure_same_device(&vulkan, &gl_context)?;
    // ANCHOR_END: same_device
    let largest = unsafe { gl.get_parameter_i32(glow::MAX_TEXTURE_SIZE) }.max(0) as u32;
    ensure!(width <= largest && height <= largest, "{width}x{height}: GL_MAX_TEXTURE_SIZE is {largest} here");
    let welcome = Message::Welcome {
        device_uuid: gl_context.device_uuid,
        driver_uuid: gl_context.driver_uuid,
        renderer: gl_context.renderer.clone(),
    };
    ensure!(socket.send(&welcome, &[])?, "the renderer hung up during the handshake");
    let open_fds_before = open_fd_count()?;

    // 3. Import the ring
    // ANCHOR: import
    // What GL must be told of each slot's memory: its size, and that it is one image's alone.
    let memory = MemoryTerms { size: hello.memory_size, dedicated: true };
    let mut ring = Vec::new();
    for expected in 0..hello.slots {
        let (slot, memory_size, fd) = match socket.recv()? {
            Received::Message(Message::Slot { slot, memory_size }, Some(fd)) => (slot, memory_size, fd),
            Received::Message(other, _) => {
                bail!("expected slot {expected}, the renderer sent {}", other.name())
            }
            Received::HungUp | Received::TimedOut => bail!("the renderer went away while sending the slots"),
        };
        // From here until the import succeeds, the fd is ours: every `?` below closes it.
        ensure!(slot == expected, "the renderer sent slot {slot} where slot {expected} was due");
        let size = hello.memory_size;
        ensure!(memory_size == size, "slot {slot} is {memory_size} bytes; the Hello said {size}");
        let fd = wire::check_memory_fd(fd, memory_size)?;
        // A successful import takes the fd (GL closes it with the memory object); a failed one
        // does not, and `import_texture_2d` closes it.
        let texture = interop::import_texture_2d(&gl_context, memory, fd, glow::RGBA8, (width, height))?;
        let framebuffer = common::base::gl::create(gl, "glCreateFramebuffers", |gl| unsafe {
            gl.create_named_framebuffer()
        })?;
        let attached = Some(*texture.texture);
        unsafe { gl.named_framebuffer_texture(Some(*framebuffer), glow::COLOR_ATTACHMENT0, attached, 0) };
        ring.push((framebuffer, texture)); // dropped in that order
    }
    ensure!(socket.send(&Message::Ready, &[])?, "the renderer hung up after sending the slots");
    // ANCHOR_END: import
    eprintln!("viewer: showing frames ({} slots of {width}x{height})", hello.slots);

    // 4. Show each frame, then free its slot
    // ANCHOR: frames
    let (mut shown, mut all_right, mut last) = (0u64, true, None::<(u64, Vec<u8>)>);
    let gone = loop {
        let (frame, slot) = match socket.recv()? {
            Received::Message(Message::FrameReady { frame, slot }, _) => (frame, slot),
            Received::Message(Message::Bye, _) => break None,
            Received::Message(other, _) => bail!("the renderer sent {} during the frames", other.name()),
            Received::HungUp => break Some("hung up"),
            Received::TimedOut => break Some("fell silent"),
        };
        let (framebuffer, _) =
            ring.get(slot as usize).with_context(|| format!("slot {slot} of {}", hello.slots))?;
        if let Some((previous, _)) = &last {
            ensure!(frame > *previous, "frame {frame} came after frame {previous}");
        }
        // The renderer waited for its fence before saying "ready": Vulkan's writes are done.
        unsafe { gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(**framebuffer)) };
        // glReadPixels returns when the pixels are in our memory: GL is done with the slot.
        // (GL numbers rows from the bottom; flipped back, row 0 is Vulkan's row 0.)
        let pixels = output::flip_rows(&output::read_gl_rgba8(gl, width, height), width, height);
        // Unbound, the slot is held by nothing of GL's state between frames.
        unsafe { gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None) };
        gl_context.check_error("reading a slot")?;
        all_right &= is_picture_of(&pixels, frame, width, height);
        shown += 1;
        last = Some((frame, pixels));
        if !socket.send(&Message::SlotFree { slot }, &[])? {
            break Some("hung up");
        }
    };
    // ANCHOR_END: frames

    // 5. Keep the last complete frame
    if let Some((frame, pixels)) = &last {
        output::save_rgba8(report, &args.common.out_dir(CHAPTER), CHAPTER, (width, height), pixels)?;
        report.set("last_frame", frame);
    }
    if let Some(why) = gone {
        let kept = last.as_ref().map_or("no frame".to_owned(), |(frame, _)| format!("frame {frame}"));
        eprintln!(
            "viewer: the renderer {why}; keeping {kept}, the last one shown, and letting go of the ring"
        );
    }
    report.check("every_frame_is_the_one_announced", all_right);
    report.set("frames_shown", shown);
    report.set("renderer_gone", gone.is_some());

    // 6. Clean up
    drop(ring); // each framebuffer, then its texture and memory object: GL lets go of the memory
    gl_context.check_error("cleaning up")?;
    // Each slot's fd was GL's from its import, and went with its memory object.
    report.check("no_fd_leaked", settled_fd_count(open_fds_before)? == open_fds_before);
    if gone.is_none() {
        let mut summary = serde_json::to_value(&*report)?;
        summary["gl_errors"] = common::base::gl::gl_error_count().into();
        let summary = Message::Summary { json: summary.to_string() };
        ensure!(socket.send(&summary, &[])?, "the renderer hung up before the summary");
    }
    Ok(())
}

/// Is `pixels` (row 0 first, as Vulkan wrote it) frame `frame`'s picture? Probes the corner
/// (background), the square's centre (white) and the pixel left of it (background, if any).
fn is_picture_of(pixels: &[u8], frame: u64, width: u32, height: u32) -> bool {
    let (background, (x, y, side)) = picture(frame, width, height);
    let at = |px: u32, py: u32| &pixels[(py * width + px) as usize * 4..][..4];
    let close = |p: &[u8], q: [u8; 4]| p.iter().zip(q).all(|(&a, b)| a.abs_diff(b) <= 1);
    let left_ok = x == 0 || close(at(x - 1, y + side / 2), background);
    close(at(0, 0), background) && close(at(x + side / 2, y + side / 2), [255; 4]) && left_ok
}

/// Puts the viewer's summary into the renderer's report: its GL, its checks (as `viewer_*`), the
/// picture it kept.
pub fn merge_summary(report: &mut Report, json: &str) -> Result<()> {
    let summary: serde_json::Value =
        serde_json::from_str(json).context("the viewer's summary is not JSON")?;
    let text = |v: &serde_json::Value| v.as_str().unwrap_or_default().to_owned();
    let gl = &summary["gl"];
    report.gl = Some(common::base::report::GlReport {
        renderer: text(&gl["renderer"]),
        version: text(&gl["version"]),
        device_uuid: text(&gl["device_uuid"]),
        driver_uuid: text(&gl["driver_uuid"]),
        extensions: gl["extensions"].as_array().into_iter().flatten().map(text).collect(),
    });
    for (name, ok) in summary["checks"].as_object().into_iter().flatten() {
        report.check(&format!("viewer_{name}"), ok.as_bool() == Some(true));
    }
    report.check("viewer_no_gl_errors", summary["gl_errors"] == 0);
    for image in summary["images"].as_array().into_iter().flatten() {
        let size = |key: &str| image[key].as_u64().unwrap_or(0) as u32;
        let path = std::path::PathBuf::from(text(&image["path"]));
        report.image(&text(&image["name"]), &path, size("width"), size("height"), &text(&image["format"]));
    }
    report.set("frames_shown_by_the_last_viewer", &summary["frames_shown"]);
    Ok(())
}
