//! The interop layer: memory Vulkan exports and GL imports, and how the two APIs take turns on
//! it (taught in chapters 01-04), plus CUDA's import of the same memory (chapter 11).

pub mod cuda;
pub mod exportable;
pub mod handoff;
mod import;
pub mod wire;

pub use import::*;

/// What a chapter reports of its hand-off (chapter 03's `Handoff`): the path it took (the
/// report's `sync`: semaphores or the host), and whether, on the host path, every hand-over named
/// the layout its image was really in.
pub fn report_handoff(report: &mut crate::instruments::report::Report, handoff: &handoff::Handoff) {
    report.sync = Some(handoff.name());
    report.check("hand_over_layouts_agree", handoff.layouts_agreed());
}
