//! Chapter 12's frame in the bench: the chapter's own program, run headless with `--json` at each
//! scene, size and ray count, its GPU pass times read from its report into one more row
//! (`fast-frame`). Its own program, not its code copied in: the row measures exactly the frame
//! chapter 12 draws, with its checks passed. Chapter 13's program too, at the rays a frame that
//! reach chapter 12's error (measured by the `convergence` tool's walk of its frame). And the
//! ablation: chapter 12 with its choices undone one at a time, each with its time and its error
//! after the blur.

use crate::{Mode, Row};
use anyhow::{Context as _, Result, bail, ensure};
use common::base::cli::Size;
use common::scene::builtin::SceneKind;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Chapter 12's program and chapter 13's, which the bench runs as they are (and `convergence`,
/// whose walk of chapter 13's frame measures its error).
const FAST: &str = "12-fast-frame";
const TEMPORAL: &str = "13-temporal-reuse";

/// A chapter's binary, built beside this one (`cargo build --release` builds them all).
fn program(chapter: &str) -> Result<PathBuf> {
    let exe = std::env::current_exe().context("finding the bench's own path")?;
    let program = exe.with_file_name(chapter);
    ensure!(
        program.exists(),
        "bench runs chapter {chapter}'s program, {}, which is not built: cargo build --release --bin {chapter}",
        program.display()
    );
    Ok(program)
}

/// Runs chapter 12 with `args` and returns its report; a failed run (a check included) is an error.
fn run(args: &[String], out: &Path) -> Result<Value> {
    run_chapter(FAST, args, out)
}

/// Runs `chapter` headless with `args` and returns its report.
fn run_chapter(chapter: &str, args: &[String], out: &Path) -> Result<Value> {
    let fast = program(chapter)?;
    let output = Command::new(&fast)
        // The bench's own steps are the ones an injected failure numbers; chapter 12's own are
        // failed when it runs alone.
        .env_remove("VKGL_FAIL_AT")
        .args(["--headless", "--json", "--out"])
        .arg(out)
        .args(args)
        .output()
        .with_context(|| format!("running {}", fast.display()))?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(12).collect();
        bail!(
            "{chapter} {} exited with {}:\n{}",
            args.join(" "),
            output.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    serde_json::from_slice(&output.stdout).with_context(|| format!("reading {chapter}'s JSON report"))
}

/// The arguments that put chapter 12 at a bench setting. (With `--quick`, chapter 08's rows
/// draw the large scene with a coarse ground; chapter 12 always builds the full one.)
fn setting(scene: SceneKind, size: Size, spp: u32, frames: u32) -> Vec<String> {
    let mut args = vec!["--size".into(), format!("{}x{}", size.width, size.height)];
    args.extend(["--samples".into(), spp.to_string(), "--frames".into(), frames.to_string()]);
    if scene != SceneKind::Default {
        args.extend(["--builtin".into(), scene.name().into()]);
    }
    args
}

/// A pass's median GPU time from a chapter report (0 if the pass never ran).
fn median(report: &Value, pass: &str) -> f64 {
    report["timings_ms"][format!("{pass}_median")].as_f64().unwrap_or(0.0)
}

/// One `fast-frame` row: chapter 12's defaults at one setting. `covered`: the pixels that cast
/// rays, counted by the bench from chapter 08's G-buffers with the same camera.
pub fn row(scene: SceneKind, size: Size, spp: u32, frames: u32, covered: u64, out: &Path) -> Result<Row> {
    let report = run(&setting(scene, size, spp, frames), out)?;
    let row = row_of(&report, Mode::FastFrame, (scene, size, spp));
    let rays = spp as f64 * covered as f64;
    let grays_per_s = if row.ao_ms > 0.0 { rays / (row.ao_ms * 1e-3) / 1e9 } else { 0.0 };
    Ok(Row { grays_per_s, ..row })
}

/// Chapter 13 at chapter 12's error: at one scene and size, the fewest rays a frame (1, 2, 4 ...,
/// up to chapter 12's `spp`) at which chapter 13's mean error along its orbit is at most that of
/// chapter 12's frame at `spp` rays along the same orbit. Both errors come from the `convergence`
/// tool's walk of chapter 13's frame (`convergence temporal --error-against`), against
/// `reference` rays a pixel.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EqualError {
    pub scene: &'static str,
    pub width: u32,
    pub height: u32,
    /// Chapter 12's rays a frame, and its mean error after the blur along chapter 13's orbit.
    pub spp: u32,
    pub chapter_12_error: f64,
    /// Chapter 13's rays a frame: the fewest that reach chapter 12's error (the most tried, where
    /// none does), and its mean error.
    pub samples: u32,
    pub error: f64,
}

/// The mean error after the blur of `convergence temporal` along chapter 13's orbit without the
/// cut, `frames` long, against `reference` rays, with `extra` flags.
fn orbit_error(
    scene: SceneKind,
    size: Size,
    (frames, reference): (u32, u32),
    extra: &[String],
    out: &Path,
) -> Result<f64> {
    let mut args = vec!["temporal".to_owned(), "--size".into(), format!("{}x{}", size.width, size.height)];
    args.extend(["--frames".into(), frames.to_string(), "--cut-at".into(), "0".into()]);
    args.extend(["--error-against".into(), reference.to_string()]);
    if scene != SceneKind::Default {
        args.extend(["--builtin".into(), scene.name().into()]);
    }
    args.extend(extra.iter().cloned());
    let report = run_chapter("convergence", &args, out)?;
    report["walks"][0]["error_mean"]
        .as_f64()
        .with_context(|| format!("convergence {} measured no error", args.join(" ")))
}

/// The two `temporal-reuse` rows at one setting, at chapter 12's error (`EqualError`): chapter
/// 13's program at the rays a frame that reach the error of chapter 12's at `spp`, in each of the
/// two views its path shows. Its orbit cuts once to a closer view, where every method's frame
/// costs about twice as much, so one median over its path would fall in whichever view has more
/// frames: one row orbits without the cut (`--cut-at 0`), the other cuts at frame 1 and orbits on
/// in the closer view. The rows' `spp` is chapter 12's, whose error they match; their frames
/// trace fewer rays than that per covered pixel, so no ray rate is given.
pub fn temporal_rows(
    scene: SceneKind,
    size: Size,
    spp: u32,
    (frames, reference): (u32, u32),
    out: &Path,
) -> Result<([Row; 2], EqualError)> {
    let errors = out.join("error");
    let fresh = ["--method".to_owned(), "fresh".into(), "--samples".into(), spp.to_string()];
    let chapter_12_error = orbit_error(scene, size, (frames, reference), &fresh, &errors)?;
    let (mut samples, mut error) = (1, f64::INFINITY);
    loop {
        let ours = ["--samples".to_owned(), samples.to_string()];
        error = error.min(orbit_error(scene, size, (frames, reference), &ours, &errors)?);
        if error <= chapter_12_error || samples * 2 > spp.min(64) {
            break;
        }
        samples *= 2;
    }
    let view = |mode: Mode, cut_at: &str, out: &Path| -> Result<Row> {
        let mut args = setting(scene, size, samples, frames);
        args.extend(["--cut-at".into(), cut_at.into()]);
        let report = run_chapter(TEMPORAL, &args, out)?;
        Ok(row_of(&report, mode, (scene, size, spp)))
    };
    let rows = [
        view(Mode::TemporalReuse, "0", &out.join("orbit"))?,
        view(Mode::TemporalReuseCloser, "1", &out.join("closer"))?,
    ];
    let (scene, width, height) = (scene.name(), size.width, size.height);
    Ok((rows, EqualError { scene, width, height, spp, chapter_12_error, samples, error }))
}

/// Chapter 13 at chapter 12's error, as a markdown table.
pub fn equal_error_table(found: &[EqualError]) -> String {
    let mut table = String::from(
        "| scene | size | chapter 12: rays a frame | its mean error | chapter 13: rays a frame | its mean error |\n\
         |---|---|---:|---:|---:|---:|\n",
    );
    for e in found {
        table.push_str(&format!(
            "| {} | {}x{} | {} | {:.4} | {} | {:.4} |\n",
            e.scene, e.width, e.height, e.spp, e.chapter_12_error, e.samples, e.error
        ));
    }
    table
}

/// A row from a chapter's report: its GPU medians of the ids, the trace and the composite with
/// the overlays, and its frame's wall clock; the hand-overs are what the passes leave of it.
fn row_of(report: &Value, mode: Mode, (scene, size, spp): (SceneKind, Size, u32)) -> Row {
    let frame_ms = median(report, "frame_wall");
    let (raster_ms, ao_ms) = (median(report, "visibility"), median(report, "ao_trace"));
    let composite_ms = median(report, "composite") + median(report, "overlays");
    Row {
        mode,
        scene: scene.name(),
        width: size.width,
        height: size.height,
        spp,
        frame_ms,
        p95_ms: report["timings_ms"]["frame_wall_p95"].as_f64().unwrap_or(0.0),
        raster_ms,
        handoff_ms: (frame_ms - raster_ms - ao_ms - composite_ms).max(0.0),
        ao_ms,
        composite_ms,
        grays_per_s: 0.0,
    }
}

// ANCHOR: ablation
/// Chapter 12's choices, undone one at a time (the flags that undo them).
pub const STEPS: [(&str, &[&str]); 4] = [
    ("lean buffer + compute composite", &["--pattern", "per-pixel", "--blas", "per-mesh"]),
    ("+ one flat BLAS", &["--pattern", "per-pixel", "--blas", "flat"]),
    ("+ 4x4 blocks of one run (chapter 12)", &["--pattern", "tile4x4", "--blas", "flat"]),
    ("(8x8 tiles of one rotation instead)", &["--pattern", "tile", "--blas", "flat"]),
];

/// One line of the ablation: a step's times (GPU medians) and its error after the blur.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Step {
    pub step: &'static str,
    pub flags: String,
    pub frame_ms: f64,
    pub raster_ms: f64,
    pub ao_ms: f64,
    pub composite_ms: f64,
    /// RMS error of one frame's occlusion against `reference_rays`, before and after the blur.
    pub error_raw: f64,
    pub error_blurred: f64,
}

/// Every step at one setting of the default scene, each with `--error-against reference`.
pub fn ablation(size: Size, spp: u32, frames: u32, reference: u32, out: &Path) -> Result<Vec<Step>> {
    let mut steps = Vec::new();
    for (step, flags) in STEPS {
        let mut args = setting(SceneKind::Default, size, spp, frames);
        args.extend(flags.iter().map(|f| f.to_string()));
        args.extend(["--error-against".into(), reference.to_string()]);
        let report = run(&args, out)?;
        let error = &report["ao_rms_error"];
        steps.push(Step {
            step,
            flags: flags.join(" "),
            frame_ms: median(&report, "frame_wall"),
            raster_ms: median(&report, "visibility"),
            ao_ms: median(&report, "ao_trace"),
            composite_ms: median(&report, "composite") + median(&report, "overlays"),
            error_raw: error["raw"].as_f64().unwrap_or(f64::NAN),
            error_blurred: error["blurred"].as_f64().unwrap_or(f64::NAN),
        });
        eprintln!("bench: ablation '{step}' done");
    }
    Ok(steps)
}
// ANCHOR_END: ablation

/// The ablation as a markdown table, chapter 08's zero-copy row first.
pub fn table(chapter_08: Option<&Row>, steps: &[Step]) -> String {
    let mut table = String::from(
        "| step | frame ms | raster ms | AO ms | composite ms | error | after blur |\n|---|---:|---:|---:|---:|---:|---:|\n",
    );
    if let Some(r) = chapter_08 {
        let line = format!(
            "| chapter 08 (zero-copy) | {:.2} | {:.2} | {:.2} | {:.2} | as the next | as the next |\n",
            r.frame_ms, r.raster_ms, r.ao_ms, r.composite_ms
        );
        table.push_str(&line);
    }
    for s in steps {
        table.push_str(&format!(
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.4} | {:.4} |\n",
            s.step, s.frame_ms, s.raster_ms, s.ao_ms, s.composite_ms, s.error_raw, s.error_blurred
        ));
    }
    table
}
