//! Every program, at tiny, odd and too large sizes: it either draws and passes every check it
//! makes at a usual size (exit 0), or refuses up front with exit 2 and a message naming the
//! smallest size, the widest or tallest shape, or the largest size and the device limit behind
//! it. Never a failed check (exit 1), never a panic. A size the scene covers no pixel of is
//! refused too (exit 2, "the scene covers no pixel"), once drawn: every mean, minimum and check over
//! the covered pixels would be over none, so a run that passes must have covered some.
//!
//! The walk, per program: 1x1, 2x2, 3x1, 16x200 and 200x16; the smallest size it names (run, and
//! it must pass); the widest and the tallest shape it names at that smallest size (run); a side of
//! 16384, the device's largest on the software stack, where the program takes so wide a picture
//! (run); 16384x1 and 1x16384, a single row and column through the middle of the picture, which
//! the framed scene covers no pixel of (refused by every program that draws a scene); and
//! 16385x16385, one past that limit (refused, naming the limit). Chapter 01 also
//! runs at 16384x16384, the largest it accepts; the others would take 10 to 30 seconds and 4 to 6
//! GiB each at their largest on llvmpipe (chapters 02-04 at 16384x16384; 05-12 stop at the
//! G-buffer read-back limit, 11585x11585, minutes of ray tracing): `largest_pictures` runs 02-04
//! there when asked (`cargo test --test sizes -- --ignored`).

mod harness;

use harness::run_chapter_with;
use harness::sizes::{self, Outcome, run_at, walk};
use std::collections::BTreeSet;

/// Each program with flags that make it quick and let its every check run (several frames where
/// checks compare frames).
const PROGRAMS: &[(&str, &str, &[&str])] = &[
    ("01-exportable-memory", env!("CARGO_BIN_EXE_01-exportable-memory"), &[]),
    ("02-gl-buffer-import", env!("CARGO_BIN_EXE_02-gl-buffer-import"), &[]),
    ("03-semaphores", env!("CARGO_BIN_EXE_03-semaphores"), &["--frames", "3"]),
    ("04-compute-triangle", env!("CARGO_BIN_EXE_04-compute-triangle"), &["--frames", "3"]),
    ("05-g-buffers", env!("CARGO_BIN_EXE_05-g-buffers"), &[]),
    ("06-blas-tlas", env!("CARGO_BIN_EXE_06-blas-tlas"), &[]),
    ("07-ao-ray-pipeline", env!("CARGO_BIN_EXE_07-ao-ray-pipeline"), &["--frames", "2", "--samples", "2"]),
    ("08-composite", env!("CARGO_BIN_EXE_08-composite"), &["--frames", "2", "--samples", "2"]),
    (
        "09-animated-instances",
        env!("CARGO_BIN_EXE_09-animated-instances"),
        &["--frames", "3", "--samples", "2"],
    ),
    (
        "10-vertex-animation",
        env!("CARGO_BIN_EXE_10-vertex-animation"),
        &["--frames", "2", "--samples", "2", "--rings", "16"],
    ),
    ("11-cuda-depth-composite", env!("CARGO_BIN_EXE_11-cuda-depth-composite"), &["--tracer", "cpu"]),
    ("12-fast-frame", env!("CARGO_BIN_EXE_12-fast-frame"), &["--frames", "2", "--samples", "2"]),
    (
        "13-temporal-reuse",
        env!("CARGO_BIN_EXE_13-temporal-reuse"),
        &["--frames", "3", "--cut-at", "2", "--instances", "50"],
    ),
];

/// The walk for one of [`PROGRAMS`], and the limit its refusal names (`harness::sizes`).
fn walk_sizes(name: &str) {
    let &(_, bin, flags) = PROGRAMS.iter().find(|p| p.0 == name).expect("a program of PROGRAMS");
    let limit = if name == "01-exportable-memory" { "maxExtent" } else { "maxImageDimension2D 16384" };
    sizes::walk_sizes(name, bin, flags, limit);
}

#[test]
fn sizes_01() {
    walk_sizes("01-exportable-memory");
    // The largest it accepts: a 16384x16384 exportable image (1 GiB), made in a moment.
    run_at(env!("CARGO_BIN_EXE_01-exportable-memory"), &[], "16384x16384").succeeded();
}

#[test]
fn sizes_02() {
    walk_sizes("02-gl-buffer-import");
}

#[test]
fn sizes_03() {
    walk_sizes("03-semaphores");
}

#[test]
fn sizes_04() {
    walk_sizes("04-compute-triangle");
}

#[test]
fn sizes_05() {
    walk_sizes("05-g-buffers");
}

#[test]
fn sizes_06() {
    walk_sizes("06-blas-tlas");
}

#[test]
fn sizes_07() {
    walk_sizes("07-ao-ray-pipeline");
}

#[test]
fn sizes_08() {
    walk_sizes("08-composite");
}

#[test]
fn sizes_09() {
    walk_sizes("09-animated-instances");
}

#[test]
fn sizes_10() {
    walk_sizes("10-vertex-animation");
}

#[test]
fn sizes_11() {
    walk_sizes("11-cuda-depth-composite");
}

#[test]
fn sizes_12() {
    walk_sizes("12-fast-frame");
}

#[test]
fn sizes_13() {
    walk_sizes("13-temporal-reuse");
}

/// bench takes `--sizes`: each is refused alike, before anything runs, or measured.
#[test]
fn sizes_bench() {
    let bin = env!("CARGO_BIN_EXE_bench");
    let quick = ["--quick", "--scenes", "ceiling", "--spp", "1", "--frames", "1", "--reference-rays", "16"];
    let bench = |sizes: &str| {
        let mut args = quick.to_vec();
        args.extend(["--sizes", sizes]);
        run_chapter_with(bin, &args, &[])
    };
    let usual: BTreeSet<String> =
        bench("64x48").succeeded()["checks"].as_object().unwrap().keys().cloned().collect();
    for (size, expected) in [
        ("1x1", "error: --sizes 1x1 is too small for bench: its checks need at least 24x24 pixels"),
        ("2x2", "error: --sizes 2x2 is too small for bench"),
        ("3x1", "error: --sizes 3x1 is too small for bench"),
        ("16x200", "error: --sizes 16x200 is too small for bench"),
        ("200x16", "error: --sizes 200x16 is too small for bench"),
        ("200x24", "error: --sizes 200x24 is too wide for bench: its checks need a width of at most 4 times"),
        ("16385x16385", "error: --sizes 16385x16385 is too large for bench: at most 16384x16384 pixels here"),
    ] {
        let run = bench(size);
        assert_eq!(run.output.status.code(), Some(2), "{size}: exit 2\n{}", run.stderr);
        assert!(run.stderr.contains(expected), "{size}: {expected:?}\n{}", run.stderr);
        assert!(!run.stderr.contains("panicked"), "{size}\n{}", run.stderr);
    }
    assert!(matches!(walk("bench", "24x24", &bench("24x24"), &usual), Outcome::Passed));
    assert!(matches!(walk("bench", "96x24", &bench("96x24"), &usual), Outcome::Passed));
}

/// convergence draws fixed sizes (64x48 with --quick, 320x240 without): it takes no `--size`.
#[test]
fn convergence_takes_no_size() {
    let run = run_chapter_with(env!("CARGO_BIN_EXE_convergence"), &["--quick", "--size", "1x1"], &[]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("unexpected argument '--size'"), "{}", run.stderr);
}

/// Chapters 02-04 at 16384x16384, the largest they accept on llvmpipe: 10 to 30 seconds and 4 to
/// 6 GiB each, one after the other. Not in the default run (`-- --ignored`).
#[test]
#[ignore]
fn largest_pictures() {
    for &(name, bin, flags) in &PROGRAMS[1..4] {
        let run = run_at(bin, flags, "16384x16384");
        assert!(matches!(walk(name, "16384x16384", &run, &BTreeSet::new()), Outcome::Passed), "{name}");
    }
}
