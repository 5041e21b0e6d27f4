//! Chapter 04: the compute triangle, headless (snapshot, animation, leak test) and in a real
//! window under Xvfb.

mod harness;

use harness::{
    DEFAULT_TOLERANCE, Xvfb, assert_images_match, assert_report_snapshot, run_chapter, run_chapter_with,
};

const BIN: &str = env!("CARGO_BIN_EXE_04-compute-triangle");

#[test]
fn ch04_compute_triangle() {
    let run = run_chapter(BIN, &["--size", "160x120", "--time", "0"], &[]);
    let report = run.succeeded();
    assert_eq!(report["vulkan"]["extensions"], serde_json::json!(["VK_KHR_external_memory_fd"]));
    assert_eq!(report["uuids_match"], true);
    assert_eq!(report["window"], false);
    assert_report_snapshot("04-compute-triangle", report);
    assert_images_match(report, DEFAULT_TOLERANCE);
}

#[test]
fn ch04_time_moves_the_picture() {
    let picture = |time: &str| {
        let run = run_chapter(BIN, &["--size", "160x120", "--time", time], &[]);
        let path = run.succeeded()["images"][0]["path"].as_str().unwrap().to_owned();
        image::open(&path).unwrap_or_else(|e| panic!("{path}: {e}")).to_rgba8()
    };
    let (at_0, at_1_5) = (picture("0"), picture("1.5"));
    assert_eq!(at_0.dimensions(), at_1_5.dimensions());
    let changed = at_0.pixels().zip(at_1_5.pixels()).filter(|(a, b)| a != b).count();
    let pixels = at_0.pixels().len();
    // The triangle covers about a fifth of the frame; almost all of it changes in 1.5 s.
    assert!(changed * 10 > pixels, "only {changed} of {pixels} pixels differ between --time 0 and 1.5");
}

/// Two frames 1/60 s apart may not differ visibly in a small picture: the check that the
/// animation moves is then not made, and the chapter says so; from 2/60 s apart it is made.
#[test]
fn ch04_frames_too_close_to_differ_are_not_compared() {
    let close = run_chapter(BIN, &["--size", "16x16", "--frames", "2", "--time", "5"], &[]);
    assert!(close.succeeded()["checks"].get("frames_differ_over_time").is_none());
    assert!(close.stderr.contains("frames_differ_over_time is not checked"), "{}", close.stderr);
    let apart = run_chapter(BIN, &["--size", "16x16", "--frames", "3", "--time", "5"], &[]);
    assert_eq!(apart.succeeded()["checks"]["frames_differ_over_time"], true);
}

#[test]
fn ch04_resizing_leaks_nothing() {
    let args = ["--size", "160x120", "--time", "0", "--frames", "40", "--resize-every", "1"];
    let run = run_chapter(BIN, &args, &[]);
    let report = run.succeeded();
    assert_eq!(report["checks"]["nothing_grows_across_resizes"], true);
    assert_eq!(report["resizes"], 39);
    assert_eq!(report["frames"], 40);
    assert_eq!(report["images"].as_array().unwrap().len(), 40);
    assert_eq!(report["images"][0]["name"], "04-compute-triangle-frame0");
}

#[test]
fn ch04_resize_every_needs_a_whole_cycle() {
    let run = run_chapter(BIN, &["--frames", "3", "--resize-every", "1"], &[]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("--resize-every 1 needs more than 3 --frames"), "{}", run.stderr);
}

#[test]
fn ch04_without_a_display_runs_headless() {
    // No --headless and no display: the chapter says so and runs headless.
    let run = run_chapter_with(BIN, &["--size", "64x48"], &[]);
    let report = run.succeeded();
    assert_eq!(report["window"], false);
    assert!(run.stderr.contains("no display"), "says why it runs headless:\n{}", run.stderr);
}

#[test]
fn ch04_in_a_window_under_xvfb() {
    let Some(xvfb) = Xvfb::start("ch04_in_a_window_under_xvfb") else { return };
    // No --headless: a display exists, so the chapter opens a window there. `--time 0` steps the
    // animation 1/60 s a frame: on real time, five frames drawn within a few milliseconds of
    // each other (a fast machine) could barely move, and the check below would fail by chance.
    let args = ["--size", "160x120", "--frames", "5", "--time", "0"];
    let run = run_chapter_with(BIN, &args, &[("DISPLAY", &xvfb.display)]);
    drop(xvfb);
    let report = run.succeeded();
    assert_eq!(report["window"], true, "{}", run.stderr);
    assert_eq!(report["uuids_match"], true);
    assert_eq!(report["frames"], 5);
    // The window's back buffer, read before the first and the last swap.
    let names: Vec<&str> =
        report["images"].as_array().unwrap().iter().map(|i| i["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["04-compute-triangle-frame0", "04-compute-triangle-frame4"]);
    assert_eq!(report["checks"]["frames_differ_over_time"], true);
}

/// A window is never refused its size: at 8x6 the picture's checks say they were not judged,
/// and why (headless, the size is refused).
#[test]
fn ch04_tiny_window_reports_what_it_cannot_judge() {
    let Some(xvfb) = Xvfb::start("ch04_tiny_window_reports_what_it_cannot_judge") else { return };
    let run = run_chapter_with(BIN, &["--size", "8x6", "--frames", "3"], &[("DISPLAY", &xvfb.display)]);
    drop(xvfb);
    let report = run.succeeded();
    assert_eq!(report["window"], true, "{}", run.stderr);
    for check in ["centre_pixel_inside_triangle", "triangle_shows_computed_image", "frames_differ_over_time"]
    {
        assert!(report["checks"].get(check).is_none(), "{check} judged at 8x6");
        let why = report["not_judged"][check].as_str().unwrap_or_default();
        assert!(why.contains("8x6 frame is too small"), "{check}: {why}");
    }
    let headless = run_chapter_with(BIN, &["--headless", "--size", "8x6"], &[]);
    assert_eq!(headless.output.status.code(), Some(2), "{}", headless.stderr);
}

#[test]
fn ch04_names_a_display_without_gl_for_the_gpu() {
    // What a GPU without its own X driver meets (an NVIDIA GPU beside Xvfb): the X server offers
    // no GLX and EGL finds no driver for it. The chapter must say so, with the way out, and exit 2.
    let test = "ch04_names_a_display_without_gl_for_the_gpu";
    let Some(xvfb) = Xvfb::start_with(test, &["-extension", "GLX"]) else { return };
    let display = xvfb.display.clone();
    let env = [("DISPLAY", display.as_str()), ("__EGL_VENDOR_LIBRARY_FILENAMES", "/nonexistent/egl.json")];
    let run = run_chapter_with(BIN, &["--size", "64x48", "--frames", "2"], &env);
    drop(xvfb);
    assert_eq!(run.output.status.code(), Some(2), "exit 2:\n{}", run.stderr);
    assert!(!run.stderr.contains("panicked"), "no panic:\n{}", run.stderr);
    let expected = format!("no GL configuration for a window on X display {display}");
    assert!(run.stderr.contains(&expected), "names the display:\n{}", run.stderr);
    assert!(run.stderr.contains("--headless"), "names the way out:\n{}", run.stderr);
    assert!(!run.stderr.contains("has not been destroyed"), "nothing leaked:\n{}", run.stderr);
}
