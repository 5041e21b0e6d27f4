//! `--stall-probe`: what the driver does with the one wait this chapter's design rules out, GL
//! waiting on a semaphore that nobody will ever signal (as a renderer killed before its queue ran
//! would leave it). Measured, not assumed: how GL's fence behind the wait answers, and how long
//! letting go of the semaphore and the context takes afterwards.

use crate::slot;
use anyhow::{Result, ensure};
use common::base::gl::GlContext;
use common::interop::handoff;
use common::{Report, VulkanContext};
use std::time::{Duration, Instant};

/// The probe, in this process (`--one-process`): a Vulkan semaphore exported and imported into
/// GL, never signalled; GL told to wait for it; then GL's fence waited for up to `timeout`.
pub fn probe(
    vk: &VulkanContext,
    gl_context: GlContext,
    timeout: Duration,
    report: &mut Report,
) -> Result<()> {
    let ext = gl_context.semaphores.as_ref();
    ensure!(
        ext.is_some()
            && vk.has_extension(handoff::SEMAPHORE_EXTENSION)
            && handoff::vulkan_can_export_semaphores(vk),
        "--stall-probe needs shared semaphores: VK_KHR_external_semaphore_fd on {} and GL_EXT_semaphore_fd",
        vk.info.name
    );
    let never = handoff::exportable_semaphore(vk)?; // nothing will ever signal it
    let gl_never = handoff::import_semaphore(&gl_context, handoff::semaphore_fd(vk, *never)?)?;
    // GL's queue now waits for a signal that will not come (no textures named: nothing to hand over).
    let wait = ext.expect("checked above").WaitSemaphoreEXT;
    unsafe { wait(gl_never.0, 0, std::ptr::null(), 0, std::ptr::null(), std::ptr::null()) };
    let started = Instant::now();
    let finished = slot::gl_finished(&gl_context, timeout);
    report.set("stall_fence_signalled", finished.is_ok());
    report.set("stall_waited_ms", started.elapsed().as_secs_f64() * 1e3);
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
    report.set("stall_gl_semaphore_deleted_ms", ms(started));
    eprintln!("stall probe: letting go of Vulkan's semaphore");
    let started = Instant::now();
    drop(never);
    report.set("stall_vulkan_semaphore_destroyed_ms", ms(started));
    eprintln!("stall probe: letting go of the GL context");
    let started = Instant::now();
    drop(gl_context);
    report.set("stall_gl_context_destroyed_ms", ms(started));
    eprintln!(
        "stall probe: GL's fence {} within {timeout:?}",
        if finished.is_ok() { "signalled" } else { "did not signal" }
    );
    Ok(())
}
