//! Chapter 14's renderer side of the conversation: starting (or accepting) a viewer, the
//! handshake, and the frames, one "frame k is in slot i" and one "slot i is free" at a time.

use anyhow::{Context as _, Result, bail, ensure};
use ash::vk;
use common::base::child::OwnedChild;
use common::base::owned::Owned;
use common::base::vulkan::DeviceInfo;
use common::clocks::timing::PassTimes;
use common::frame::ring::Ring;
use common::instruments::fail;
use common::interop::handoff;
use common::interop::wire::{self, Broken, Message, Received, Socket};
use common::{Report, VulkanContext, ms_since};
use std::collections::VecDeque;
use std::os::fd::{AsFd, AsRawFd};
use std::path::Path;
use std::time::{Duration, Instant};

/// How a viewer's session ended, if not with an error.
pub enum Outcome {
    /// Every frame shown; the viewer's summary (a JSON object).
    Done(serde_json::Value),
    /// The viewer hung up or fell silent; `lost` frames were sent and not shown.
    Gone { why: &'static str, lost: u64 },
}

/// One viewer, from the handshake to its summary.
pub struct Session<'a> {
    pub socket: &'a Socket,
    pub child: Option<&'a mut OwnedChild>,
    pub kill_every: Option<u32>,
    /// Ping/Pong round trips to time once the ring is shared.
    pub pings: u32,
}

/// What the renderer shares with a viewer, and what draws into it.
pub struct Shared<'a> {
    pub vk: &'a VulkanContext,
    pub hello: &'a wire::Hello,
    pub ring: &'a Ring,
    /// Each slot's "frame written" semaphore, for this viewer (empty: the host path).
    pub frame_written: &'a [Owned<vk::Semaphore>],
}

/// What the renderer measures across viewers, for its report.
pub struct Measured {
    /// `frame`, `handover` and `round_trip` (ms).
    pub times: PassTimes,
    /// When the renderer noticed its last viewer's death, until the next one shows a frame.
    pub viewer_died_at: Option<Instant>,
    /// From each death noticed to the next frame shown (ms).
    pub death_to_frame: Vec<f64>,
    /// What the last handshake chose: "semaphores" or "host".
    pub sync: &'static str,
}

impl Session<'_> {
    pub fn serve(
        mut self,
        shared: &Shared,
        next_frame: &mut u64,
        frames: u64,
        measured: &mut Measured,
        report: &mut Report,
    ) -> Result<Outcome> {
        let hello = shared.hello;
        // ANCHOR: handshake
        // Only this user's processes are handed our memory: mode 0600 keeps others from
        // connecting to our socket, and the kernel's word on who connected holds where it cannot.
        self.socket.ensure_same_user()?;
        // Hello: who we are and what we share. The viewer checks GL runs on our device.
        if !self.socket.send(&Message::Hello(hello.clone()), &[])? {
            return self.left_early("hung up before the handshake");
        }
        let (device_uuid, driver_uuid, renderer, semaphores) = match self.recv()? {
            Some(Message::Welcome { device_uuid, driver_uuid, renderer, semaphores }) => {
                (device_uuid, driver_uuid, renderer, semaphores)
            }
            Some(other) => bail!(Broken(format!("the viewer answered Hello with {}", other.name()))),
            None => return self.left_early("hung up or fell silent during the handshake"),
        };
        // The viewer's GL must run on our device: our memory's fds mean something to our driver only.
        let same = (device_uuid, driver_uuid) == (hello.device_uuid, hello.driver_uuid);
        report.uuids_match = Some(same);
        let viewers = DeviceInfo { name: renderer, device_uuid, driver_uuid, ..hello.device() }.identity();
        let ours = hello.device().identity();
        ensure!(same, Broken(format!("the viewer's GL ({viewers}) is not our Vulkan ({ours})")));
        // Semaphores only where both sides have them: the viewer accepts only what we offered.
        ensure!(
            !semaphores || hello.semaphores,
            Broken("the viewer accepted semaphores that were not offered".into())
        );
        measured.sync = if semaphores { "semaphores" } else { "host" };
        // The fds, one message per slot (and one per slot's semaphore). Each is ours until
        // sendmsg returns; then the kernel has given the viewer its own, and ours is closed.
        for slot in 0..hello.slots {
            let fd = shared.ring.memory_fd(slot as usize)?;
            let slot_message = Message::Slot { slot, memory_size: hello.memory_size };
            let mut sent = self.socket.send(&slot_message, &[fd.as_fd()])?;
            drop(fd); // sent or not, ours is closed: the viewer has its own, or is gone
            if sent && semaphores {
                let fd = handoff::semaphore_fd(shared.vk, *shared.frame_written[slot as usize])?;
                sent = self.socket.send(&Message::SlotSemaphore { slot }, &[fd.as_fd()])?;
            }
            if !sent {
                return self.left_early("hung up while the slots were sent");
            }
        }
        match self.recv()? {
            Some(Message::Ready) => {}
            Some(other) => bail!(Broken(format!("the viewer answered the slots with {}", other.name()))),
            None => return self.left_early("hung up or fell silent while importing the slots"),
        }
        // ANCHOR_END: handshake
        // A round trip, Ping to Pong, timed: what one message each way costs.
        for n in 0..self.pings as u64 {
            let started = Instant::now();
            if !self.socket.send(&Message::Ping { n }, &[])? {
                return self.hung_up("hung up", 0);
            }
            match self.recv()? {
                Some(Message::Pong { n: m }) if m == n => measured.times.add("round_trip", ms_since(started)),
                Some(other) => bail!(Broken(format!("the viewer answered Ping {n} with {}", other.name()))),
                None => return Ok(Outcome::Gone { why: "hung up", lost: 0 }),
            }
        }
        // Sent and not yet free, oldest first: (frame, slot, when its fence had signalled).
        let mut in_flight = VecDeque::new();
        let shown = self.frames(shared, semaphores, (next_frame, frames), &mut in_flight, measured);
        // However the viewer went, refused included, the frames it did not free are drawn again.
        *next_frame = in_flight.front().map_or(*next_frame, |&(frame, _, _)| frame);
        if let Some(gone) = shown? {
            return Ok(gone);
        }
        if !self.socket.send(&Message::Bye, &[])? {
            while self.recv()?.is_some() {} // its refusal, if it left one, is the error
            bail!(Broken("the viewer hung up after the last frame, before its summary".into()));
        }
        match self.recv()? {
            // Read into the report: it must be a JSON object, as a viewer of ours sends.
            Some(Message::Summary { json }) => match serde_json::from_str::<serde_json::Value>(&json) {
                Ok(summary) if summary.is_object() => Ok(Outcome::Done(summary)),
                _ => bail!(Broken("the viewer's summary is not a JSON object".into())),
            },
            Some(other) => bail!(Broken(format!("the viewer answered Bye with {}", other.name()))),
            None => bail!(Broken("the viewer hung up before its summary".into())),
        }
    }

    /// Frames until `frames` have been shown (`None`), or the viewer is gone. `in_flight`: those
    /// sent and not yet freed, which are drawn again for the next viewer, however this one goes.
    fn frames(
        &mut self,
        shared: &Shared,
        semaphores: bool,
        (next_frame, frames): (&mut u64, u64),
        in_flight: &mut VecDeque<(u64, u32, u64)>,
        measured: &mut Measured,
    ) -> Result<Option<Outcome>> {
        let slots = shared.hello.slots;
        // ANCHOR: frames
        let mut sent = 0u32;
        while *next_frame < frames || !in_flight.is_empty() {
            let slot = (*next_frame % slots as u64) as u32;
            // The slot is the viewer's until it says it is free: wait for that, on the CPU, with a
            // timeout. Never on a GPU semaphore: a dead viewer would never signal it.
            let must_wait = *next_frame == frames || in_flight.iter().any(|&(_, s, _)| s == slot);
            if must_wait {
                let lost = in_flight.len() as u64;
                match self.recv()? {
                    Some(Message::SlotFree { slot: freed, sent_ns }) => {
                        let Some(&(_, oldest, written_ns)) = in_flight.front() else {
                            bail!(Broken(format!("the viewer freed slot {freed} with none in flight")));
                        };
                        ensure!(
                            oldest == freed,
                            Broken(format!(
                                "the viewer freed slot {freed}, not the oldest sent, slot {oldest}"
                            ))
                        );
                        in_flight.pop_front();
                        // From our fence to the viewer's "free": the whole hand-over, one clock.
                        measured.times.add("handover", sent_ns.saturating_sub(written_ns) as f64 / 1e6);
                        if let Some(died) = measured.viewer_died_at.take() {
                            measured.death_to_frame.push(ms_since(died)); // a new viewer showed one
                        }
                    }
                    Some(Message::Closed) => {
                        // Its window was closed: the frames in flight are not shown, nor drawn again.
                        *next_frame = in_flight.front().map_or(*next_frame, |&(frame, _, _)| frame);
                        in_flight.clear();
                        eprintln!("renderer: the viewer's window was closed; {} frame(s) shown", *next_frame);
                        return Ok(None);
                    }
                    Some(other) => {
                        bail!(Broken(format!("the viewer sent {} during the frames", other.name())))
                    }
                    // Everything in flight is lost: drawn again for the next viewer.
                    None => return Ok(Some(Outcome::Gone { why: "hung up or fell silent", lost })),
                }
                continue;
            }
            let started = Instant::now();
            // Either way, "frame ready" goes only once the fence says Vulkan is done. On the host
            // path the message is the synchronisation. With semaphores, the slot's semaphore is
            // signalled by then too: GL's wait on it is satisfied, and cannot be left hanging by
            // our death (a signal submitted, then cut short, would leave it waiting for ever).
            let frame_written = semaphores.then(|| *shared.frame_written[slot as usize]);
            shared.ring.draw(shared.vk, *next_frame, slot as usize, frame_written)?;
            let written_ns = wire::monotonic_ns();
            let ready = Message::FrameReady { frame: *next_frame, slot };
            if !self.socket.send(&ready, &[])? {
                return self.hung_up("hung up", in_flight.len() as u64).map(Some);
            }
            measured.times.add("frame", ms_since(started));
            in_flight.push_back((*next_frame, slot, written_ns));
            *next_frame += 1;
            sent += 1;
            if let (Some(k), Some(child)) = (self.kill_every, self.child.as_deref_mut()) {
                if sent % k == 0 && *next_frame < frames {
                    eprintln!("renderer: killing the viewer (pid {}) after {sent} frames", child.id());
                    child.kill().context("kill -KILL the viewer")?;
                }
            }
        }
        // ANCHOR_END: frames
        Ok(None)
    }

    /// The viewer hung up while we were sending: if it said why first (a refusal waiting in
    /// the socket), that is an error; otherwise it is gone, with `lost` frames.
    fn hung_up(&mut self, why: &'static str, lost: u64) -> Result<Outcome> {
        while self.recv()?.is_some() {} // a refusal bails; anything else is moot now
        Ok(Outcome::Gone { why, lost })
    }

    /// The viewer left before it was ready for frames. One we started died: it is replaced. A
    /// client that connected to our socket and never finished the handshake is refused, as one
    /// that breaks the protocol is: hanging up and falling silent are ways of lying too.
    fn left_early(&mut self, why: &'static str) -> Result<Outcome> {
        ensure!(self.child.is_some(), Broken(format!("the viewer {why}")));
        self.hung_up(why, 0)
    }

    /// The viewer's next message; `None` if it hung up or said nothing for the timeout. A
    /// refusal is the viewer's error, named.
    fn recv(&mut self) -> Result<Option<Message>> {
        match self.socket.recv()? {
            Received::Message(Message::Refused { reason }, _) => {
                bail!(Broken(format!("the viewer refused: {reason}")))
            }
            Received::Message(message, fd) => {
                ensure!(fd.is_none(), Broken(format!("the viewer sent an fd with {}", message.name())));
                Ok(Some(message))
            }
            Received::HungUp | Received::TimedOut => Ok(None),
        }
    }
}

// ANCHOR: spawn
/// Starts this same program as the viewer, on one end of a socket pair: `--viewer-fd N` names
/// the end it inherits. Our copy of that end is closed once it has started, so that its death is
/// our hang-up (a socket reads as hung up only when every copy of the other end is closed).
pub fn spawn_viewer(
    (width, height): (u32, u32),
    windowed: bool,
    timeout: Duration,
    out_dir: &Path,
) -> Result<(Socket, Option<OwnedChild>)> {
    let (ours, theirs) = wire::socketpair()?;
    let exe = std::env::current_exe().context("finding this program, to start the viewer")?;
    let mut command = std::process::Command::new(exe);
    let fd = theirs.fd.as_raw_fd();
    let (size, timeout) = (format!("{width}x{height}"), timeout.as_secs_f64().to_string());
    command.args(["--viewer-fd", &fd.to_string(), "--size", &size, "--timeout", &timeout]);
    if !windowed {
        command.arg("--headless"); // and in a window, it shows each frame as it arrives
    }
    command.arg("--out").arg(out_dir);
    command.stdout(std::process::Stdio::null()); // --json's one document is the renderer's
    // Failure injection is the renderer's; the viewer's comes from VKGL_VIEWER_FAIL_AT.
    command.env_remove("VKGL_FAIL_AT");
    if let Some(at) = std::env::var_os("VKGL_VIEWER_FAIL_AT") {
        command.env("VKGL_FAIL_AT", at);
    }
    // SAFETY: between fork and exec only fcntl runs, which is async-signal-safe. It clears
    // FD_CLOEXEC on the viewer's end, in the child only, so that exec keeps it open.
    unsafe {
        use std::os::unix::process::CommandExt as _;
        command.pre_exec(move || {
            let end = std::os::fd::BorrowedFd::borrow_raw(fd);
            rustix::io::fcntl_setfd(end, rustix::io::FdFlags::empty()).map_err(Into::into)
        });
    }
    // Owned from here: on any way out, ours or the caller's, it is killed and reaped.
    let child = OwnedChild::from(fail::call("starting the viewer process", || command.spawn())?);
    // One write, whole: the viewer is printing on the same stderr already.
    common::instruments::eprint_whole(&format!("renderer: started the viewer (pid {})", child.id()));
    drop(theirs);
    Ok((ours, Some(child)))
}
// ANCHOR_END: spawn

/// Closes our end of the socket, then reaps the viewer we started (None: we started none): a
/// viewer that hung up or saw us hang up exits by itself, within `grace`; one that does not is
/// hung, and is killed. Whether it exited with 0.
pub fn end_viewer(socket: Socket, child: Option<OwnedChild>, grace: Duration) -> Option<bool> {
    drop(socket);
    child.map(|child| child.end(grace))
}

/// Turns away a client of our socket (`--listen`) that broke the protocol: it is told why,
/// if its end still takes a message, and its connection closed, with whatever it sent.
pub fn refuse(socket: Socket, why: &anyhow::Error) {
    let _ = socket.send(&Message::Refused { reason: format!("{why:#}") }, &[]);
    eprintln!("renderer: refused a viewer: {why:#}");
}
