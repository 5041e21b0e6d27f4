//! The `convergence` tool on the software stack: the shape of its report, error that falls with
//! rays at the rate independent samples give or faster, an unbiased estimate on the cases with an
//! exact answer, and the same error wherever the exact cases are placed and however scaled.

mod harness;

use harness::run_chapter_with;
use serde_json::Value;

fn convergence(extra: &[&str]) -> Value {
    let mut args = vec!["--quick"];
    args.extend_from_slice(extra);
    run_chapter_with(env!("CARGO_BIN_EXE_convergence"), &args, &[]).succeeded().clone()
}

fn rmse(case: &Value) -> Vec<f64> {
    case["rows"].as_array().unwrap().iter().map(|r| r["rmse"].as_f64().unwrap()).collect()
}

#[test]
fn error_falls_and_the_exact_cases_are_unbiased() {
    let report = convergence(&[]);
    let cases = report["cases"].as_array().unwrap();
    let names: Vec<&str> = cases.iter().map(|c| c["scene"].as_str().unwrap()).collect();
    assert_eq!(names, ["parallel-planes", "floor-and-wall", "default-scene"]);
    for case in cases {
        let name = case["scene"].as_str().unwrap();
        let rows = case["rows"].as_array().unwrap();
        assert_eq!(rows.len(), 6, "{name}: 2 rays per frame x 3 frame counts");
        for row in rows {
            for field in ["spp", "frames", "gpu_ms", "rmse", "max_abs"] {
                assert!(row[field].as_f64().is_some_and(|v| v >= 0.0), "{name}: {field} in {row}");
            }
        }
        assert!(case["pixels"].as_u64().unwrap() > 500, "{name}: {}", case["pixels"]);
        // Independent samples: rmse ~ N^-1/2. The R2 sequence does better; a constant error or a
        // bias that does not shrink would give a slope near 0.
        let slope = case["slope"].as_f64().unwrap();
        assert!((-1.3..=-0.4).contains(&slope), "{name}: slope {slope}");
        let errors = rmse(case);
        assert!(errors.last().unwrap() < &0.03 && errors.last() < errors.first(), "{name}: {errors:?}");
        let last = rows.last().unwrap();
        let (mean, se) = (last["mean_error"].as_f64().unwrap(), last["standard_error"].as_f64().unwrap());
        if case["reference"] == "analytic" {
            // The estimator is unbiased for these exact answers: the mean error of the longest
            // run is within a few standard errors of 0.
            assert!(mean.abs() <= 4.0 * se + 1e-4, "{name}: mean error {mean}, standard error {se}");
        } else {
            assert_eq!(case["reference"], "high-spp");
        }
    }
}

/// The exact cases scaled by 1e-4 and 1e4 and moved 10,000 times their size from the origin: the
/// error against the exact answer is what it is at the origin (the same rays, up to rounding),
/// and the estimate stays unbiased (no lost occlusion, no acne).
#[test]
fn exact_cases_give_the_same_error_at_any_scale_and_distance() {
    let at_origin = convergence(&["--exact-only"]);
    for (scale, offset) in [("1e-4", "0"), ("1e4", "0"), ("1", "1e4"), ("1e-3", "1e4"), ("1e3", "1e4")] {
        let report = convergence(&["--exact-only", "--scale", scale, "--offset", offset]);
        for (case, reference) in
            report["cases"].as_array().unwrap().iter().zip(at_origin["cases"].as_array().unwrap())
        {
            let (here, there) = (rmse(case), rmse(reference));
            for (a, b) in here.iter().zip(&there) {
                assert!(
                    (a - b).abs() <= 0.1 * b + 0.002,
                    "{} at scale {scale}, offset {offset}: rmse {here:?}, at the origin {there:?}",
                    case["scene"]
                );
            }
        }
    }
}

/// The arguments chapter 13's walks share here, as in its own tests: a small picture, fewer
/// tetrahedra (a TLAS of 10,001 instances traces slowly on a CPU), and the cut early in the path.
const CH13: [&str; 6] = ["--size", "64x48", "--cut-at", "4", "--instances", "400"];

/// `convergence temporal` with `args`: chapter 13's frame along its path, headless.
fn temporal(args: &[&str]) -> harness::Run {
    let mut all = vec!["temporal"];
    all.extend_from_slice(args);
    run_chapter_with(env!("CARGO_BIN_EXE_convergence"), &all, &[])
}

/// The tool draws chapter 13's very frame: along the same path with the same flags, the same
/// pictures as the chapter's own program, byte for byte.
#[test]
fn temporal_draws_what_chapter_13_draws() {
    let mut args = CH13.to_vec();
    args.extend(["--frames", "6"]);
    let tool = temporal(&args);
    tool.succeeded();
    args.insert(0, "--headless");
    let chapter = run_chapter_with(env!("CARGO_BIN_EXE_13-temporal-reuse"), &args, &[]);
    chapter.succeeded();
    // The tool names its pictures as itself, so that they never replace the chapter's.
    for (ours, theirs) in [
        ("convergence-temporal.png", "13-temporal-reuse.png"),
        ("convergence-temporal-ao.png", "13-temporal-reuse-ao.png"),
    ] {
        let read = |run: &harness::Run, name: &str| {
            let path = run.out_dir.path().join(name);
            std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        };
        assert!(read(&tool, ours) == read(&chapter, theirs), "{ours} differs from chapter 13's {theirs}");
    }
}

/// `--fresh-pass packed` traces the pixels with nothing remembered in a second launch, listed by
/// the first; `inline` traces them in the one launch, beside their neighbours. The same rays from
/// the same points of the sequence: the same pictures, byte for byte, along a path whose cut
/// leaves every pixel with nothing remembered.
#[test]
fn temporal_packed_fresh_pass_draws_what_inline_draws() {
    let run = |pass| {
        let mut args = CH13.to_vec();
        args.extend(["--frames", "8", "--fresh-pass", pass]);
        temporal(&args)
    };
    let (packed, inline) = (run("packed"), run("inline"));
    let reports = [packed.succeeded(), inline.succeeded()];
    assert_eq!(reports.map(|r| r["fresh_pass"].clone()), ["packed", "inline"]);
    assert_eq!(reports[0]["ao_mean"], reports[1]["ao_mean"]);
    for name in ["convergence-temporal.png", "convergence-temporal-ao.png"] {
        let read = |run: &harness::Run| {
            let path = run.out_dir.path().join(name);
            std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        };
        assert!(read(&packed) == read(&inline), "{name} differs between --fresh-pass packed and inline");
    }
}

/// GL's next ids drawn before the CPU waits for the trace (`--next-ids early`, the default) or
/// after (`late`): the same pictures and the same history at the cut, and the early walk did
/// draw its frames' ids ahead, all but those after which something is read back.
#[test]
fn temporal_next_ids_drawn_early_draw_what_late_draws() {
    let run = |when: &str| {
        let mut args = CH13.to_vec();
        args.extend(["--frames", "10", "--next-ids", when]);
        temporal(&args)
    };
    let (early, late) = (run("early"), run("late"));
    let (a, b) = (early.succeeded(), late.succeeded());
    // Frames 3 and 4 are read back for the cut check, frame 9 is the last: 7 of 10 draw ahead.
    assert_eq!(a["frames_with_ids_drawn_ahead"], 7);
    assert_eq!(b["frames_with_ids_drawn_ahead"], 0);
    assert_eq!(a["cut_pixels_kept"], b["cut_pixels_kept"]);
    for name in ["convergence-temporal.png", "convergence-temporal-ao.png"] {
        let (x, y) = (early.out_dir.path().join(name), late.out_dir.path().join(name));
        assert_eq!(std::fs::read(&x).unwrap(), std::fs::read(&y).unwrap(), "{name}");
    }
}

/// A case built to ghost: every remembered texel reused, whatever it saw (`--accept none`). The
/// cut check fails, and the error measured after the cut is larger than with the tests on: the
/// metric sees the ghosts.
#[test]
fn temporal_ghosts_fail_the_cut_check_and_raise_the_error() {
    let run = |accept: &str| {
        let mut args = CH13.to_vec();
        args.extend(["--frames", "10", "--accept", accept, "--error-against", "64", "--error-every", "100"]);
        temporal(&args)
    };
    let after_cut = |report: &serde_json::Value| -> f64 {
        let frames = report["walks"][0]["frames"].as_array().unwrap();
        let errors: Vec<f64> = frames
            .iter()
            .filter(|f| f["frame"].as_u64().unwrap() >= 4)
            .filter_map(|f| f["rmse"].as_f64())
            .collect();
        assert!(errors.len() >= 5, "the frames after the cut are measured: {errors:?}");
        errors.iter().sum::<f64>() / errors.len() as f64
    };
    let tested = run("instance,plane,normal");
    let tested = after_cut(tested.succeeded());
    let ghosting = run("none");
    assert_eq!(ghosting.output.status.code(), Some(1), "a failed check:\n{}", ghosting.stderr);
    let report = ghosting.report.as_ref().unwrap();
    assert_eq!(report["checks"]["no_history_kept_across_the_cut_from_unseen_surfaces"], false);
    assert!(report["cut_pixels_kept_unseen"].as_u64().unwrap() > 0);
    let ghosted = after_cut(report);
    assert!(ghosted > tested * 1.2, "ghosts are errors: {ghosted} with none of the tests, {tested} with all");
}

/// Along the orbit without its cut, the tool reports as itself (its own name, folder and
/// pictures, never over chapter 13's) the checks chapter 13 makes of such a walk.
#[test]
fn temporal_reports_as_itself() {
    let args = ["--size", "64x48", "--frames", "4", "--cut-at", "0", "--instances", "400"];
    let run = temporal(&args);
    let report = run.succeeded();
    assert_eq!(report["chapter"], "convergence-temporal");
    assert!(run.out_dir.path().join("convergence-temporal.png").exists(), "the tool's own picture");
    harness::assert_report_snapshot("convergence-temporal", report);
}

/// `--timeline N`: the last N frames' passes, GL's and Vulkan's, on one clock, as chapter 12's.
#[test]
fn temporal_timeline_puts_both_apis_on_one_clock() {
    let mut args = CH13.to_vec();
    args.extend(["--frames", "5", "--timeline", "3"]);
    let run = temporal(&args);
    let report = run.succeeded();
    assert_eq!(report["timeline"]["frames"], 3);
    for file in ["timeline.json", "timeline.svg"] {
        let path = run.out_dir.path().join(file);
        assert!(std::fs::metadata(&path).is_ok_and(|m| m.len() > 0), "{} written", path.display());
    }
}

/// `--method fresh`: chapter 12's frame along the same path, across the cut, with the same
/// checks of the last frame (and none of the history's: it keeps none).
#[test]
fn temporal_draws_chapter_12s_frame_along_the_path() {
    let mut args = CH13.to_vec();
    args.extend(["--frames", "6", "--method", "fresh", "--samples", "4"]);
    let run = temporal(&args);
    let report = run.succeeded();
    assert_eq!(report["checks"]["composite_matches_cpu_reference"], true);
    assert!(report["checks"].get("no_history_kept_across_the_cut_from_unseen_surfaces").is_none());
}

/// `--compare` sums each walk up per view of the path, before the cut and from it on, and writes
/// every frame's times to compare.csv; an error run reads them back with `--times-from`, frame by
/// frame, so that its table shows the time run's times beside its own errors.
#[test]
fn temporal_compare_sums_up_each_view_and_takes_times_frame_by_frame() {
    let mut args = CH13.to_vec();
    args.extend(["--frames", "6", "--compare"]);
    let timed = temporal(&args);
    let report = timed.succeeded();
    let walks = report["walks"].as_array().unwrap();
    assert_eq!(walks.len(), 6);
    for walk in walks {
        let frames = walk["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 6);
        assert!(frames.iter().all(|f| f["wall_ms"].as_f64().is_some_and(|t| t > 0.0)), "{walk}");
        for view in ["before_cut", "after_cut"] {
            assert!(walk[view]["frame_wall_ms"].as_f64().is_some_and(|t| t > 0.0), "{view}: {walk}");
        }
    }
    let table = std::fs::read_to_string(timed.out_dir.path().join("compare.md")).unwrap();
    assert!(table.contains("| frame ms (wall), before the cut | from the cut on |"), "{table}");
    let csv = timed.out_dir.path().join("compare.csv");
    let mut args = CH13.to_vec();
    args.extend([
        "--frames",
        "6",
        "--compare",
        "--error-against",
        "16",
        "--times-from",
        csv.to_str().unwrap(),
    ]);
    let measured = temporal(&args);
    let report = measured.succeeded();
    for (theirs, ours) in walks.iter().zip(report["walks"].as_array().unwrap()) {
        assert_eq!(theirs["method"], ours["method"]);
        assert!(ours["error_mean"].as_f64().is_some(), "{ours}");
        for (a, b) in theirs["frames"].as_array().unwrap().iter().zip(ours["frames"].as_array().unwrap()) {
            // compare.csv keeps six decimals.
            let close = |k: &str| (a[k].as_f64().unwrap() - b[k].as_f64().unwrap()).abs() < 1e-5;
            assert!(close("wall_ms") && close("ao_ms"), "frame {}: {a} against {b}", a["frame"]);
        }
        let (a, b) = (
            theirs["after_cut"]["frame_wall_ms"].as_f64().unwrap(),
            ours["after_cut"]["frame_wall_ms"].as_f64().unwrap(),
        );
        assert!((a - b).abs() < 1e-5, "{a} against {b}");
    }
}

/// `--times-from` names a file that is not a compare.csv: refused, naming it, before any GPU work.
#[test]
fn temporal_refuses_times_from_what_is_not_a_compare_csv() {
    let dir = tempfile::tempdir().unwrap();
    let not_csv = dir.path().join("compare.md");
    std::fs::write(&not_csv, "| method | frame ms (wall) |\n").unwrap();
    for (file, why) in [
        (not_csv.clone(), "not a compare.csv of this chapter"),
        (dir.path().join("none.csv"), "No such file"),
    ] {
        let args = ["--size", "64x48", "--compare", "--times-from", file.to_str().unwrap()];
        let run = temporal(&args);
        assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
        assert!(run.stderr.contains(why) && run.stderr.contains(file.to_str().unwrap()), "{}", run.stderr);
        assert!(!run.stderr.contains("vulkan: using"), "refused before the device: {}", run.stderr);
    }
}
