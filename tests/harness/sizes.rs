//! The size walk of `tests/sizes.rs`, for every program: tiny, odd and too large sizes, each
//! drawn and checked or refused up front naming the limit. Here so that a chapter that is a
//! package of its own (15) walks the same sizes in its own tests.

use super::{Run, run_chapter};
use std::collections::BTreeSet;

/// What one size did.
pub enum Outcome {
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
pub fn draws_a_scene(name: &str) -> bool {
    !matches!(name, "01-exportable-memory" | "02-gl-buffer-import" | "03-semaphores" | "04-compute-triangle")
}

/// What a passed run reports about the pixels it covered, where it reports it (07's rays, 05's and
/// 06's fraction), must be more than none: a mean or a check over no pixel means nothing.
pub fn covered_something(label: &str, report: &serde_json::Value, stderr: &str) {
    for key in ["rays_traced", "covered_fraction"] {
        if let Some(value) = report.get(key).and_then(|v| v.as_f64()) {
            assert!(value > 0.0, "{label}: passed with {key} {value}: the scene covered no pixel\n{stderr}");
        }
    }
}

/// Runs one program at one size and says what happened; panics on anything else (exit 1, a
/// panic, exit 2 without a message naming a limit, or a run that passes fewer checks than usual).
pub fn walk(name: &str, size: &str, run: &Run, usual: &BTreeSet<String>) -> Outcome {
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

pub fn run_at(bin: &str, flags: &[&str], size: &str) -> Run {
    let mut args = vec!["--size", size];
    args.extend_from_slice(flags);
    run_chapter(bin, &args, &[])
}

/// The walk for one program, `name` run as `bin` with `flags` (see `tests/sizes.rs`); `limit`,
/// what its refusal of one past the largest size names.
pub fn walk_sizes(name: &str, bin: &str, flags: &[&str], limit: &str) {
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
    // pixels, or few, so a program that draws it refuses them (too small, or once drawn) or
    // passes with a mean over the pixels it covered; one that draws no scene may draw them.
    for (w, h) in [(16384, 1), (1, 16384)] {
        let size = format!("{w}x{h}");
        let run = run_at(bin, flags, &size);
        match walk(name, &size, &run, &usual) {
            // Passed with its mean AO, which a program reports only over covered pixels (and
            // refuses the size without one): its scene reaches the middle (chapter 16's fence).
            Outcome::Passed if run.report.as_ref().is_some_and(|r| r["ao_mean"].is_number()) => {}
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
