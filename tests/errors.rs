//! Error paths: chapters made to fail half-way, after both contexts and the shared resources
//! exist, must still leave nothing behind. `VKGL_FAIL_AT=<point>` (common::base::fail) makes a named
//! step fail as a driver might; each run must exit 2 with an error naming the step, without a
//! panic, without a single validation message (a Vulkan object still alive when the device is
//! destroyed is one: "has not been destroyed"), with no counted resource alive at exit
//! (`common::base::resources::live`), and with no file descriptor left open beyond those the driver
//! keeps after a successful run (`VKGL_FAIL_AT=none`, the baseline).

mod harness;

use harness::{Run, run_chapter};

/// Every chapter with the points it reaches, so that each point is proved in several chapters.
const CASES: &[(&str, &str, &[&str], &[&str])] = &[
    (
        "03-semaphores",
        env!("CARGO_BIN_EXE_03-semaphores"),
        &["--size", "64x48", "--frames", "3"],
        &["import", "texture", "submit", "gl_acquire"],
    ),
    (
        "04-compute-triangle",
        env!("CARGO_BIN_EXE_04-compute-triangle"),
        &["--size", "64x48", "--frames", "3"],
        &["map", "texture", "submit", "gl_acquire"],
    ),
    (
        "05-g-buffers",
        env!("CARGO_BIN_EXE_05-g-buffers"),
        &["--size", "64x48"],
        &["map", "import", "texture", "submit", "gl_acquire"],
    ),
    (
        "07-ao-ray-pipeline",
        env!("CARGO_BIN_EXE_07-ao-ray-pipeline"),
        &["--size", "64x48", "--frames", "2", "--samples", "2"],
        &["map", "texture", "submit", "gl_acquire"],
    ),
    (
        "08-composite",
        env!("CARGO_BIN_EXE_08-composite"),
        &["--size", "64x48", "--frames", "2", "--samples", "2"],
        &["import", "submit", "gl_acquire"],
    ),
    (
        "12-fast-frame",
        env!("CARGO_BIN_EXE_12-fast-frame"),
        &["--size", "64x48", "--frames", "2", "--samples", "2"],
        &["map", "import", "texture", "submit", "gl_acquire"],
    ),
    (
        "10-vertex-animation",
        env!("CARGO_BIN_EXE_10-vertex-animation"),
        &["--size", "64x48", "--frames", "2", "--samples", "2", "--rings", "16"],
        &["texture", "submit"],
    ),
];

/// What each fd left open at exit points at (the fd numbers themselves may differ between runs).
fn fds_left(run: &Run) -> Vec<String> {
    let line = run
        .stderr
        .lines()
        .find_map(|l| l.strip_prefix("fds: left open after the chapter ran: "))
        .unwrap_or_else(|| panic!("with VKGL_FAIL_AT the chapter lists the fds it left:\n{}", run.stderr));
    let mut targets: Vec<String> = line
        .split("\", \"")
        .filter_map(|fd| fd.split_once(" -> "))
        .map(|(_, t)| t.trim_end_matches("\"]").to_owned())
        .collect();
    targets.sort();
    targets
}

/// Nothing a clean error path may print (a panic, or any validation message at all), and no
/// counted resource alive at exit: GL objects die with their context, so only the count shows
/// a GL memory object, texture or renderbuffer that `run` forgot.
fn assert_clean(label: &str, run: &Run) {
    for bad in ["panicked", "has not been destroyed", "not destroyed", "validation error", "RUST_BACKTRACE"] {
        assert!(!run.stderr.contains(bad), "{label}: stderr contains {bad:?}:\n{}", run.stderr);
    }
    let alive = "resources: alive after the chapter ran: []";
    assert!(run.stderr.contains(alive), "{label}: resources left alive:\n{}", run.stderr);
}

#[test]
fn every_injected_failure_exits_2_and_leaves_nothing_behind() {
    for &(chapter, bin, args, points) in CASES {
        let baseline = run_chapter(bin, args, &[("VKGL_FAIL_AT", "none")]);
        baseline.succeeded();
        let kept_by_driver = fds_left(&baseline);
        for &point in points {
            let label = format!("{chapter} with VKGL_FAIL_AT={point}");
            let run = run_chapter(bin, args, &[("VKGL_FAIL_AT", point)]);
            assert_eq!(run.output.status.code(), Some(2), "{label}: exit code\n{}", run.stderr);
            let named = format!("error: injected failure at {point}: ");
            assert!(run.stderr.contains(&named), "{label}: the error names the step\n{}", run.stderr);
            assert_clean(&label, &run);
            let mut left = fds_left(&run);
            left.retain(|fd| !kept_by_driver.contains(fd));
            assert!(left.is_empty(), "{label}: fds left open {left:?}\n{}", run.stderr);
        }
    }
}

#[test]
fn an_unknown_fail_point_is_refused() {
    let run =
        run_chapter(env!("CARGO_BIN_EXE_03-semaphores"), &["--size", "32x32"], &[("VKGL_FAIL_AT", "sumbit")]);
    assert_eq!(run.output.status.code(), Some(2));
    assert!(
        run.stderr.contains("VKGL_FAIL_AT=sumbit names no fail point; known: none, map"),
        "{}",
        run.stderr
    );
}

/// A natural failure: a size the flags accept and the device refuses once both contexts exist
/// (reading a 16384x16384 RGBA32F G-buffer back takes 4 GiB, more than GL reads in one call).
#[test]
fn a_size_the_device_refuses_fails_cleanly() {
    let bin = env!("CARGO_BIN_EXE_05-g-buffers");
    let baseline = run_chapter(bin, &["--size", "32x24"], &[("VKGL_FAIL_AT", "none")]);
    baseline.succeeded();
    let kept_by_driver = fds_left(&baseline);
    let run = run_chapter(bin, &["--size", "16384x16384"], &[("VKGL_FAIL_AT", "none")]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("error: --size 16384x16384: "), "{}", run.stderr);
    assert!(run.stderr.contains("4294967296 bytes"), "the error names the bytes needed:\n{}", run.stderr);
    assert_clean("05 at 16384x16384", &run);
    let mut left = fds_left(&run);
    left.retain(|fd| !kept_by_driver.contains(fd));
    assert!(left.is_empty(), "fds left open {left:?}\n{}", run.stderr);
}
