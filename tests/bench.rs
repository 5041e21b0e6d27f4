//! The `bench` binary on the software stack: `--quick --json` runs, and its report has every
//! row, pass time and ablation step (no timing asserts: lavapipe's speed says nothing about a
//! GPU's).

mod harness;

use harness::{assert_report_snapshot, run_chapter_with};
use serde_json::Value;

#[test]
fn quick_bench_reports_every_mode_scene_size_and_ray_count() {
    let run = run_chapter_with(env!("CARGO_BIN_EXE_bench"), &["--quick"], &[]);
    let report = run.succeeded();
    assert!(report["device"].as_str().is_some_and(|d| !d.is_empty()));
    assert!(report["driver"].as_str().is_some_and(|d| !d.is_empty()));
    let rows = report["rows"].as_array().expect("rows");
    // 3 modes of chapter 08's frame, chapter 12's and chapter 13's two (one per view of its
    // path), x 3 scenes x 2 sizes x 2 ray counts.
    assert_eq!(rows.len(), 72);
    let fields = [
        "mode",
        "scene",
        "width",
        "height",
        "spp",
        "frame_ms",
        "p95_ms",
        "raster_ms",
        "handoff_ms",
        "ao_ms",
        "composite_ms",
        "grays_per_s",
    ];
    for row in rows {
        let keys: Vec<&str> = row.as_object().unwrap().keys().map(String::as_str).collect();
        let mut expected = fields.to_vec();
        expected.sort();
        let mut keys_sorted = keys.clone();
        keys_sorted.sort();
        assert_eq!(keys_sorted, expected, "exactly the row's fields: {row}");
        for field in &fields[2..] {
            assert!(row[field].as_f64().is_some_and(|v| v.is_finite() && v >= 0.0), "{field} in {row}");
        }
    }
    let set = |field: &str| {
        let mut values: Vec<String> = rows.iter().map(|r| r[field].to_string()).collect();
        values.sort();
        values.dedup();
        values
    };
    assert_eq!(
        set("mode"),
        [
            r#""cpu-round-trip""#,
            r#""fast-frame""#,
            r#""host-sync""#,
            r#""temporal-reuse""#,
            r#""temporal-reuse-closer""#,
            r#""zero-copy""#
        ]
    );
    assert_eq!(set("scene"), [r#""ceiling""#, r#""default""#, r#""large""#]);
    assert_eq!(set("spp"), ["1", "4"]);
    // Chapter 13's rows at chapter 12's error: for every scene, size and ray count, chapter 12's
    // error along chapter 13's orbit, and the fewest rays a frame of chapter 13's that reach it
    // (or the most tried, where none does), both measured.
    let equal = report["temporal_equal_error"].as_array().expect("temporal_equal_error");
    assert_eq!(equal.len(), 12, "3 scenes x 2 sizes x 2 ray counts");
    for e in equal {
        let (spp, samples) = (e["spp"].as_u64().unwrap(), e["samples"].as_u64().unwrap());
        let (theirs, ours) = (e["chapter_12_error"].as_f64().unwrap(), e["error"].as_f64().unwrap());
        // The ceiling scene occludes nothing within the radius: both errors are 0 there.
        let occluded = e["scene"] != "ceiling";
        assert!(theirs >= 0.0 && ours >= 0.0 && (!occluded || (theirs > 0.0 && ours > 0.0)), "{e}");
        assert!((1..=spp).contains(&samples), "{e}");
        assert!(ours <= theirs || samples == spp, "the fewest rays that reach chapter 12's error: {e}");
    }
    // The large scene's acceleration structures: sizes and GPU build times.
    let large = &report["large_scene"];
    for field in ["triangles", "blas_bytes", "compacted_bytes", "tlas_bytes"] {
        assert!(large[field].as_u64().is_some_and(|v| v > 0), "{field} in {large}");
    }
    for field in ["blas_build_ms", "compaction_ms", "tlas_build_ms"] {
        assert!(large[field].as_f64().is_some_and(|v| v >= 0.0), "{field} in {large}");
    }
    // The table and the plot beside the report.
    for file in ["bench.json", "bench.md", "bench.svg"] {
        let path = run.out_dir.path().join(file);
        assert!(std::fs::metadata(&path).is_ok_and(|m| m.len() > 0), "{} written", path.display());
    }
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(run.out_dir.path().join("bench.json")).unwrap())
            .unwrap();
    assert_eq!(json["rows"].as_array().unwrap().len(), rows.len());

    // The rest of the report, snapshotted: which rows (not their times), the checks, the settings,
    // the large scene's sizes (lavapipe builds the same structures every run), what was created.
    let mut snapshot = report.clone();
    // Which rays a frame chapter 13 needed may differ with the driver's rounding: counted only.
    snapshot["temporal_equal_error"] = Value::from(equal.len());
    snapshot["rows"] = rows
        .iter()
        .map(|r| {
            Value::from(format!("{} {} {}x{} {}", r["mode"], r["scene"], r["width"], r["height"], r["spp"]))
        })
        .collect::<Vec<Value>>()
        .into();
    for field in ["device", "driver"] {
        snapshot[field] = Value::from("[device]");
    }
    for field in ["blas_build_ms", "compaction_ms", "tlas_build_ms"] {
        snapshot["large_scene"][field] = Value::from("[ms]");
    }
    // The ablation: chapter 12 with each choice undone, at the largest size and the most rays,
    // every step timed and its error after the blur measured.
    let ablation = &report["ablation"];
    assert_eq!((ablation["size"].as_str(), ablation["spp"].as_u64()), (Some("96x64"), Some(4)));
    let steps = ablation["steps"].as_array().expect("ablation steps");
    assert_eq!(steps.len(), 4);
    for step in steps {
        for field in ["frame_ms", "raster_ms", "ao_ms", "composite_ms", "error_raw", "error_blurred"] {
            assert!(step[field].as_f64().is_some_and(|v| v.is_finite() && v > 0.0), "{field} in {step}");
        }
        assert!(
            step["error_blurred"].as_f64() < step["error_raw"].as_f64(),
            "the blur lowers the error: {step}"
        );
    }
    snapshot["ablation"]["steps"] = steps.iter().map(|s| s["flags"].clone()).collect::<Vec<Value>>().into();
    assert_report_snapshot("bench-quick", &snapshot);
}

/// `--timeline N` puts the last N frames of chapter 08's frame and of chapter 12's (drawn by the
/// bench from the chapter's library), each on one clock: both gaps of a hand-over reported, every
/// pass's span in order, both pictures written.
#[test]
fn bench_timeline_draws_chapter_08_and_chapter_12() {
    let args = ["--quick", "--scenes", "default", "--sizes", "64x48", "--spp", "4", "--timeline", "2"];
    let run = run_chapter_with(env!("CARGO_BIN_EXE_bench"), &args, &[]);
    let report = run.succeeded();
    let gaps = [
        ("timeline_08", ["gap_gbuffer_to_trace_ms_median", "gap_trace_to_composite_ms_median"]),
        ("timeline_12", ["gap_ids_to_trace_ms_median", "gap_trace_to_composite_ms_median"]),
    ];
    for (timeline, keys) in gaps {
        let timeline = &report[timeline];
        assert_eq!(timeline["frames"], 2, "{timeline}");
        for key in keys {
            assert!(timeline[key].as_f64().is_some_and(f64::is_finite), "{key}: {timeline}");
        }
    }
    let out = run.out_dir.path();
    for (name, raster) in [("timeline-08", "gbuffer"), ("timeline-12", "ids")] {
        let json = std::fs::read_to_string(out.join(format!("{name}.json"))).unwrap();
        let spans: Value = serde_json::from_str(&json).unwrap();
        let spans = spans.as_array().unwrap();
        let passes: Vec<&str> = spans.iter().map(|s| s["pass"].as_str().unwrap()).collect();
        assert_eq!(passes.len(), 6, "{name}: the raster pass, trace and composite of two frames: {passes:?}");
        for pass in [raster, "ao_trace", "composite"] {
            assert_eq!(passes.iter().filter(|p| **p == pass).count(), 2, "{name}: {pass} in {passes:?}");
        }
        for span in spans {
            assert!(span["end_ms"].as_f64() >= span["start_ms"].as_f64(), "{name}: {span}");
        }
        let picture = format!("{name}.svg");
        assert!(std::fs::metadata(out.join(&picture)).is_ok_and(|m| m.len() > 0), "{picture}");
    }
}

/// The rows of a `--probe` run that passed its checks, each measured value of `keys` finite and
/// at least 0 (no timing asserts beyond that: lavapipe's speed says nothing about a GPU's).
fn probe_rows(args: &[&str], env: &[(&str, &str)], keys: &[&str]) -> Vec<Value> {
    let run = run_chapter_with(env!("CARGO_BIN_EXE_bench"), args, env);
    let report = run.succeeded();
    let rows = report["rows"].as_array().expect("rows").clone();
    for row in &rows {
        for key in keys {
            let value = &row["measured"][key];
            assert!(value.as_f64().is_some_and(|v| v.is_finite() && v >= 0.0), "{key}: {row}");
        }
    }
    let probe = report["probe"].as_str().unwrap();
    let table = run.out_dir.path().join(format!("probe-{probe}.md"));
    assert!(std::fs::read_to_string(&table).is_ok_and(|t| t.lines().count() >= 4 + rows.len()), "{table:?}");
    rows
}

/// `--probe layouts` draws chapter 12's ids and a packed normal and depth, timed, over the same
/// pixels.
#[test]
fn probe_layouts_draws_both_lean_buffers_over_the_same_pixels() {
    let args = ["--quick", "--probe", "layouts", "--sizes", "40x30", "--spp", "1"];
    let rows = probe_rows(&args, &[], &["ids_r32ui_ms", "normal_depth_rg32ui_ms"]);
    assert_eq!(rows.len(), 1);
}

/// `--probe overlap` times the same GL and Vulkan work in two orders (on lavapipe the CPU waits
/// at every hand-over, so nothing is said of which is faster).
#[test]
fn probe_overlap_times_both_orders() {
    let args = ["--quick", "--probe", "overlap", "--sizes", "64x48", "--spp", "2"];
    let keys = ["gl_during_vulkan_ms", "gl_after_vulkan_ms", "gl_pass_alone_ms"];
    for row in probe_rows(&args, &[], &keys) {
        for key in keys {
            assert!(row["measured"][key].as_f64().is_some_and(|ms| ms > 0.0), "{key}: {row}");
        }
    }
}

/// `--probe vulkan-composite` runs chapter 12's composite as a Vulkan compute shader: timed, and
/// its picture GL's within rounding, on both hand-over paths, at a size that is not a whole
/// number of 16x16 groups, with the widest blur.
#[test]
fn probe_vulkan_composite_draws_what_gl_draws() {
    let args = ["--quick", "--probe", "vulkan-composite", "--sizes", "37x29", "--spp", "2", "--blurs", "8"];
    for env in [&[][..], &[("VKGL_HIDE_EXTENSIONS", "GL_EXT_semaphore_fd")][..]] {
        let rows = probe_rows(&args, env, &["gl_compute_ms", "vulkan_compute_ms"]);
        assert_eq!(rows.len(), 1, "{env:?}");
        assert!(rows[0]["measured"]["largest_difference"].as_u64().is_some_and(|d| d <= 2), "{env:?}");
        assert!(rows[0]["measured"]["vulkan_compute_ms"].as_f64().is_some_and(|ms| ms > 0.0), "{env:?}");
    }
}

/// `--probe patterns`: each pattern's trace timed, and its error before and after the blur.
#[test]
fn probe_patterns_measures_time_and_error_per_pattern() {
    let args = [
        "--quick",
        "--probe",
        "patterns",
        "--sizes",
        "40x30",
        "--spp",
        "2",
        "--patterns",
        "per-pixel,tile4x4",
        "--reference-rays",
        "16",
    ];
    let rows = probe_rows(&args, &[], &["ao_ms", "error_raw", "error_blurred"]);
    let patterns: Vec<&str> = rows.iter().map(|r| r["setting"]["pattern"].as_str().unwrap()).collect();
    assert_eq!(patterns, ["per-pixel", "tile4x4"]);
    for row in &rows {
        assert!(row["measured"]["error_blurred"].as_f64() < row["measured"]["error_raw"].as_f64(), "{row}");
    }
}
