//! Numerical robustness (the numerics issue): ambient occlusion that does not depend on where the
//! scene sits or how large it is, odd and extreme inputs handled or refused clearly, and work
//! skipped where a scene needs none. Every test runs the chapters headless on the software stack.

mod harness;

use harness::run_chapter;
use std::path::Path;

const AO: &str = env!("CARGO_BIN_EXE_07-ao-ray-pipeline");
const BUNNY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/bunny.obj");

/// Writes `obj` with every vertex `v x y z` replaced by `scale * v + offset`, in full f64
/// precision (the loader reads f64), and returns the new file's path.
fn transformed(obj: &str, scale: f64, offset: [f64; 3], dir: &Path, name: &str) -> String {
    let text = std::fs::read_to_string(obj).unwrap();
    let lines: Vec<String> = text
        .lines()
        .map(|line| match line.strip_prefix("v ") {
            Some(rest) => {
                let v: Vec<f64> = rest.split_whitespace().map(|c| c.parse().unwrap()).collect();
                let p: Vec<String> = (0..3).map(|a| format!("{:e}", v[a] * scale + offset[a])).collect();
                format!("v {}", p.join(" "))
            }
            None => line.to_owned(),
        })
        .collect();
    let path = dir.join(name);
    std::fs::write(&path, lines.join("\n")).unwrap();
    path.to_str().unwrap().to_owned()
}

fn ao_report(scene: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = if extra.contains(&"--size") { vec![] } else { vec!["--size", "64x64"] };
    args.extend(["--frames", "2", "--samples", "8", "--scene", scene]);
    args.extend_from_slice(extra);
    run_chapter(AO, &args, &[]).succeeded().clone()
}

/// The bunny scaled by 1e-4 .. 1e4, and moved 10,000 times its own size from the origin (at
/// three scales), has the same occlusion as the bunny where it was made. Before the fix, a
/// thousandth-scale or far-away bunny came out almost white (ao_mean 0.99 instead of 0.94): the
/// ray offset was absolute, and skipped every occluder within reach.
#[test]
fn ao_of_the_bunny_is_the_same_at_any_scale_and_distance() {
    let dir = tempfile::tempdir().unwrap();
    let reference = ao_report(BUNNY, &[]);
    let (mean, min) = (reference["ao_mean"].as_f64().unwrap(), reference["ao_min"].as_f64().unwrap());
    assert!(mean < 0.96, "the bunny occludes itself: {mean}");
    let size = 0.25; // the bunny's diagonal, near enough
    let cases = [
        (1e-4, 0.0),
        (1e-2, 0.0),
        (1e2, 0.0),
        (1e4, 0.0),
        (1.0, 1e4 * size),
        (1e-3, 1e4 * size * 1e-3),
        (1e3, 1e4 * size * 1e3),
    ];
    for (i, (scale, distance)) in cases.into_iter().enumerate() {
        // Along a diagonal that is not an axis, so every coordinate is far.
        let offset = [distance, -0.7 * distance, 0.4 * distance];
        let scene = transformed(BUNNY, scale, offset, dir.path(), &format!("bunny{i}.obj"));
        let report = ao_report(&scene, &[]);
        let radius = report["radius"].as_f64().unwrap();
        let expected_radius = reference["radius"].as_f64().unwrap() * scale;
        assert!((radius / expected_radius - 1.0).abs() < 1e-4, "scale {scale}: radius {radius}");
        let (m, n) = (report["ao_mean"].as_f64().unwrap(), report["ao_min"].as_f64().unwrap());
        // The same rays in the same frame: only rounding differs, far below Monte Carlo noise.
        assert!(
            (m - mean).abs() <= 0.003,
            "scale {scale}, {distance} from the origin: ao_mean {m}, {mean} at the origin"
        );
        assert!((n - min).abs() <= 0.1, "scale {scale}, {distance} away: ao_min {n}, {min} at the origin");
    }
}

/// Chapter 12 rebuilds each hit point from the triangle's corners instead of reading GL's
/// interpolated position: the occlusion must not depend on scale or distance either, and must
/// agree with chapter 08's on the same rays at each (the chapter checks that itself).
#[test]
fn the_fast_frame_is_the_same_at_any_scale_and_distance() {
    let dir = tempfile::tempdir().unwrap();
    let fast = env!("CARGO_BIN_EXE_12-fast-frame");
    let args = |scene: &str| {
        ["--size", "64x64", "--frames", "2", "--samples", "8", "--scene", scene].map(String::from)
    };
    let reference = run_chapter(fast, &args(BUNNY).each_ref().map(|a| a.as_str()), &[]).succeeded().clone();
    let mean = reference["visibility_mean"].as_f64().unwrap();
    for (i, (scale, distance)) in [(1e-4, 0.0), (1e4, 0.0), (1.0, 2.5e3), (1e-3, 2.5)].into_iter().enumerate()
    {
        let offset = [distance, -0.7 * distance, 0.4 * distance];
        let scene = transformed(BUNNY, scale, offset, dir.path(), &format!("bunny{i}.obj"));
        let report = run_chapter(fast, &args(&scene).each_ref().map(|a| a.as_str()), &[]).succeeded().clone();
        let m = report["visibility_mean"].as_f64().unwrap();
        assert!(
            (m - mean).abs() <= 0.003,
            "scale {scale}, {distance} away: visibility {m}, {mean} at the origin"
        );
        assert_eq!(report["checks"]["rebuilt_hits_match_the_rasterised_positions"], true, "scale {scale}");
    }
}

/// Chapter 13 reprojects with relative tolerances (a plane within 1% of the depth): its path,
/// with the model turning where it stands, must give the same occlusion at any scale and distance.
#[test]
fn the_reused_frame_is_the_same_at_any_scale_and_distance() {
    let dir = tempfile::tempdir().unwrap();
    let temporal = env!("CARGO_BIN_EXE_13-temporal-reuse");
    let args = |scene: &str| {
        ["--size", "64x64", "--frames", "6", "--cut-at", "3", "--scene", scene].map(String::from)
    };
    let run = |scene: &str| run_chapter(temporal, &args(scene).each_ref().map(|a| a.as_str()), &[]);
    let reference = run(BUNNY).succeeded().clone();
    let mean = reference["ao_mean"].as_f64().unwrap();
    for (i, (scale, distance)) in [(1e-4, 0.0), (1e4, 0.0), (1.0, 2.5e3), (1e-3, 2.5)].into_iter().enumerate()
    {
        let offset = [distance, -0.7 * distance, 0.4 * distance];
        let scene = transformed(BUNNY, scale, offset, dir.path(), &format!("bunny{i}.obj"));
        let report = run(&scene).succeeded().clone();
        let m = report["ao_mean"].as_f64().unwrap();
        assert!(
            (m - mean).abs() <= 0.003,
            "scale {scale}, {distance} away: ao_mean {m}, {mean} at the origin"
        );
        assert_eq!(report["cut_pixels_kept"], reference["cut_pixels_kept"], "scale {scale}, {distance} away");
    }
}

/// The other direction: nothing may occlude a lone plane (a hit is the plane hitting itself, or
/// "acne"), at the extremes of scale and distance.
#[test]
fn a_lone_plane_is_unoccluded_at_any_scale_and_distance() {
    let dir = tempfile::tempdir().unwrap();
    let plane = dir.path().join("plane.obj");
    std::fs::write(&plane, "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 4 3\nf 1 3 2\n").unwrap();
    for (i, (scale, distance)) in
        [(1e-4, 0.0), (1e4, 0.0), (1.0, 2e4), (1e-4, 2.0), (1e4, 2e8), (1.0, 0.3)].into_iter().enumerate()
    {
        let offset = [distance, 0.37 * distance, -0.61 * distance];
        let scene = transformed(plane.to_str().unwrap(), scale, offset, dir.path(), &format!("p{i}.obj"));
        let report = ao_report(&scene, &[]);
        assert_eq!(report["ao_min"], 1.0, "scale {scale}, {distance} away: a ray hit the plane it left");
    }
    // Seen at a grazing angle: a plane tilted 2 and 0.5 degrees out of the camera's line of sight
    // (`Camera::framing` looks along (0.55, 0.6, 1)), where a pixel spans a long stretch of it.
    let view = [0.55f64, 0.6, 1.0].map(|c| c / (0.55f64 * 0.55 + 0.36 + 1.0).sqrt());
    let side = [view[2], 0.0, -view[0]].map(|c| c / (view[0] * view[0] + view[2] * view[2]).sqrt());
    let up = [
        side[1] * view[2] - side[2] * view[1],
        side[2] * view[0] - side[0] * view[2],
        side[0] * view[1] - side[1] * view[0],
    ];
    for degrees in [2.0f64, 0.5] {
        let (s, c) = degrees.to_radians().sin_cos();
        let along: Vec<f64> = (0..3).map(|a| view[a] * c + up[a] * s).collect();
        let corner =
            |u: f64, v: f64| (0..3).map(|a| format!("{:e}", u * side[a] + v * along[a])).collect::<Vec<_>>();
        let obj: String = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
            .iter()
            .map(|&(u, v)| format!("v {}\n", corner(u, v).join(" ")))
            .collect::<String>()
            + "f 1 2 3\nf 1 3 4\n";
        let path = dir.path().join(format!("grazing{degrees}.obj"));
        std::fs::write(&path, obj).unwrap();
        let report = ao_report(path.to_str().unwrap(), &["--size", "256x256"]);
        assert!(
            report["rays_traced"].as_u64().unwrap() > 0,
            "{degrees} degrees: the plane covers some pixels"
        );
        assert_eq!(report["ao_min"], 1.0, "{degrees} degrees: a ray hit the plane it left");
    }
}

/// Triangles with no area (a degenerate one among real ones, and one whose corners coincide)
/// and normals that are zero or point inwards: the picture still comes out, with no NaN.
#[test]
fn degenerate_triangles_and_bad_normals_are_handled() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("odd.obj");
    // A plane whose normals all point down, away from the side they shade; a zero-area
    // triangle (its corners on a line) and one whose corners coincide; a small triangle just
    // above the plane, within the radius, with a zero normal among its corners.
    let obj = "o flipped\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n\
               vn 0 -1 0\nf 1//1 4//1 3//1\nf 1//1 3//1 2//1\n\
               o degenerate\nv 0 0.2 0\nv 0.2 0.2 0\nv 0.4 0.2 0\nf 5 6 7\nf 5 5 5\nf 5 6 7\n\
               o zero_normal\nv 0 0.05 0\nv 0.5 0.05 0\nv 0 0.05 0.5\nvn 0 0 0\nvn 0 1 0\n\
               f 8//2 10//3 9//3\n";
    std::fs::write(&path, obj).unwrap();
    let run = run_chapter(
        AO,
        &["--size", "48x48", "--frames", "2", "--samples", "8", "--scene", path.to_str().unwrap()],
        &[],
    );
    let report = run.succeeded();
    assert!(run.stderr.contains("zero or invalid normals"), "says it recomputed them:\n{}", run.stderr);
    // The small triangle above the plane occludes it: something below 1, nothing outside [0, 1].
    assert!(report["ao_min"].as_f64().unwrap() < 1.0, "{report}");
}

/// A scene whose vertices all coincide has no size: an error that says so (not a complaint
/// about a radius nobody gave).
#[test]
fn a_scene_without_size_is_an_error_that_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("point.obj");
    std::fs::write(&path, "v 1 2 3\nv 1 2 3\nv 1 2 3\nf 1 2 3\n").unwrap();
    let run = run_chapter(AO, &["--size", "32x32", "--scene", path.to_str().unwrap()], &[]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("coincide"), "{}", run.stderr);
    assert!(run.stderr.contains("point.obj"), "names the file:\n{}", run.stderr);
    assert!(!run.stderr.contains("panicked") && !run.stderr.contains("radius"), "{}", run.stderr);
}

/// Scenes beyond what 32-bit floats can trace (lengths are squared on the GPU): refused with the
/// size and the range, never an "infinite radius" or a blank picture.
#[test]
fn scenes_too_large_or_too_small_for_floats_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for (name, far, expected) in [
        ("huge", "1e30", "units across; 32-bit floats on the GPU handle scenes from 1e-15 to 1e15"),
        ("tiny", "1e-20", "units across; 32-bit floats on the GPU handle scenes from 1e-15 to 1e15"),
        ("beyond", "1e39", "beyond 32-bit float range"),
    ] {
        let path = dir.path().join(format!("{name}.obj"));
        std::fs::write(&path, format!("v 0 0 0\nv {far} 0 0\nv 0 {far} 0\nf 1 2 3\n")).unwrap();
        let run = run_chapter(AO, &["--size", "32x32", "--scene", path.to_str().unwrap()], &[]);
        assert_eq!(run.output.status.code(), Some(2), "{name}: {}", run.stderr);
        assert!(
            run.stderr.contains(expected) && run.stderr.contains(path.to_str().unwrap()),
            "{}",
            run.stderr
        );
    }
}

/// `--samples 0` and `--radius 0` trace nothing, say so, and give visibility 1 everywhere.
#[test]
fn no_rays_or_no_radius_skips_tracing() {
    for flag in [["--samples", "0"], ["--radius", "0"]] {
        let run = run_chapter(AO, &["--size", "48x48", "--frames", "2", flag[0], flag[1]], &[]);
        let report = run.succeeded();
        assert_eq!(report["ao_skipped"], format!("{} {}", flag[0], flag[1]));
        assert_eq!(report["checks"]["untraced_means_visibility_1"], true);
        assert_eq!(report["rays_traced"], 0);
        assert!(run.stderr.contains("no rays traced"), "{}", run.stderr);
    }
    let run = run_chapter(
        env!("CARGO_BIN_EXE_08-composite"),
        &["--size", "48x48", "--frames", "2", "--radius", "0", "--blur", "0"],
        &[],
    );
    let report = run.succeeded();
    assert_eq!(report["ao_skipped"], "--radius 0");
    assert_eq!(report["checks"]["composite_matches_cpu_reference"], true);
}

/// Every AO and scene flag at and beyond its limits: a clear error and exit 2, never a panic;
/// or, at the limit, a run that passes its checks.
#[test]
fn flags_at_and_beyond_their_limits() {
    let refused = [
        (vec!["--max-samples", "0"], "expected a number from 1 to 1073741824"),
        (vec!["--samples", "257"], "expected a number from 0 to 256"),
        (vec!["--radius", "-1"], "expected a number from 0 to 1000000"),
        (vec!["--radius", "NaN"], "expected a number from 0 to 1000000"),
        (vec!["--radius", "inf"], "expected a number from 0 to 1000000"),
        (vec!["--power", "0.5"], "expected a number from 1 to 3"),
        (vec!["--power", "-2"], "expected a number from 1 to 3"),
        (vec!["--instances", "4294967295"], "expected a number from 0 to 1000000"),
        (vec!["--size", "0x1"], "between 1 and 32768"),
    ];
    for (args, expected) in refused {
        let mut all = if args[0] == "--size" { vec![] } else { vec!["--size", "32x32"] };
        all.extend_from_slice(&args);
        let run = run_chapter(AO, &all, &[]);
        assert_eq!(run.output.status.code(), Some(2), "{args:?}: {}", run.stderr);
        assert!(run.stderr.contains(expected), "{args:?} should say {expected:?}:\n{}", run.stderr);
        assert!(!run.stderr.contains("panicked"), "{args:?}: {}", run.stderr);
    }
    // A size the device cannot hold: refused before anything exists, naming the bytes.
    for chapter in [AO, env!("CARGO_BIN_EXE_08-composite")] {
        let run = run_chapter(chapter, &["--size", "16384x16384"], &[]);
        assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
        assert!(run.stderr.contains("4294967296 bytes"), "names the bytes:\n{}", run.stderr);
        assert!(!run.stderr.contains("validation error"), "nothing was made, nothing leaks:\n{}", run.stderr);
    }
    // At the limits: one pixel, one ray, the smallest cap, no tetrahedra, the widest image.
    let report = run_chapter(AO, &["--size", "16384x8", "--samples", "1"], &[]).succeeded().clone();
    assert_eq!(report["images"][0]["width"], 16384);
    for args in [
        vec!["--size", "1x1", "--samples", "1", "--max-samples", "1", "--frames", "3"],
        vec!["--size", "32x32", "--instances", "0", "--samples", "256", "--frames", "1"],
    ] {
        let report = run_chapter(AO, &args, &[]).succeeded().clone();
        assert!(report["samples_per_pixel"].as_u64().unwrap() <= 256, "{report}");
    }
}

/// Occlusion between a floor and a wall, at one pixel, after a million rays: the running mean
/// neither drifts nor does the sample sequence collapse (in f32, `alpha * float(i)` would put
/// the R2 points on a 1/16 grid by then). The exact answer for a floor point at distance x from
/// an infinite wall, cosine-weighted rays of length R: occluded S(x/R)/pi, with
/// S(a) = acos a - a sqrt(1 - a^2).
#[test]
fn a_million_samples_converge_to_the_exact_answer() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wall.obj");
    // Floor: x in [0, 2], z in [-2, 2], facing up. Wall: x = 0, y in [0, 2], facing +x.
    let obj = "v 0 0 -2\nv 2 0 -2\nv 2 0 2\nv 0 0 2\nv 0 2 -2\nv 0 2 2\nf 1 4 3\nf 1 3 2\nf 1 5 6\nf 1 6 4\n";
    std::fs::write(&path, obj).unwrap();
    // The one pixel looks along the camera's axis through the bounds' centre (1, 1, 0), from the
    // direction `Camera::framing` uses, (0.55, 0.6, 1): it meets the floor at y = 0, where
    // x = 1 - 0.55 / 0.6, far enough from every edge for the planes to count as infinite.
    let x = 1.0 - 0.55 / 0.6;
    let radius = 0.05 * (2f64 * 2.0 + 2.0 * 2.0 + 4.0 * 4.0).sqrt();
    let a: f64 = x / radius;
    let exact = 1.0 - (a.acos() - a * (1.0 - a * a).sqrt()) / std::f64::consts::PI;
    let args = ["--size", "1x1", "--samples", "256", "--frames", "3907", "--max-samples", "1000000"];
    let mut all = args.to_vec();
    all.extend(["--scene", path.to_str().unwrap()]);
    let report = run_chapter(AO, &all, &[]).succeeded().clone();
    assert_eq!(report["samples_per_pixel"], 1_000_000);
    assert!((report["radius"].as_f64().unwrap() - radius).abs() < 1e-5, "{}", report["radius"]);
    let estimate = report["ao_min"].as_f64().unwrap(); // one pixel: its visibility, unpowered
    assert!((estimate - exact).abs() < 1e-3, "after a million rays {estimate}, exactly {exact:.5}");
}

/// Convex geometry cannot occlude itself, however thin, and two coplanar copies of a surface
/// occlude nothing: a thin slab (1e-4 of its width) and a doubled plane stay exactly unoccluded.
#[test]
fn thin_and_coplanar_geometry_casts_no_false_occlusion() {
    let dir = tempfile::tempdir().unwrap();
    let t = 1e-4;
    let slab = format!(
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv -1 {t} -1\nv 1 {t} -1\nv 1 {t} 1\nv -1 {t} 1\n\
         f 1 2 3\nf 1 3 4\nf 5 8 7\nf 5 7 6\nf 1 5 6\nf 1 6 2\nf 2 6 7\nf 2 7 3\nf 3 7 8\nf 3 8 4\nf 4 8 5\nf 4 5 1\n"
    );
    let doubled =
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 4 3\nf 1 3 2\no copy\nf 1 4 3\nf 1 3 2\nf 2 4 1\n";
    let one_triangle = "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 3 2\n";
    for (name, obj) in [("slab", slab.as_str()), ("doubled", doubled), ("one_triangle", one_triangle)] {
        let path = dir.path().join(format!("{name}.obj"));
        std::fs::write(&path, obj).unwrap();
        let report = ao_report(path.to_str().unwrap(), &[]);
        assert_eq!(report["ao_min"], 1.0, "{name}: false occlusion");
    }
}

/// Each report lists what the chapter created on the GPU; a static scene needs nothing
/// updatable, and a scene without textures needs no texture or sampler of GL's own.
#[test]
fn reports_list_resources_and_static_scenes_need_nothing_updatable() {
    for (bin, args) in [
        (AO, vec!["--size", "32x32", "--instances", "50"]),
        (env!("CARGO_BIN_EXE_08-composite"), vec!["--size", "32x32", "--instances", "50", "--blur", "0"]),
    ] {
        let run = run_chapter(bin, &args, &[]);
        let report = run.succeeded();
        let kinds: Vec<&str> =
            report["resources"].as_array().unwrap().iter().map(|r| r["kind"].as_str().unwrap()).collect();
        assert!(kinds.iter().any(|k| k.starts_with("vk_acceleration_structure: TOP_LEVEL")), "{kinds:?}");
        assert!(kinds.iter().all(|k| !k.contains("ALLOW_UPDATE") && !k.contains("update")), "{kinds:?}");
        assert!(kinds.iter().all(|k| !k.starts_with("gl_texture:") && !k.contains("sampler")), "{kinds:?}");
        let exportable =
            report["resources"].as_array().unwrap().iter().find(|r| r["kind"] == "vk_memory_exportable");
        assert!(exportable.unwrap()["bytes"].as_u64().unwrap() > 0, "{kinds:?}");
    }
}

/// The depth-aware blur at near/far ratios of 10^5 and more: the camera zoomed into the pile.
/// The blur's test is relative (a neighbour within 2% of this pixel's view depth), so it means
/// the same near and far, and the composite still matches the CPU's version of the same rule
/// pixel for pixel. (An absolute threshold on clip-space depth, as in the reference sample,
/// would see every distant surface as one depth, and blur across their edges.)
#[test]
fn the_blur_holds_at_near_far_ratios_of_1e5() {
    for zoom in ["3000", "100000"] {
        let args =
            ["--size", "64x48", "--frames", "1", "--samples", "2", "--instances", "2000", "--zoom", zoom];
        let run = run_chapter(env!("CARGO_BIN_EXE_08-composite"), &args, &[]);
        let report = run.succeeded();
        assert!(report["near_far_ratio"].as_f64().unwrap() >= 1e5, "{}", report["near_far_ratio"]);
        assert_eq!(report["checks"]["composite_matches_cpu_reference"], true);
    }
    // Both chapters that take --zoom refuse what the planes cannot hold, with one message.
    let zooming = [env!("CARGO_BIN_EXE_08-composite"), env!("CARGO_BIN_EXE_12-fast-frame")];
    for (chapter, zoom) in zooming.iter().flat_map(|c| ["0", "NaN", "1e7", "-2"].map(|z| (c, z))) {
        let run = run_chapter(chapter, &["--size", "32x32", "--zoom", zoom], &[]);
        assert_eq!(run.output.status.code(), Some(2), "{chapter} --zoom {zoom}: {}", run.stderr);
        assert!(run.stderr.contains("expected a number from 0.001 to 1000000"), "{}", run.stderr);
    }
}
