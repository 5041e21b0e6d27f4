//! What every chapter test shares: run a chapter binary headless, snapshot its report, and
//! compare the images it wrote with reference PNGs.
//!
//! The tests pin Mesa's software stack (lavapipe + llvmpipe) when it is installed, so the
//! snapshots mean the same thing on every machine; set `VKGL_TEST_NATIVE=1` to run the chapters
//! on the machine's own driver instead (the checks still apply, the snapshots may then differ).
//!
//! A missing or changed reference fails. To write references, run with `INSTA_UPDATE=always`
//! (reports) and `VKGL_UPDATE_IMAGES=1` (images), then look at every file that changed.

#![allow(dead_code)] // each test crate uses part of the harness

pub mod flags;
pub mod sizes;
pub mod x11;

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

pub struct Run {
    pub output: Output,
    /// The report printed with `--json`, when the chapter printed one.
    pub report: Option<Value>,
    pub stderr: String,
    /// Where the chapter was told to write its images.
    pub out_dir: tempfile::TempDir,
}

impl Run {
    /// The report of a run that must have succeeded; panics with the chapter's stderr otherwise.
    pub fn succeeded(&self) -> &Value {
        assert!(self.output.status.success(), "chapter failed with {}:\n{}", self.output.status, self.stderr);
        let report = self.report.as_ref().expect("a successful --json run prints a report");
        for (name, ok) in report["checks"].as_object().expect("checks is an object") {
            assert_eq!(ok, &Value::Bool(true), "check {name} failed:\n{}", self.stderr);
        }
        assert_eq!(report["validation"]["errors"], 0, "validation errors:\n{}", self.stderr);
        if std::env::var_os("CI").is_some() {
            // CI installs the layer (.ci/deps); a run without it would prove nothing.
            assert_eq!(report["validation"]["layer"], true, "CI must run with VK_LAYER_KHRONOS_validation");
        }
        report
    }
}

/// Runs `bin` (from `env!("CARGO_BIN_EXE_<name>")`) with `--headless --json --out <temp dir>`
/// plus `args`, with extra environment variables `env`.
pub fn run_chapter(bin: &str, args: &[&str], env: &[(&str, &str)]) -> Run {
    let mut all = vec!["--headless"];
    all.extend_from_slice(args);
    run_chapter_with(bin, &all, env)
}

/// Like [`run_chapter`], without `--headless`: the chapter opens a window if `env` gives it a
/// display (see [`Xvfb`]), and says why it runs headless otherwise.
pub fn run_chapter_with(bin: &str, args: &[&str], env: &[(&str, &str)]) -> Run {
    run_chapter_in(Command::new(bin), bin, args, env)
}

/// Like [`run_chapter`], started in `dir` instead of the checkout: what a user who runs a
/// binary from elsewhere sees.
pub fn run_chapter_from(dir: &Path, bin: &str, args: &[&str]) -> Run {
    let mut command = Command::new(bin);
    command.current_dir(dir);
    let mut all = vec!["--headless"];
    all.extend_from_slice(args);
    run_chapter_in(command, bin, &all, &[])
}

/// Like [`run_chapter_with`], with `drive` run while the chapter runs (a user's keys to its
/// window, say); `drive` must end the chapter (Esc). Should `drive` panic, the chapter is killed
/// and its stderr shown.
pub fn run_chapter_driven(bin: &str, args: &[&str], env: &[(&str, &str)], drive: impl FnOnce()) -> Run {
    let out_dir = tempfile::tempdir().expect("temporary directory");
    let mut command = chapter_command(Command::new(bin), &out_dir, args, env);
    let child = command.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn();
    let mut chapter = child.unwrap_or_else(|e| panic!("could not start {bin}: {e}"));
    let driven = std::panic::catch_unwind(std::panic::AssertUnwindSafe(drive));
    if driven.is_err() {
        let _ = chapter.kill();
    }
    let output = chapter.wait_with_output().expect("the chapter's output");
    let run = collect(output, out_dir);
    if let Err(panic) = driven {
        eprintln!("the chapter's stderr:\n{}", run.stderr);
        std::panic::resume_unwind(panic);
    }
    run
}

fn run_chapter_in(command: Command, bin: &str, args: &[&str], env: &[(&str, &str)]) -> Run {
    let out_dir = tempfile::tempdir().expect("temporary directory");
    let mut command = chapter_command(command, &out_dir, args, env);
    let output = command.output().unwrap_or_else(|e| panic!("could not start {bin}: {e}"));
    collect(output, out_dir)
}

/// `command` with `--json --out <out_dir>` and `args`, on the software stack, with `env`.
fn chapter_command(
    mut command: Command,
    out_dir: &tempfile::TempDir,
    args: &[&str],
    env: &[(&str, &str)],
) -> Command {
    command.args(["--json", "--out"]).arg(out_dir.path()).args(args);
    pin_software_stack(&mut command);
    // The validation layer's synchronisation checks too (hazards between commands, barriers
    // that miss a stage), which are off by default; Debian 12's layer (1.3.239) reads this.
    if std::env::var_os("VK_LAYER_ENABLES").is_none() {
        command.env("VK_LAYER_ENABLES", "VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT");
    }
    command.env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY");
    command.envs(env.iter().copied());
    command
}

fn collect(output: Output, out_dir: tempfile::TempDir) -> Run {
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let report = if stdout.trim().is_empty() {
        None
    } else {
        Some(
            serde_json::from_str(&stdout)
                .unwrap_or_else(|e| panic!("stdout is not one JSON document ({e}):\n{stdout}")),
        )
    };
    Run { output, report, stderr, out_dir }
}

/// Points the Vulkan loader at lavapipe and EGL at Mesa, unless `VKGL_TEST_NATIVE` is set.
pub fn pin_software_stack(command: &mut Command) {
    if std::env::var_os("VKGL_TEST_NATIVE").is_some() {
        return;
    }
    let icds = std::fs::read_dir("/usr/share/vulkan/icd.d").into_iter().flatten().flatten();
    if let Some(lavapipe) = icds
        .map(|e| e.path())
        .find(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("lvp_icd")))
    {
        command.env("VK_DRIVER_FILES", lavapipe);
    }
    let mesa_egl = Path::new("/usr/share/glvnd/egl_vendor.d/50_mesa.json");
    if mesa_egl.exists() {
        command.env("__EGL_VENDOR_LIBRARY_FILENAMES", mesa_egl);
    }
}

/// Snapshots a report with everything that differs between machines of the same software stack
/// redacted: device and driver names and versions, UUIDs, file descriptor numbers, timings.
pub fn assert_report_snapshot(name: &str, report: &Value) {
    insta::with_settings!({
        snapshot_path => "../snapshots",
        prepend_module_to_snapshot => false,
        omit_expression => true,
    }, {
        insta::assert_json_snapshot!(name, report, {
            ".vulkan.device" => "[device]",
            ".vulkan.driver" => "[driver]",
            ".vulkan.api" => "[version]",
            ".vulkan.device_uuid" => "[uuid]",
            ".vulkan.driver_uuid" => "[uuid]",
            ".gl.renderer" => "[renderer]",
            ".gl.version" => "[version]",
            ".gl.device_uuid" => "[uuid]",
            ".gl.driver_uuid" => "[uuid]",
            ".validation.layer" => "[checked in Run::succeeded]",
            ".images[].path" => "[out]",
            // Rates come from GPU timestamps, like timings_ms.
            ".mrays_per_s" => "[rate]",
            ".mrays_per_s_launched" => "[rate]",
            ".texture_mb_per_s" => insta::dynamic_redaction(redact_values("[rate]")),
            ".timings_ms" => insta::dynamic_redaction(redact_values("[ms]")),
            ".fds" => insta::dynamic_redaction(redact_values("[fd]")),
        });
    });
}

/// Keeps a map's keys (which timings, which fds) and hides the values (how long, which number).
fn redact_values(
    placeholder: &'static str,
) -> impl Fn(insta::internals::Content, insta::internals::ContentPath) -> insta::internals::Content {
    use insta::internals::Content;
    move |value, _path| match value {
        Content::Map(entries) => {
            Content::Map(entries.into_iter().map(|(key, _)| (key, Content::from(placeholder))).collect())
        }
        other => other,
    }
}

/// The workspace's tests/snapshots, for the root package's tests and for chapter 15's (a
/// package of its own, in chapters/15-wgpu) alike.
pub fn snapshot_dir() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = manifest.ancestors().find(|dir| dir.join("Cargo.lock").exists()).unwrap_or(manifest);
    root.join("tests/snapshots")
}

/// How far an image may be from its reference, in FLIP error (0 = identical, 1 = maximal).
#[derive(Clone, Copy, Debug)]
pub struct Tolerance {
    pub mean: f32,
    /// (percentile, largest error allowed at it)
    pub percentile: (f32, f32),
}

/// llvmpipe and NVIDIA (H100/H200, driver 580) round colours differently by one step in 255.
/// Such a difference over a whole image scores a FLIP mean of about 0.024 and a 99th percentile of
/// about 0.04 (`image_comparison` in tests/chapters.rs measures it); a changed region scores far
/// higher where it lies, which the percentile catches even when the region is small.
pub const DEFAULT_TOLERANCE: Tolerance = Tolerance { mean: 0.04, percentile: (0.99, 0.15) };

/// Compares every image the report lists with `tests/snapshots/<name>.png`; a report that lists
/// none fails.
pub fn assert_images_match(report: &Value, tolerance: Tolerance) {
    let images = report["images"].as_array().expect("images is an array");
    // A run that wrote no picture would pass a loop over its pictures: it is a failure instead.
    assert!(!images.is_empty(), "{} lists no image: there is nothing to compare", report["chapter"]);
    for image in images {
        let name = image["name"].as_str().expect("image name");
        let actual = Path::new(image["path"].as_str().expect("image path"));
        let reference = snapshot_dir().join(format!("{name}.png"));
        if let Err(message) = compare_image(actual, &reference, tolerance) {
            panic!("{name}: {message}");
        }
    }
}

/// Compares two PNGs with the FLIP perceptual metric. On a mismatch writes `<reference>-actual.png`
/// and `<reference>-difference.png` (FLIP's error map) beside the reference and says so.
pub fn compare_image(actual: &Path, reference: &Path, tolerance: Tolerance) -> Result<(), String> {
    let actual_image =
        image::open(actual).map_err(|e| format!("cannot read {}: {e}", actual.display()))?.to_rgb8();
    if !reference.exists() {
        if std::env::var_os("VKGL_UPDATE_IMAGES").is_some() {
            actual_image.save(reference).map_err(|e| format!("cannot write {}: {e}", reference.display()))?;
            eprintln!("wrote new reference {}", reference.display());
            return Ok(());
        }
        return Err(format!(
            "no reference image {}; run with VKGL_UPDATE_IMAGES=1 to write it, then look at it",
            reference.display()
        ));
    }
    let expected =
        image::open(reference).map_err(|e| format!("cannot read {}: {e}", reference.display()))?.to_rgb8();
    let sibling = |suffix: &str| reference.with_file_name(format!("{}-{suffix}.png", stem(reference)));
    if expected.dimensions() != actual_image.dimensions() {
        actual_image.save(sibling("actual")).ok();
        return Err(format!(
            "size {:?} differs from the reference's {:?}; wrote {}",
            actual_image.dimensions(),
            expected.dimensions(),
            sibling("actual").display()
        ));
    }
    let (w, h) = expected.dimensions();
    let error_map = nv_flip::flip(
        nv_flip::FlipImageRgb8::with_data(w, h, expected.as_raw()),
        nv_flip::FlipImageRgb8::with_data(w, h, actual_image.as_raw()),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    );
    let mut pool = nv_flip::FlipPool::from_image(&error_map);
    let mean = pool.mean();
    let (p, limit) = tolerance.percentile;
    let at_p = pool.get_percentile(p, false); // unweighted: the error below which p of the pixels lie
    if mean <= tolerance.mean && at_p <= limit {
        return Ok(());
    }
    actual_image.save(sibling("actual")).ok();
    let difference = error_map.apply_color_lut(&nv_flip::magma_lut());
    image::RgbImage::from_raw(w, h, difference.to_vec())
        .expect("FLIP returns w*h RGB pixels")
        .save(sibling("difference"))
        .ok();
    Err(format!(
        "FLIP mean {mean:.4} (allowed {}), {}th percentile {at_p:.4} (allowed {limit}); wrote {} and {}",
        tolerance.mean,
        p * 100.0,
        sibling("actual").display(),
        sibling("difference").display()
    ))
}

fn stem(path: &Path) -> String {
    path.file_stem().and_then(|s| s.to_str()).unwrap_or("image").to_owned()
}

/// An X server without a screen, for tests that open real windows. Killed when dropped, so a
/// failing test leaves no X server behind.
/// A test that cannot run here because a tool it needs is missing. In CI, which installs every
/// tool (`bash .ci/deps --tests`), that is a failure: a skip there would pass a check that never
/// ran. Elsewhere it says so on stderr and, under `bash .ci/test`, adds a line to the file named by
/// `VKGL_SKIPPED`, which that script counts as skipped, not passed, in its closing line.
pub fn skip(test: &str, why: &str) {
    let line = match skip_line(std::env::var_os("CI").is_some(), test, why) {
        Ok(line) => line,
        Err(fail) => panic!("{fail}"),
    };
    eprintln!("skipping {line}");
    if let Some(file) = std::env::var_os("VKGL_SKIPPED") {
        use std::io::Write as _;
        let mut file =
            std::fs::OpenOptions::new().append(true).create(true).open(file).expect("VKGL_SKIPPED");
        // One write of one line: tests run on many threads.
        file.write_all(format!("{line}\n").as_bytes()).expect("writing VKGL_SKIPPED");
    }
}

/// What [`skip`] decides: the line that counts the skip, or, in CI, the failure.
pub fn skip_line(ci: bool, test: &str, why: &str) -> Result<String, String> {
    if ci {
        Err(format!(
            "{test} cannot run: {why}; CI installs it (bash .ci/deps --tests), so it must not be skipped"
        ))
    } else {
        Ok(format!("{test}: {why}"))
    }
}

pub struct Xvfb {
    child: Child,
    /// The `DISPLAY` to give the chapter, such as ":1".
    pub display: String,
}

impl Xvfb {
    /// Starts one on a free display. `None` (after [`skip`] said so) only when Xvfb is not
    /// installed and this is not CI, which installs it (`.ci/deps`) and must run these tests.
    pub fn start(test: &str) -> Option<Xvfb> {
        Xvfb::start_with(test, &[])
    }

    /// Like [`Xvfb::start`], with extra server arguments (`-extension GLX` turns GLX off).
    pub fn start_with(test: &str, extra: &[&str]) -> Option<Xvfb> {
        // -displayfd: Xvfb picks a free display number and writes it once it accepts clients.
        let started = Command::new("Xvfb")
            .args(["-displayfd", "1", "-screen", "0", "1024x768x24", "-nolisten", "tcp"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn();
        let mut child = match started {
            Ok(child) => child,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                skip(test, "no Xvfb binary (apt-get install xvfb)");
                return None;
            }
            Err(e) => panic!("could not start Xvfb: {e}"),
        };
        let mut number = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut number).expect("Xvfb's display number");
        assert!(!number.trim().is_empty(), "Xvfb wrote no display number");
        Some(Xvfb { child, display: format!(":{}", number.trim()) })
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Every file under `dir`, at any depth, whose name ends in `.{extension}`, unsorted. Links are
/// skipped: `book/src` links to the sources, which are not pages.
pub fn files_ending(dir: &Path, extension: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).flatten() {
        let path = entry.path();
        if entry.file_type().is_ok_and(|t| t.is_symlink()) {
            continue;
        }
        if path.is_dir() {
            found.extend(files_ending(&path, extension));
        } else if path.extension().is_some_and(|e| e == extension) {
            found.push(path);
        }
    }
    found
}

/// Fails unless `scan` finds nothing in any Rust file of `chapters/` and `common/src/` (given the
/// file's path from the repository's root, and its text, it returns one line per finding); the
/// message is `what`, then every finding.
pub fn assert_no_source_has(what: &str, scan: impl Fn(&str, &str) -> Vec<String>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = files_ending(&root.join("chapters"), "rs");
    files.extend(files_ending(&root.join("common/src"), "rs"));
    files.sort();
    assert!(files.len() > 50, "found only {} Rust files under chapters and common/src", files.len());
    let found: Vec<String> = files
        .iter()
        .flat_map(|path| {
            let name = path.strip_prefix(root).unwrap().display().to_string();
            scan(&name, &std::fs::read_to_string(path).unwrap())
        })
        .collect();
    assert!(found.is_empty(), "{what}:\n{}", found.join("\n"));
}

/// The targets of the fds a chapter listed as left open after it ran (`fds: left open after the
/// chapter ran: [...]`), sorted, or None if it got as far as listing none. The listing's own handle
/// on /proc/<pid>/fd is left out: new at each listing, at whichever number is free then (chapter
/// 14's viewer closes its socket in between, so it moves).
pub fn fds_listed(stderr: &str) -> Option<Vec<String>> {
    let line = stderr.lines().find_map(|l| l.strip_prefix("fds: left open after the chapter ran: "))?;
    let mut targets: Vec<String> = line
        .split("\", \"")
        .filter_map(|fd| fd.split_once(" -> "))
        .map(|(_, t)| t.trim_end_matches("\"]").to_owned())
        .filter(|t| !(t.starts_with("/proc/") && t.ends_with("/fd")))
        .collect();
    targets.sort();
    Some(targets)
}

/// A package's own failure injection (chapters 15 and 16, whose binaries `tests/errors.rs` cannot
/// name): each fallible step `bin` reaches with `args`, failed the first and the last time a run
/// reaches it, must exit 2 naming the step, with no panic, no validation message, nothing left
/// alive and no fd left open beyond those a run that fails nothing leaves (the driver's).
/// `expect`: a step the listing must include (the package's own lesson).
pub fn every_fallible_step_fails_cleanly(bin: &str, args: &[&str], expect: Option<&str>) {
    let listing = run_chapter(bin, args, &[("VKGL_FAIL_AT", "list")]);
    listing.succeeded();
    let steps: Vec<(u32, String)> = listing
        .stderr
        .lines()
        .filter_map(|l| l.strip_prefix("fail step ")?.split_once(": "))
        .map(|(n, what)| (n.parse().unwrap(), what.to_owned()))
        .collect();
    assert!(steps.len() > 10, "too few steps: {steps:?}");
    if let Some(expect) = expect {
        assert!(steps.iter().any(|(_, what)| what.contains(expect)), "no step of {expect:?}: {steps:?}");
    }
    let mut first_and_last = std::collections::BTreeMap::new();
    for (n, what) in &steps {
        first_and_last.entry(what.clone()).and_modify(|(_, last)| *last = *n).or_insert((*n, *n));
    }
    let fds = |stderr: &str| -> Vec<String> {
        fds_listed(stderr).unwrap_or_else(|| panic!("no list of the fds left:\n{stderr}"))
    };
    let kept_by_driver = fds(&listing.stderr);
    let mut problems = Vec::new();
    for (what, (first, last)) in first_and_last {
        for n in if first == last { vec![first] } else { vec![first, last] } {
            let run = run_chapter(bin, args, &[("VKGL_FAIL_AT", &n.to_string())]);
            let named = format!("injected failure at step {n}: {what} (VKGL_FAIL_AT={n})");
            let mut wrong = Vec::new();
            if run.output.status.code() != Some(2) {
                wrong.push(format!("exit {:?}", run.output.status.code()));
            }
            if !run.stderr.lines().any(|l| l.starts_with("error: ") && l.contains(&named)) {
                wrong.push("no error naming the step".into());
            }
            for bad in ["panicked", "has not been destroyed", "validation error"] {
                if run.stderr.contains(bad) {
                    wrong.push(format!("stderr contains {bad:?}"));
                }
            }
            if !run.stderr.contains("resources: alive after the chapter ran: []") {
                wrong.push("resources left alive".into());
            }
            let left: Vec<String> =
                fds(&run.stderr).into_iter().filter(|fd| !kept_by_driver.contains(fd)).collect();
            if !left.is_empty() {
                wrong.push(format!("fds left open: {left:?}"));
            }
            if !wrong.is_empty() {
                problems.push(format!("step {n} ({what}): {}\n{}", wrong.join(", "), run.stderr));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n\n"));
}
