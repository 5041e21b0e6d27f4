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
