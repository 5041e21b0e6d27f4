//! Chapter 04: the compute triangle, headless (snapshot, animation, leak test) and in a real
//! window under Xvfb.

mod harness;

use harness::{DEFAULT_TOLERANCE, Run, assert_images_match, assert_report_snapshot, run_chapter};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

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

#[test]
fn ch04_resizing_leaks_nothing() {
    let args = ["--size", "160x120", "--time", "0", "--frames", "40", "--resize-every", "1"];
    let run = run_chapter(BIN, &args, &[]);
    let report = run.succeeded();
    assert_eq!(report["checks"]["no_fd_growth_across_resizes"], true);
    assert_eq!(report["fds"]["after_first_cycle"], report["fds"]["at_end"], "{}", run.stderr);
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
    let out = tempfile::tempdir().unwrap();
    let mut command = Command::new(BIN);
    command.args(["--size", "64x48", "--json", "--out"]).arg(out.path());
    command.env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY");
    let run = finish(command, out);
    let report = run.succeeded();
    assert_eq!(report["window"], false);
    assert!(run.stderr.contains("no display"), "says why it runs headless:\n{}", run.stderr);
}

/// Kills Xvfb when dropped, so that a failing test leaves no X server behind.
struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn ch04_in_a_window_under_xvfb() {
    // -displayfd: Xvfb picks a free display number and writes it once it accepts clients.
    let started = Command::new("Xvfb")
        .args(["-displayfd", "1", "-screen", "0", "1024x768x24", "-nolisten", "tcp"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn();
    let mut xvfb = match started {
        Ok(child) => Xvfb(child),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound && std::env::var_os("CI").is_none() => {
            eprintln!(
                "skipping ch04_in_a_window_under_xvfb: no Xvfb binary (apt-get install xvfb; CI has it)"
            );
            return;
        }
        Err(e) => panic!("could not start Xvfb: {e}"),
    };
    let mut display = String::new();
    BufReader::new(xvfb.0.stdout.take().unwrap()).read_line(&mut display).expect("Xvfb's display number");
    let display = format!(":{}", display.trim());
    assert!(display.len() > 1, "Xvfb wrote no display number");

    let out = tempfile::tempdir().unwrap();
    let mut command = Command::new(BIN);
    // No --headless: a display exists, so the chapter opens a window there.
    command.args(["--size", "160x120", "--frames", "5", "--json", "--out"]).arg(out.path());
    command.env("DISPLAY", &display).env_remove("WAYLAND_DISPLAY");
    let run = finish(command, out);
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

/// Runs `command` with the software stack pinned as the harness pins it, and collects its report.
fn finish(mut command: Command, out_dir: tempfile::TempDir) -> Run {
    if std::env::var_os("VKGL_TEST_NATIVE").is_none() {
        let icds = std::fs::read_dir("/usr/share/vulkan/icd.d").into_iter().flatten().flatten();
        if let Some(lavapipe) = icds
            .map(|e| e.path())
            .find(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("lvp_icd")))
        {
            command.env("VK_DRIVER_FILES", lavapipe);
        }
        let mesa_egl = std::path::Path::new("/usr/share/glvnd/egl_vendor.d/50_mesa.json");
        if mesa_egl.exists() {
            command.env("__EGL_VENDOR_LIBRARY_FILENAMES", mesa_egl);
        }
    }
    let output = command.output().expect("the chapter starts");
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let report = (!stdout.trim().is_empty()).then(|| {
        serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{stdout}"))
    });
    Run { output, report, stderr, out_dir }
}
