//! Chapter 14: two processes.
//!
//! The Vulkan renderer and the GL viewer are separate programs now: the renderer draws into a ring
//! of exported images, hands their fds to the viewer once over a Unix-domain socket, then says
//! "frame k is in slot i" each frame; the viewer reads the slot and answers "slot i is free".
//! Either side may die or lie at any moment; the other notices and carries on (or, for the
//! viewer, stops cleanly).
//!
//! Run: `cargo run --release --bin 14-two-processes` (the renderer starts its own viewer), or by
//! hand in two terminals: `-- --listen` and `-- --connect` (a socket in `$XDG_RUNTIME_DIR`, or the
//! path given); or, to compare, `-- --one-process` (the same hand-over, with GL in the renderer's
//! own process).

mod draw;
mod gauges;
mod one_process;
mod session;
mod slot;
mod stall;
mod viewer;
mod wire;

use anyhow::{Result, bail, ensure};
use ash::vk;
use common::base::cli::{Smallest, number, seconds};
use common::base::commands::{Commands, HostBuffer, image_barrier};
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::clocks::timing::PassTimes;
use common::instruments::{fail, resources};
use common::interop::exportable::{self, Dedicated};
use common::interop::handoff;
use common::{Flags, Report, Requirements, VulkanContext};
use session::{Measured, Outcome, Ring, Session};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

const CHAPTER: &str = "14-two-processes";
/// How long a viewer has to exit once the conversation is over before it is killed.
const GRACE: Duration = Duration::from_secs(2);
const SMALLEST: Smallest = Smallest {
    width: 16,
    height: 16,
    why: "the moving square, a quarter of the shorter side, must have background around it",
    shape: None,
};

/// Chapter 14: a Vulkan renderer and a GL viewer in two processes, sharing a ring of images.
#[derive(clap::Parser)]
struct Args {
    /// Images in the ring, each a frame in flight (2 to 16).
    #[arg(long, default_value_t = 2, value_parser = number::<u32>(2..=wire::MAX_SLOTS))]
    slots: u32,
    /// Wait for a viewer at this socket path instead of starting one (the viewer: --connect)
    /// [default path: $XDG_RUNTIME_DIR/14-two-processes.sock].
    #[arg(long, value_name = "PATH", num_args = 0..=1, conflicts_with = "connect")]
    listen: Option<Option<PathBuf>>,
    /// Be the viewer of the renderer listening at this socket path [default path: --listen's].
    #[arg(long, value_name = "PATH", num_args = 0..=1)]
    connect: Option<Option<PathBuf>>,
    /// Seconds to wait for the other process before giving up on it (0.001 to 86400).
    #[arg(long, value_name = "SECONDS", default_value = "10", value_parser = seconds(0.001..=86400.0))]
    timeout: Duration,
    /// How many viewers that died are replaced before the renderer gives up (0 to 1000000).
    #[arg(long, default_value_t = 3, value_parser = number::<u32>(0..=1_000_000))]
    restarts: u32,
    /// Kill the viewer (SIGKILL) each time it has been sent K frames, to see it replaced (as
    /// long as --restarts allows one more; K from --slots + 1 to 1000000).
    #[arg(long, value_name = "K", value_parser = number::<u32>(1..=1_000_000))]
    kill_viewer_every: Option<u32>,
    /// Ping/Pong round trips to time with each viewer, before its frames (0 to 100000).
    #[arg(long, default_value_t = 20, value_parser = number::<u32>(0..=100_000))]
    pings: u32,
    /// No viewer: import the ring into GL in this same process and read each frame back there,
    /// timing the same hand-over, to compare with two processes.
    #[arg(long, conflicts_with_all = ["listen", "connect", "kill_viewer_every"])]
    one_process: bool,
    /// (The viewer, with --connect) outlive the renderer: wait for the next one at the same path.
    #[arg(long, requires = "connect")]
    reconnect: bool,
    /// (Internal) be the viewer, on this inherited socket (0, 1 and 2 are stdin, stdout, stderr).
    #[arg(long, hide = true, value_parser = number::<i32>(3..=i32::MAX))]
    viewer_fd: Option<i32>,
    /// (Internal) the viewer keeps a copy of the first fd it receives: a leak, to prove that
    /// the leak check sees one.
    #[arg(long, hide = true)]
    keep_a_received_fd: bool,
    /// (Internal, with --one-process) GL waits on a semaphore nobody signals, to see what the
    /// driver does: the wait this chapter's design rules out.
    #[arg(long, hide = true, requires = "one_process")]
    stall_probe: bool,
}

/// The socket's path, for `--listen` or `--connect` given with or without one (None: not given).
fn socket_path(flag: &Option<Option<PathBuf>>) -> Result<Option<PathBuf>> {
    flag.as_ref().map(|path| path.clone().map_or_else(wire::default_path, Ok)).transpose()
}

// ANCHOR: picture
/// Frame `frame`'s picture, which both processes know: a background colour no nearby frame
/// shares, and a white square (x, y, side) that moves one step a frame. A viewer that read a
/// slot too early, or the wrong slot, sees another frame's colour or square.
pub fn picture(frame: u64, width: u32, height: u32) -> ([u8; 4], (u32, u32, u32)) {
    let channel = |step: u64| (20 + frame * step % 200) as u8;
    let background = [channel(37), channel(91), channel(53), 255];
    let side = width.min(height) / 4;
    let x = (frame * 3 % (width - side + 1) as u64) as u32;
    (background, (x, (height - side) / 2, side))
}
// ANCHOR_END: picture

fn render(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let slots = args.slots;
    if let Some(k) = args.kill_viewer_every {
        ensure!(k > slots, "--kill-viewer-every {k}: more than --slots {slots}, or no frame is ever shown");
        ensure!(args.listen.is_none(), "--kill-viewer-every: the renderer kills only a viewer it started");
    }
    // --listen's path, checked before anything is made (its directory must be ours alone).
    let listen_path = socket_path(&args.listen)?;
    let (width, height) = (args.common.size.width, args.common.size.height);
    // The renderer has no window; the viewer it starts opens one where there is a display, and
    // then, as every windowed chapter, runs until it is closed unless --frames says otherwise.
    let windowed = !args.common.headless && common::base::window::display_available() && !args.one_process;
    let frames = match windowed {
        true => Some(args.common.window_frames()).filter(|&n| n > 0).map_or(u64::MAX, u64::from),
        false => args.common.headless_frames() as u64,
    };

    // 1. Vulkan alone: the renderer has no GL
    let vk = VulkanContext::new(&Requirements {
        extensions: &[ash::khr::external_memory_fd::NAME],
        // Shared semaphores where the driver has them (NVIDIA); the host path where not.
        optional_extensions: &[handoff::SEMAPHORE_EXTENSION],
        ..Default::default()
    })?;
    report.vulkan = Some(vk.report());
    let offer_semaphores =
        vk.has_extension(handoff::SEMAPHORE_EXTENSION) && handoff::vulkan_can_export_semaphores(&vk);
    // --one-process: GL in this process too, on the same device, opened before the fds are
    // counted, as the viewer's is (the driver may keep files of its own for the context's life).
    let gl_context = match args.one_process {
        true => Some(GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?),
        false => None,
    };
    if args.stall_probe {
        let gl_context = gl_context.expect("--stall-probe requires --one-process");
        return stall::probe(&vk, gl_context, args.timeout, report);
    }
    let fds_before = resources::open_fd_targets();

    // 2. A ring of exportable images
    // ANCHOR: ring
    let usage = vk::ImageUsageFlags::TRANSFER_DST // Vulkan clears and copies into it
        | vk::ImageUsageFlags::COLOR_ATTACHMENT // a windowed viewer blits from a framebuffer on it
        | vk::ImageUsageFlags::SAMPLED; // GL reads it as a texture (glGetTexImage)
    let extent = vk::Extent2D { width, height };
    let ring = (0..slots)
        .map(|_| -> Result<_> {
            let image = exportable::create_image(&vk, vk::Format::R8G8B8A8_UNORM, usage, extent)?;
            let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
            let local = vk::MemoryPropertyFlags::DEVICE_LOCAL;
            let memory = exportable::allocate(&vk, &requirements, local, Dedicated::Image(*image))?;
            fail::call("vkBindImageMemory (a ring slot)", || unsafe {
                vk.device.bind_image_memory(*image, *memory.memory, 0)
            })?;
            Ok((image, memory)) // dropped in that order: the image, then its memory
        })
        .collect::<Result<Vec<_>>>()?;
    // ANCHOR_END: ring
    let side = picture(0, width, height).1.2;
    let mut square = HostBuffer::new(&vk, side as u64 * side as u64 * 4, vk::BufferUsageFlags::TRANSFER_SRC)?;
    square.bytes_mut().fill(255); // white, opaque
    let commands = Commands::new(&vk)?; // dropped first: it waits for its last submission
    // Every slot starts outside Vulkan, in GENERAL, as it is after each frame's release.
    commands.run_once(&vk, |cb| unsafe {
        let to_general = (vk::ImageLayout::UNDEFINED, vk::ImageLayout::GENERAL);
        let (none, families) = (vk::AccessFlags::NONE, (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL));
        let barriers: Vec<_> = ring
            .iter()
            .map(|(image, _)| image_barrier(**image, to_general, (none, none), families))
            .collect();
        let (top, bottom) = (vk::PipelineStageFlags::TOP_OF_PIPE, vk::PipelineStageFlags::BOTTOM_OF_PIPE);
        vk.device.cmd_pipeline_barrier(cb, top, bottom, vk::DependencyFlags::empty(), &[], &[], &barriers);
    })?;

    // 3. Serve viewers until every frame has been shown
    let timeout = args.timeout;
    let listener = listen_path.as_deref().map(wire::listen).transpose()?;
    let hello = wire::Hello {
        device_uuid: vk.info.device_uuid,
        driver_uuid: vk.info.driver_uuid,
        device: vk.info.name.clone(),
        format: wire::FORMAT_RGBA8,
        width,
        height,
        memory_size: ring[0].1.size,
        slots,
        semaphores: offer_semaphores,
    };
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    let memory_fd = |slot: usize| exportable::export_fd(&fd_loader, *ring[slot].1.memory);
    let (mut next_frame, mut restarts, mut redrawn, mut refused) = (0u64, 0u32, 0u64, 0u64);
    let mut measured =
        Measured { times: PassTimes::new(), viewer_died_at: None, death_to_frame: vec![], sync: "host" };
    let mut sessions = Vec::new(); // the renderer's resources after each viewer
    let summary = loop {
        // ANCHOR: frame_written
        // Per viewer, where Vulkan can share them: one "frame written" semaphore per slot, which
        // Vulkan signals and GL waits on. New for each viewer: one that died may have left a
        // semaphore signalled with no wait to come, and signalling it again would be an error.
        let frame_written = match offer_semaphores {
            true => (0..slots).map(|_| handoff::exportable_semaphore(&vk)).collect::<Result<Vec<_>>>()?,
            false => Vec::new(),
        };
        let semaphore_fd = |slot: usize| handoff::semaphore_fd(&vk, *frame_written[slot]);
        // ANCHOR_END: frame_written
        let draw = |frame: u64, slot: usize, signal: bool| {
            let frame_written = signal.then(|| *frame_written[slot]);
            draw::draw(&vk, &commands, *ring[slot].0, &square, picture(frame, width, height), frame_written)
        };
        let shared = Ring { hello: &hello, memory_fd: &memory_fd, semaphore_fd: &semaphore_fd, draw: &draw };
        if let Some(gl_context) = &gl_context {
            let out_dir = args.common.out_dir(CHAPTER);
            one_process::serve(
                (&vk.info, gl_context),
                &shared,
                frames,
                (timeout, &out_dir),
                &mut measured,
                report,
            )?;
            next_frame = frames;
            break None; // no viewer, no summary
        }
        let (socket, mut child) = match &listener {
            Some(listener) => (session::accept(listener, timeout)?, None),
            None => session::spawn_viewer(args, hello.width, hello.height, windowed)?,
        };
        socket.set_timeout(timeout)?;
        // Killed on purpose only while a replacement is allowed: the run then finishes.
        let kill_every = args.kill_viewer_every.filter(|_| restarts < args.restarts);
        let session = Session { socket: &socket, child: child.as_mut(), kill_every, pings: args.pings };
        let outcome = session.serve(&shared, &mut next_frame, frames, &mut measured, report);
        let outcome = match outcome {
            Ok(outcome) => outcome,
            // A client of our socket that lied, or was not our user: refused, counted, and the
            // next one served. No budget: a liar costs one connection and at most --timeout, and
            // never stops the renderer. (A viewer we started that breaks the protocol is our
            // own bug: an error.)
            Err(error) if listener.is_some() && error.is::<wire::Broken>() => {
                session::refuse(socket, &error);
                refused += 1;
                continue;
            }
            Err(error) => {
                session::end_viewer(socket, child, GRACE);
                return Err(error);
            }
        };
        match outcome {
            Outcome::Done(summary) => {
                let exited = session::end_viewer(socket, child, GRACE);
                report.check("viewer_exited_cleanly", exited != Some(false));
                break Some(summary);
            }
            Outcome::Gone { why, lost } => {
                measured.viewer_died_at = Some(std::time::Instant::now());
                session::end_viewer(socket, child, GRACE);
                sessions.push(gauges::sample(None));
                restarts += 1;
                redrawn += lost;
                eprintln!("renderer: the viewer {why}; {lost} frame(s) in flight will be drawn again");
                if restarts > args.restarts {
                    bail!(
                        "the viewer {why}, and it has been replaced {} times already (--restarts)",
                        args.restarts
                    );
                }
            }
        }
    };
    if let Some(summary) = &summary {
        gauges::merge_summary(report, summary)?;
    }
    report.sync = Some(measured.sync);
    measured.times.record(report);
    if restarts > 0 {
        report.set("death_to_next_frame_ms", gauges::median_max(&measured.death_to_frame));
        report.set("sessions", &sessions);
    }
    report.set("frames", next_frame); // `frames`, or as many as were shown until the window closed
    report.set("slots", slots);
    report.set("restarts", restarts);
    if listener.is_some() {
        report.set("viewers_refused", refused);
    }
    report.set("frames_drawn_again", redrawn);
    let mode = match (args.one_process, &listener) {
        (true, _) => "one process",
        (false, Some(_)) => "listen",
        (false, None) => "one command",
    };
    report.set("mode", mode);

    // 4. Clean up, newest first (the last frame's fence has signalled)
    drop(listener);
    drop(commands);
    drop(square);
    drop(ring); // each image, then its memory
    drop(gl_context); // --one-process: its textures went in `one_process::serve`
    if let Some(path) = &listen_path {
        let _ = std::fs::remove_file(path);
    }
    // Every fd exported went to a viewer, and ours was closed once sent; every socket is closed.
    report.check("no_fd_leaked", gauges::no_fd_leaked("renderer", &fds_before));
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, |args: &Flags<Args>, report: &mut Report| {
        match args.viewer_fd.is_some() || args.connect.is_some() {
            true => viewer::run(args, report),
            false => render(args, report),
        }
    })
}
