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

use harness::{Run, run_chapter, run_chapter_with};
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

/// What one size did.
enum Outcome {
    Passed,
    /// Refused for being too small: the smallest size named.
    TooSmall(u32, u32),
    /// Refused for its shape: the ratio of the sides named.
    TooWide(f32),
    TooTall(f32),
    /// Refused for being too large: the largest size named.
    TooLarge(u32, u32),
    /// Refused because the scene, drawn, covered no pixel of it.
    Uncovered,
}

/// The programs that draw the framed scene and measure or check its covered pixels.
fn draws_a_scene(name: &str) -> bool {
    !matches!(name, "01-exportable-memory" | "02-gl-buffer-import" | "03-semaphores" | "04-compute-triangle")
}

/// What a passed run reports about the pixels it covered, where it reports it (07's rays, 05's and
/// 06's fraction), must be more than none: a mean or a check over no pixel means nothing.
fn covered_something(label: &str, report: &serde_json::Value, stderr: &str) {
    for key in ["rays_traced", "covered_fraction"] {
        if let Some(value) = report.get(key).and_then(|v| v.as_f64()) {
            assert!(value > 0.0, "{label}: passed with {key} {value}: the scene covered no pixel\n{stderr}");
        }
    }
}

/// Runs one program at one size and says what happened; panics on anything else (exit 1, a
/// panic, exit 2 without a message naming a limit, or a run that passes fewer checks than usual).
fn walk(name: &str, size: &str, run: &Run, usual: &BTreeSet<String>) -> Outcome {
    let label = format!("{name} --size {size}");
    assert!(!run.stderr.contains("panicked"), "{label}: panicked\n{}", run.stderr);
    match run.output.status.code() {
        Some(0) => {
            let report = run.succeeded();
            let checks: BTreeSet<String> = report["checks"].as_object().unwrap().keys().cloned().collect();
            // A check a program does not make at this size, and says so, is not missing.
            let unmade =
                |check: &String| run.stderr.contains(&format!("{check} is not checked at this size"));
            let missing: Vec<_> = usual.difference(&checks).filter(|c| !unmade(c)).collect();
            assert!(
                missing.is_empty(),
                "{label}: passed, but without the checks {missing:?}\n{}",
                run.stderr
            );
            covered_something(&label, report, &run.stderr);
            Outcome::Passed
        }
        Some(2) => {
            let error = run
                .stderr
                .lines()
                .find(|l| l.starts_with("error: "))
                .unwrap_or_else(|| panic!("{label}: exit 2 without an error line\n{}", run.stderr));
            let after = |marker: &str| error.split_once(marker).map(|(_, rest)| rest);
            let dimensions = |text: &str| -> (u32, u32) {
                let size = text.split_whitespace().next().unwrap_or("");
                let (w, h) = size.split_once('x').unwrap_or_else(|| panic!("{label}: no WxH in {error}"));
                (w.parse().unwrap(), h.parse().unwrap())
            };
            let ratio = |text: &str| -> f32 { text.split_whitespace().next().unwrap().parse().unwrap() };
            let refused = format!("error: --size {size} is too ");
            assert!(error.starts_with(&refused), "{label}: exit 2 for another reason: {error}");
            assert!(error.contains(&format!(" for {name}: ")), "{label}: names the program: {error}");
            if after(": the scene covers no pixel of it").is_some() {
                Outcome::Uncovered
            } else if let Some(rest) = after("its checks need at least ") {
                Outcome::TooSmall(dimensions(rest).0, dimensions(rest).1)
            } else if let Some(rest) = after("its checks need a width of at most ") {
                Outcome::TooWide(ratio(rest))
            } else if let Some(rest) = after("its checks need a height of at most ") {
                Outcome::TooTall(ratio(rest))
            } else if let Some(rest) = after(": at most ") {
                Outcome::TooLarge(dimensions(rest).0, dimensions(rest).1)
            } else {
                panic!("{label}: the refusal names no size: {error}")
            }
        }
        other => panic!("{label}: exit {other:?}\n{}", run.stderr),
    }
}

fn run_at(bin: &str, flags: &[&str], size: &str) -> Run {
    let mut args = vec!["--size", size];
    args.extend_from_slice(flags);
    run_chapter(bin, &args, &[])
}

/// The walk for one program (see the top of this file).
fn walk_sizes(name: &str) {
    let &(_, bin, flags) = PROGRAMS.iter().find(|p| p.0 == name).expect("a program of PROGRAMS");
    let usual_run = run_at(bin, flags, "64x48");
    let usual: BTreeSet<String> =
        usual_run.succeeded()["checks"].as_object().unwrap().keys().cloned().collect();
    let at = |size: &str| walk(name, size, &run_at(bin, flags, size), &usual);

    // Tiny sizes: each passes or names the smallest, which must then be larger than it.
    let mut smallest = (1, 1);
    for (w, h) in [(1, 1), (2, 2), (3, 1)] {
        match at(&format!("{w}x{h}")) {
            Outcome::Passed => {}
            Outcome::TooSmall(sw, sh) => {
                assert!(w < sw || h < sh, "{name} {w}x{h}: refused, though not under {sw}x{sh}");
                smallest = (sw, sh);
            }
            _ => panic!("{name} {w}x{h}: refused for another reason than its size"),
        }
    }
    // The smallest it names is drawn and checked.
    let (sw, sh) = smallest;
    assert!(matches!(at(&format!("{sw}x{sh}")), Outcome::Passed), "{name}: its smallest, {sw}x{sh}");

    // Odd shapes: passed, or refused as too small, too wide or too tall; the widest and the
    // tallest shape named are drawn at the smallest size.
    for (w, h) in [(16, 200), (200, 16)] {
        match at(&format!("{w}x{h}")) {
            Outcome::Passed => {}
            Outcome::TooSmall(..) => assert!(w < sw || h < sh, "{name} {w}x{h}: not under {sw}x{sh}"),
            Outcome::TooWide(ratio) => {
                assert!(w as f32 > ratio * h as f32, "{name} {w}x{h}: not wider than {ratio}:1");
                let widest = format!("{}x{sh}", (ratio * sh as f32).floor() as u32);
                assert!(matches!(at(&widest), Outcome::Passed), "{name}: its widest shape, {widest}");
            }
            Outcome::TooTall(ratio) => {
                assert!(h as f32 > ratio * w as f32, "{name} {w}x{h}: not taller than 1:{ratio}");
                let tallest = format!("{sw}x{}", (ratio * sw as f32).floor() as u32);
                assert!(matches!(at(&tallest), Outcome::Passed), "{name}: its tallest shape, {tallest}");
            }
            Outcome::TooLarge(..) => panic!("{name} {w}x{h}: refused as too large"),
            Outcome::Uncovered => panic!("{name} {w}x{h}: the scene covers part of so square a picture"),
        }
    }

    // A single row and a single column through the middle: the framed scene covers none of their
    // pixels, so a program that draws it refuses them (too small, or once drawn); one that does
    // not may draw them.
    for (w, h) in [(16384, 1), (1, 16384)] {
        let size = format!("{w}x{h}");
        let run = run_at(bin, flags, &size);
        match walk(name, &size, &run, &usual) {
            Outcome::Passed => assert!(
                !draws_a_scene(name),
                "{name} {size}: passed, though the scene covers no pixel of it\n{}",
                run.stderr
            ),
            Outcome::TooSmall(sw, sh) => assert!(w < sw || h < sh, "{name} {size}: not under {sw}x{sh}"),
            Outcome::TooWide(_) | Outcome::TooTall(_) | Outcome::Uncovered => {}
            Outcome::TooLarge(..) => panic!("{name} {size}: refused as too large"),
        }
    }

    // One past the device's largest side: refused, naming the largest and the limit.
    let past = "16385x16385";
    let run = run_at(bin, flags, past);
    let Outcome::TooLarge(lw, lh) = walk(name, past, &run, &usual) else {
        panic!("{name} {past}: not refused as too large\n{}", run.stderr)
    };
    assert_eq!((lw, lh), (16384, 16384), "{name}: llvmpipe's largest image is 16384x16384\n{}", run.stderr);
    let limit = if name == "01-exportable-memory" { "maxExtent" } else { "maxImageDimension2D 16384" };
    assert!(run.stderr.contains(limit), "{name} {past}: names the limit {limit:?}\n{}", run.stderr);

    // The largest side, where the program takes a picture that wide: drawn and checked.
    let widest = format!("16384x{sh}");
    match at(&widest) {
        Outcome::Passed => {}
        Outcome::TooWide(ratio) => assert!(16384.0 > ratio * sh as f32, "{name} {widest}"),
        // So thin a picture that the scene covers none of it (07's 16384x1): a row more draws it.
        Outcome::Uncovered => {
            let wider = format!("16384x{}", sh + 1);
            assert!(matches!(at(&wider), Outcome::Passed), "{name}: {widest} refused as uncovered, {wider}");
        }
        _ => panic!("{name} {widest}: neither drawn nor refused as too wide"),
    }
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
