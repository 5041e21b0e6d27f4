//! `--one-process`: the same frames and the same hand-over with no second process, to compare
//! against. The renderer imports its own ring into a headless GL context of its own, as the
//! viewer does (the same fds, the same imports, the same semaphores where GL has them), and reads
//! each frame back with the viewer's own `read_slot`. What is left out is all the two processes
//! add: the socket, its messages, the second address space and the scheduler between the two.

use super::{CHAPTER, slot};
use crate::session::{Measured, Ring};
use crate::wire;
use anyhow::Result;
use common::base::gl::GlContext;
use common::base::vulkan::DeviceInfo;
use common::instruments::output;
use common::interop::handoff::import_semaphore;
use common::interop::{self, exportable::MemoryTerms};
use common::{Report, ms_since};
use std::time::{Duration, Instant};

/// Draws `frames` frames into `ring` and reads each back in this process's GL, timing the
/// hand-over as the two-process run does: from the renderer's fence having signalled to GL
/// being done with the slot. One slot at a time: with nobody to overlap with, a second slot
/// would only wait.
pub fn serve(
    (vulkan, gl_context): (&DeviceInfo, &GlContext),
    ring: &Ring,
    frames: u64,
    (timeout, out_dir): (Duration, &std::path::Path),
    measured: &mut Measured,
    report: &mut Report,
) -> Result<()> {
    let hello = ring.hello;
    let (width, height) = (hello.width, hello.height);
    // GL on the renderer's own device (opened by the caller as the viewer opens it from the
    // Hello, with `GlContext::headless`), and the same check.
    report.gl = Some(gl_context.report());
    report.uuids_match = Some(common::base::gl::uuids_match(vulkan, gl_context));
    common::base::gl::ensure_same_device(vulkan, gl_context)?;
    let semaphores = hello.semaphores && gl_context.semaphores.is_some();
    measured.sync = if semaphores { "semaphores" } else { "host" };

    // The viewer's imports, from fds that never leave the process.
    let memory = MemoryTerms { size: hello.memory_size, dedicated: true };
    let ring_gl = (0..hello.slots as usize)
        .map(|slot| -> Result<_> {
            let fd = (ring.memory_fd)(slot)?;
            let texture = interop::import_texture_2d(gl_context, memory, fd, glow::RGBA8, (width, height))?;
            let frame_written = match semaphores {
                true => Some(import_semaphore(gl_context, (ring.semaphore_fd)(slot)?)?),
                false => None,
            };
            Ok((texture, frame_written)) // dropped in that order, before the context
        })
        .collect::<Result<Vec<_>>>()?;

    // ANCHOR: frames
    let (mut all_right, mut last) = (true, None);
    for frame in 0..frames {
        let slot = (frame % hello.slots as u64) as usize;
        let started = Instant::now();
        (ring.draw)(frame, slot, semaphores)?; // waits for the fence
        let written_ns = wire::monotonic_ns();
        measured.times.add("frame", ms_since(started));
        let (texture, frame_written) = &ring_gl[slot];
        if let Some(frame_written) = frame_written {
            slot::wait_until_written(gl_context, texture, frame_written);
        }
        let pixels = slot::read_slot(gl_context, texture, (width, height), timeout)?;
        // Where the viewer would send SlotFree: the same moment, on the same clock.
        measured.times.add("handover", wire::monotonic_ns().saturating_sub(written_ns) as f64 / 1e6);
        all_right &= slot::is_picture_of(&pixels, frame, width, height);
        last = Some((frame, pixels));
    }
    // ANCHOR_END: frames
    report.check("every_frame_is_the_one_announced", all_right);
    if let Some((frame, pixels)) = &last {
        output::save_rgba8(report, out_dir, CHAPTER, (width, height), pixels)?;
        report.set("last_frame", frame);
    }
    drop(ring_gl); // each texture and its memory object (which closes its fd), then its semaphore
    gl_context.check_error("cleaning up")?;
    Ok(())
}
