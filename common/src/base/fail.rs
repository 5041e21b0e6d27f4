//! Injected failures, to prove the error paths clean up: `VKGL_FAIL_AT=<point>` makes the named
//! step fail as if the driver had refused it. The points sit after the contexts and shared
//! resources exist, where a leak would show: the validation layer's "not destroyed" messages at
//! device destruction, or a file descriptor still open at exit (`run_chapter` lists them in this
//! mode). `tests/errors.rs` runs chapters with each point.

use anyhow::{Result, bail};

/// The named points, in the order a chapter reaches them.
pub const POINTS: [(&str, &str); 6] = [
    ("none", "nothing fails; the fds at exit are listed all the same: the baseline for the others"),
    ("map", "mapping an exported buffer's memory (exportable::ExportedBuffer::new)"),
    ("import", "GL's import of an exported fd (interop::import_memory)"),
    ("texture", "creating the GL texture after a successful import (interop::import_texture_2d)"),
    ("submit", "submitting a frame's Vulkan work (commands::Commands::submit)"),
    ("gl_acquire", "GL taking the images back after Vulkan's work (handoff::Handoff::gl_acquire)"),
];

/// The point `VKGL_FAIL_AT` names, if any (read once).
pub fn armed() -> Option<&'static str> {
    static ARMED: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    ARMED.get_or_init(|| std::env::var("VKGL_FAIL_AT").ok()).as_deref()
}

/// Fails when `VKGL_FAIL_AT` names `point`; otherwise does nothing.
pub fn at(point: &str) -> Result<()> {
    debug_assert!(POINTS.iter().any(|(name, _)| *name == point), "unknown fail point {point}");
    if armed() == Some(point) {
        let step = POINTS.iter().find(|(name, _)| *name == point).map_or("", |(_, step)| *step);
        bail!("injected failure at {point}: {step} (VKGL_FAIL_AT={point})");
    }
    Ok(())
}

/// Checks `VKGL_FAIL_AT` names a known point: a typo would otherwise test nothing.
pub fn check_armed() -> Result<()> {
    match armed() {
        Some(point) if !POINTS.iter().any(|(name, _)| *name == point) => {
            let known: Vec<_> = POINTS.iter().map(|(name, _)| *name).collect();
            bail!("VKGL_FAIL_AT={point} names no fail point; known: {}", known.join(", "))
        }
        _ => Ok(()),
    }
}

/// The open file descriptors and what each points at (`/proc/self/fd`), sorted.
pub fn open_fds() -> Vec<String> {
    let mut fds: Vec<String> = std::fs::read_dir("/proc/self/fd")
        .map(|dir| {
            dir.flatten()
                .map(|entry| {
                    let target = std::fs::read_link(entry.path()).unwrap_or_default();
                    format!("{} -> {}", entry.file_name().to_string_lossy(), target.display())
                })
                .collect()
        })
        .unwrap_or_default();
    fds.sort();
    fds
}
