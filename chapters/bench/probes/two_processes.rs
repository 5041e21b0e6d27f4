//! Chapter 14's questions, on its frame (`common::frame::ring`) drawn here as the chapter's
//! renderer draws it:
//!
//! - `one-process`: what the second process costs. The same ring, the same fds, imports and
//!   semaphores, read back with the viewer's own `read_slot`, all in this one process; the
//!   hand-over is timed as the chapter times it, to compare with the chapter's own report.
//! - `gl-stall`: what the driver does with the one wait the chapter's design rules out, GL
//!   waiting on a semaphore that nobody will ever signal (as a renderer killed before its queue
//!   ran would leave it). Measured, not assumed: how GL's fence behind the wait answers, and how
//!   long letting go of the semaphore and the context takes afterwards.

use super::{Probe, Settings};
use anyhow::{Result, ensure};
use ash::vk;
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::clocks::timing::PassTimes;
use common::frame::ring::{self, Ring};
use common::instruments::{output, resources};
use common::interop::handoff::{self, import_semaphore};
use common::interop::{self, exportable::MemoryTerms};
use common::{Report, Requirements, VulkanContext, ms_since};
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long GL's fence is waited for, behind a wait that nothing will satisfy.
const STALL_WAIT: Duration = Duration::from_secs(10);
/// The chapter's default ring.
const SLOTS: u32 = 2;

/// Runs `probe` (`OneProcess` or `GlStall`) at every size of `s`, writing `probe-NAME.md` to `out`.
pub fn run(probe: Probe, s: &Settings, out: &Path, report: &mut Report) -> Result<()> {
    // The chapter's renderer's Vulkan (no ray tracing), and GL on the same device, opened before
    // the fds are counted, as the viewer's is (the driver may keep files of its own for its life).
    let vk = VulkanContext::new(&Requirements {
        extensions: &[ash::khr::external_memory_fd::NAME],
        optional_extensions: &[handoff::SEMAPHORE_EXTENSION],
        ..Default::default()
    })?;
    let gl = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    common::connect(report, &vk, &gl)?;
    let largest = common::largest_size(&vk, &gl);
    for &size in &s.sizes {
        largest.check_flag("--sizes", "bench", size)?;
    }
    report.set("device", &vk.info.name);
    report.set("driver", &vk.info.driver);
    report.set("probe", probe);
    let semaphores = vk.has_extension(handoff::SEMAPHORE_EXTENSION)
        && handoff::vulkan_can_export_semaphores(&vk)
        && gl.semaphores.is_some();
    let table = match probe {
        Probe::GlStall => stall(&vk, gl, semaphores, report)?,
        _ => {
            let table = one_process(&vk, &gl, semaphores, s, out, report)?;
            gl.check_error("the probe")?;
            drop(gl);
            table
        }
    };
    output::create_dir(out)?;
    let name = serde_json::to_value(probe)?.as_str().unwrap_or("probe").to_owned();
    let text = format!("Measured on {} ({}).\n\n{table}", vk.info.name, vk.info.driver);
    output::write_file(&out.join(format!("probe-{name}.md")), &text)?;
    eprintln!("{text}");
    Ok(())
}

/// `--frames` frames at each size, each drawn, then read back in this process's GL, the hand-over
/// timed as the chapter's renderer times it: from the fence having signalled to GL being done
/// with the slot. One slot at a time: with nobody to overlap with, a second would only wait.
fn one_process(
    vk: &VulkanContext,
    gl: &GlContext,
    semaphores: bool,
    s: &Settings,
    out: &Path,
    report: &mut Report,
) -> Result<String> {
    let sync = if semaphores { "semaphores" } else { "host" };
    report.sync = Some(sync);
    let fds_before = resources::open_fd_targets();
    let mut table = String::from(
        "| size | `sync` | frame (median) ms | hand-over (median) ms | hand-over (p95) ms |\n|---|---|---:|---:|---:|\n",
    );
    let (mut rows, mut all_right) = (Vec::new(), true);
    for &size in &s.sizes {
        let (width, height) = (size.width, size.height);
        let ring = Ring::new(vk, SLOTS, vk::Extent2D { width, height })?;
        let frame_written = match semaphores {
            true => (0..SLOTS).map(|_| handoff::exportable_semaphore(vk)).collect::<Result<Vec<_>>>()?,
            false => Vec::new(),
        };
        // The viewer's imports, from fds that never leave the process.
        let memory = MemoryTerms { size: ring.memory_size(), dedicated: true };
        let ring_gl = (0..SLOTS as usize)
            .map(|slot| -> Result<_> {
                let texture = interop::import_texture_2d(
                    gl,
                    memory,
                    ring.memory_fd(slot)?,
                    glow::RGBA8,
                    (width, height),
                )?;
                let written = match semaphores {
                    true => Some(import_semaphore(gl, handoff::semaphore_fd(vk, *frame_written[slot])?)?),
                    false => None,
                };
                Ok((texture, written)) // dropped in that order, before the context
            })
            .collect::<Result<Vec<_>>>()?;
        // ANCHOR: frames
        let (mut times, mut last) = (PassTimes::new(), None);
        for frame in 0..s.frames as u64 {
            let slot = (frame % SLOTS as u64) as usize;
            let started = Instant::now();
            ring.draw(vk, frame, slot, frame_written.get(slot).map(|s| **s))?; // waits for the fence
            let written_ns = interop::wire::monotonic_ns();
            times.add("frame", ms_since(started));
            let (texture, written) = &ring_gl[slot];
            if let Some(written) = written {
                ring::wait_until_written(gl, texture, written);
            }
            let pixels = ring::read_slot(gl, texture, (width, height), STALL_WAIT)?;
            // Where the viewer would send SlotFree: the same moment, on the same clock.
            times.add("handover", interop::wire::monotonic_ns().saturating_sub(written_ns) as f64 / 1e6);
            all_right &= ring::is_picture_of(&pixels, frame, width, height);
            last = Some(pixels);
        }
        // ANCHOR_END: frames
        let summary: std::collections::BTreeMap<_, _> =
            times.summary().into_iter().map(|(pass, median, p95)| (pass, (median, p95))).collect();
        let (frame_ms, (handover_ms, handover_p95)) = (summary["frame"].0, summary["handover"]);
        writeln!(
            table,
            "| {width}x{height} | {sync} | {frame_ms:.3} | {handover_ms:.3} | {handover_p95:.3} |"
        )?;
        let at = serde_json::json!({ "width": width, "height": height, "frames": s.frames, "sync": sync });
        let measured = serde_json::json!({ "frame_ms": frame_ms, "handover_ms": handover_ms, "handover_p95_ms": handover_p95 });
        rows.push(serde_json::json!({ "setting": at, "measured": measured }));
        if let Some(pixels) = &last {
            // The chapter's name: the same picture as the chapter's last frame, and its reference.
            output::save_rgba8(report, out, "14-two-processes", (width, height), pixels)?;
        }
        drop(ring_gl); // each texture and its memory object (which closes its fd), then its semaphore
        drop(frame_written);
        drop(ring); // waits for its last frame, then each image and its memory
    }
    report.check("every_frame_is_the_one_announced", all_right);
    report.check("no_fd_leaked", resources::no_fd_leaked("bench", &fds_before));
    report.set("rows", rows);
    Ok(table)
}

/// A Vulkan semaphore exported and imported into GL, never signalled; GL told to wait for it;
/// then GL's fence waited for up to [`STALL_WAIT`], and each letting go timed.
fn stall(vk: &VulkanContext, gl: GlContext, semaphores: bool, report: &mut Report) -> Result<String> {
    ensure!(
        semaphores,
        "--probe gl-stall needs shared semaphores: VK_KHR_external_semaphore_fd on {} and GL_EXT_semaphore_fd",
        vk.info.name
    );
    let never = handoff::exportable_semaphore(vk)?; // nothing will ever signal it
    let gl_never = import_semaphore(&gl, handoff::semaphore_fd(vk, *never)?)?;
    // GL's queue now waits for a signal that will not come (no textures named: nothing to hand over).
    let wait = gl.semaphores.as_ref().expect("checked above").WaitSemaphoreEXT;
    unsafe { wait(gl_never.0, 0, std::ptr::null(), 0, std::ptr::null(), std::ptr::null()) };
    let started = Instant::now();
    let finished = ring::gl_finished(&gl, STALL_WAIT);
    let waited_ms = started.elapsed().as_secs_f64() * 1e3;
    if let Err(error) = &finished {
        eprintln!("stall probe: {error:#}");
    }
    // Letting go, each timed: a driver that waits for the stalled queue here would hang the
    // process that owns it, however careful its own waits. The last "letting go" line printed
    // names a step that never returned.
    let ms = |started: Instant| (started.elapsed().as_secs_f64() * 1e4).round() / 10.0;
    eprintln!("stall probe: letting go of GL's semaphore");
    let started = Instant::now();
    drop(gl_never);
    let gl_semaphore_ms = ms(started);
    eprintln!("stall probe: letting go of Vulkan's semaphore");
    let started = Instant::now();
    drop(never);
    let vk_semaphore_ms = ms(started);
    eprintln!("stall probe: letting go of the GL context");
    let started = Instant::now();
    drop(gl);
    let gl_context_ms = ms(started);
    let signalled = finished.is_ok();
    eprintln!(
        "stall probe: GL's fence {} within {STALL_WAIT:?}",
        if signalled { "signalled" } else { "did not signal" }
    );
    let measured = serde_json::json!({
        "fence_signalled": signalled,
        "waited_ms": waited_ms,
        "gl_semaphore_deleted_ms": gl_semaphore_ms,
        "vulkan_semaphore_destroyed_ms": vk_semaphore_ms,
        "gl_context_destroyed_ms": gl_context_ms,
    });
    report.set(
        "rows",
        [serde_json::json!({ "setting": { "wait_s": STALL_WAIT.as_secs() }, "measured": measured })],
    );
    Ok(format!(
        "| GL's fence behind the wait | waited ms | GL semaphore deleted ms | Vulkan semaphore destroyed ms | \
         GL context destroyed ms |\n|---|---:|---:|---:|---:|\n| {} | {waited_ms:.0} | {gl_semaphore_ms} | \
         {vk_semaphore_ms} | {gl_context_ms} |\n",
        if signalled { "signalled" } else { "did not signal" }
    ))
}
