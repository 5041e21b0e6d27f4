//! Chapter 15 (wgpu and GL), which is a package of its own so that the other chapters do not
//! build wgpu: its tests are that package's (only they can name its binary), with the harness,
//! snapshots and reference images every chapter's tests use.

#[path = "../harness/mod.rs"]
mod harness;

use harness::{DEFAULT_TOLERANCE, assert_images_match, assert_report_snapshot, run_chapter};

const BIN: &str = env!("CARGO_BIN_EXE_15-wgpu");

#[test]
fn ch15_wgpu() {
    let run = run_chapter(BIN, &["--size", "160x120", "--frames", "2"], &[]);
    let report = run.succeeded();
    // lavapipe and llvmpipe share memory but not semaphores: the host path, and it says so.
    assert_eq!(report["sync"], "host");
    assert!(run.stderr.contains("sync: host"), "{}", run.stderr);
    assert_eq!(report["uuids_match"], true);
    let extensions = report["vulkan"]["extensions"].as_array().unwrap();
    assert!(extensions.iter().any(|e| e == "VK_KHR_external_memory_fd"), "{extensions:?}");
    assert_report_snapshot("15-wgpu", report);
    assert_images_match(report, DEFAULT_TOLERANCE);
}

/// Every shared image made anew three times: wgpu lets go of each (its drop callback), and
/// nothing is left, in fds or in counted resources.
#[test]
fn ch15_resizes_every_shared_image() {
    let run = run_chapter(BIN, &["--size", "64x48", "--frames", "7", "--resize-every", "2"], &[]);
    let report = run.succeeded();
    assert_eq!(report["resizes"], 3);
    assert_eq!(report["wgpu_released"], "16 of 16 images");
    assert_eq!(report["checks"]["nothing_grows_across_resizes"], true);
}

/// The soak, as chapter 08's: 1,000 resizes at small sizes (seconds), every one making the four
/// shared images anew, and nothing alive at the end that was not alive after the first.
#[test]
fn ch15_soak_1000_resizes() {
    let args = ["--size", "32x24", "--frames", "1001", "--resize-every", "1"];
    let run = run_chapter(BIN, &args, &[]);
    let report = run.succeeded();
    assert_eq!(report["resizes"], 1000);
    assert_eq!(report["checks"]["nothing_grows_across_resizes"], true);
    assert_eq!(report["wgpu_released"], "4004 of 4004 images");
}

#[test]
fn ch15_missing_memory_extension_is_named() {
    let hide = [("VKGL_HIDE_EXTENSIONS", "VK_KHR_external_memory_fd")];
    let run = run_chapter(BIN, &[], &hide);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("lacks VK_KHR_external_memory_fd"), "{}", run.stderr);
    assert!(run.stderr.contains("lavapipe"), "the fix is named: {}", run.stderr);
    assert!(!run.stderr.contains("panicked"), "{}", run.stderr);
}

/// Every numeric flag chapter 15 takes, its own and those every chapter shares, offered what no
/// flag means, as `tests/errors.rs` offers every other program's (`harness::flags`).
#[test]
fn ch15_every_numeric_flag_refuses_what_it_cannot_mean() {
    let table = harness::flags::numeric_flags_refuse_what_they_cannot_mean(&[BIN]);
    insta::with_settings!({
        snapshot_path => "../snapshots/flags",
        prepend_module_to_snapshot => false,
        omit_expression => true,
    }, {
        insta::assert_snapshot!("numeric-flags-15", table);
    });
}

/// Chapter 15 at every size `tests/sizes.rs` walks the other chapters through: tiny, odd, one
/// past the largest (refused naming wgpu's limit), and the largest side (`harness::sizes`).
#[test]
fn sizes_15() {
    harness::sizes::walk_sizes("15-wgpu", BIN, &["--frames", "2"], "max_texture_dimension_2d 16384");
}

/// Each fallible step, failed the first and the last time a run reaches it: exit 2 naming the
/// step, no panic, no validation message, nothing left alive, no fd left open beyond those a
/// run that fails nothing leaves (the driver's).
#[test]
fn ch15_every_fallible_step_fails_cleanly() {
    harness::every_fallible_step_fails_cleanly(BIN, &["--size", "32x24", "--frames", "3"], None);
}

#[test]
fn ch15_shows_its_picture_in_a_window_under_xvfb() {
    let Some(xvfb) = harness::Xvfb::start("ch15_shows_its_picture_in_a_window_under_xvfb") else { return };
    let args = ["--size", "160x120", "--frames", "3"];
    let run = harness::run_chapter_with(BIN, &args, &[("DISPLAY", &xvfb.display)]);
    drop(xvfb);
    let report = run.succeeded();
    assert_eq!(report["window"], true, "{}", run.stderr);
    assert_eq!(report["frames"], 3);
    // What the window showed is the outline wgpu wrote, read back from its back buffer.
    assert_eq!(report["checks"]["the_window_shows_the_outline"], true, "{}", run.stderr);
}

/// A window smaller than the pictures (at least 16x16) shows them scaled: the check that it shows
/// the outline pixel for pixel says it was not judged, and why (headless, 8x8 is refused).
#[test]
fn ch15_tiny_window_reports_what_it_cannot_judge() {
    let Some(xvfb) = harness::Xvfb::start("ch15_tiny_window_reports_what_it_cannot_judge") else { return };
    let args = ["--size", "8x8", "--frames", "2"];
    let run = harness::run_chapter_with(BIN, &args, &[("DISPLAY", &xvfb.display)]);
    drop(xvfb);
    let report = run.succeeded();
    assert_eq!(report["window"], true, "{}", run.stderr);
    let why = report["not_judged"]["the_window_shows_the_outline"].as_str().unwrap_or_default();
    assert!(why.contains("8x8 window shows the 16x16 picture"), "{why}");
    let headless = run_chapter(BIN, &["--headless", "--size", "8x8"], &[]);
    assert_eq!(headless.output.status.code(), Some(2), "{}", headless.stderr);
}
