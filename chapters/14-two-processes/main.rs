//! Chapter 14: two processes.
//!
//! The Vulkan renderer and the GL viewer are separate programs now: the renderer draws into a ring
//! of exported images, hands their fds to the viewer once over a Unix-domain socket, then says
//! "frame k is in slot i" each frame; the viewer reads the slot and answers "slot i is free".
//! Either side may die or lie at any moment; the other notices and carries on (or, for the
//! viewer, stops cleanly). The ring and its picture are `common::frame::ring`, the messages
//! `common::interop::wire`; `bench --probe one-process` times the same hand-over in one process.
//!
//! Run: `cargo run --release --bin 14-two-processes` (the renderer starts its own viewer), or by
//! hand in two terminals: `-- --listen` and `-- --connect` (a socket in `$XDG_RUNTIME_DIR`, or the
//! path given).

mod session;
mod viewer;

use anyhow::{Result, bail, ensure};
use common::base::cli::{Smallest, number, seconds};
use common::clocks::timing::{PassTimes, median_max};
use common::frame::ring::Ring;
use common::instruments::{census, resources};
use common::interop::{handoff, wire};
use common::{Flags, Report, Requirements, VulkanContext};
use session::{Measured, Outcome, Session, Shared};
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
    /// (The viewer, with --connect) outlive the renderer: wait for the next one at the same path.
    #[arg(long, requires = "connect")]
    reconnect: bool,
    /// (Internal) be the viewer, on this inherited socket (0, 1 and 2 are stdin, stdout, stderr).
    #[arg(long, hide = true, value_parser = number::<i32>(3..=i32::MAX))]
    viewer_fd: Option<i32>,
}

/// The socket's path, for `--listen` or `--connect` given with or without one (None: not given).
fn socket_path(flag: &Option<Option<PathBuf>>) -> Result<Option<PathBuf>> {
    flag.as_ref().map(|path| path.clone().map_or_else(wire::default_path, Ok)).transpose()
}

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
    let windowed = !args.common.headless && common::base::window::display_available();
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
    let fds_before = resources::open_fd_targets();

    // 2. A ring of exportable images
    let ring = Ring::new(&vk, slots, ash::vk::Extent2D { width, height })?;

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
        memory_size: ring.memory_size(),
        slots,
        semaphores: offer_semaphores,
    };
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
        // ANCHOR_END: frame_written
        let shared = Shared { vk: &vk, hello: &hello, ring: &ring, frame_written: &frame_written };
        let (socket, mut child) = match &listener {
            Some(listener) => {
                eprintln!("renderer: waiting up to {timeout:?} for a viewer (--connect)");
                (wire::accept(listener, timeout)?, None)
            }
            None => session::spawn_viewer((width, height), windowed, timeout, &args.common.out_dir(CHAPTER))?,
        };
        socket.set_timeout(timeout)?;
        // Killed on purpose only while a replacement is allowed: the run then finishes.
        let kill_every = args.kill_viewer_every.filter(|_| restarts < args.restarts);
        let session = Session { socket: &socket, child: child.as_mut(), kill_every, pings: args.pings };
        let outcome = match session.serve(&shared, &mut next_frame, frames, &mut measured, report) {
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
                break summary;
            }
            Outcome::Gone { why, lost } => {
                measured.viewer_died_at = Some(std::time::Instant::now());
                session::end_viewer(socket, child, GRACE);
                sessions.push(census::sample(None));
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

    // 4. The viewer's report into ours, then our own counts
    report.merge("viewer", &summary);
    report.set("frames_shown_by_the_last_viewer", &summary["frames_shown"]);
    report.set("window", summary["window"] == true); // the viewer's: the renderer has none
    if let Some(sessions) = summary.get("sessions") {
        report.set("viewer_sessions", sessions);
    }
    report.sync = Some(measured.sync);
    measured.times.record(report);
    if restarts > 0 {
        report.set("death_to_next_frame_ms", median_max(&measured.death_to_frame));
        report.set("sessions", &sessions);
    }
    report.set("frames", next_frame); // `frames`, or as many as were shown until the window closed
    report.set("slots", slots);
    report.set("restarts", restarts);
    if listener.is_some() {
        report.set("viewers_refused", refused);
    }
    report.set("frames_drawn_again", redrawn);
    report.set("mode", if listener.is_some() { "listen" } else { "one command" });

    // 5. Clean up, newest first (the last frame's fence has signalled)
    drop(listener);
    drop(ring); // its commands, the square, then each image and its memory
    if let Some(path) = &listen_path {
        let _ = std::fs::remove_file(path);
    }
    // Every fd exported went to a viewer, and ours was closed once sent; every socket is closed.
    report.check("no_fd_leaked", resources::no_fd_leaked("renderer", &fds_before));
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, |args: &Flags<Args>, report: &mut Report| {
        let renderer = match (args.viewer_fd, socket_path(&args.connect)?) {
            (Some(fd), _) => viewer::Renderer::Inherited(fd),
            (None, Some(path)) => viewer::Renderer::At(path),
            (None, None) => return render(args, report),
        };
        let settings = viewer::Settings {
            chapter: CHAPTER,
            renderer,
            timeout: args.timeout,
            reconnect: args.reconnect,
            headless: args.common.headless,
            out_dir: args.common.out_dir(CHAPTER),
        };
        report.chapter = format!("{CHAPTER} viewer"); // its summary line, beside the renderer's
        viewer::run(&settings, report)
    })
}
