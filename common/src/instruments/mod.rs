//! The instruments: what every layer checks, counts and reports with, below everything the
//! chapters teach. The report and its checks, counts of what is alive (objects, GL names, fds),
//! failure injection (`VKGL_FAIL_AT`), the validation layer's messages, and the images and plots
//! a chapter writes. Nothing here names Vulkan's or GL's objects of the tutorial.

pub mod census;
pub mod fail;
pub mod output;
pub mod report;
pub mod resources;
pub mod validation;

/// Writes `line` and a newline to stderr in one write. `eprintln!` writes a line in pieces, and
/// another process printing on the same stderr (chapter 14's viewer) could come between them.
pub fn eprint_whole(line: &str) {
    let _ = std::io::Write::write_all(&mut std::io::stderr(), format!("{line}\n").as_bytes());
}
