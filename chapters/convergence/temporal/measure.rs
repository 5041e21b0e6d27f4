//! Chapter 13's measurements along the path: each frame's error after the blur against a
//! converged trace of that same frame, its GPU times, and the comparison of methods as a
//! table, a CSV and two plots.

use anyhow::{Context as _, Result, ensure};
use common::instruments::{fail, output};
use common::interop::handoff::Apis;
use common::scene::Camera;
use fast_frame::check::read_picture;
use fast_frame::composite::{ComputeComposite, Uniforms, View};
use fast_frame::trace::{Pattern, Rays, SurfaceTracer};
use fast_frame::visibility::Targets;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// One frame of a walk along the path.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameRecord {
    pub frame: u32,
    /// The frame's wall-clock time as the CPU saw it, ms: from a run that measures no error
    /// (one that does reads pictures back between frames).
    pub wall_ms: Option<f64>,
    /// GPU time of the frame's passes (ids, rays, composite, overlays), ms.
    pub gpu_ms: Option<f64>,
    pub ao_ms: Option<f64>,
    /// RMS error of the blurred occlusion against the converged trace, over covered pixels.
    pub rmse: Option<f64>,
    /// FLIP between the final pictures (built with `--features flip`; else `null`).
    pub flip: Option<f64>,
}

// ANCHOR: views
/// The medians of some of a walk's frames, each over the frames that have that time.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Medians {
    pub frame_wall_ms: Option<f64>,
    pub gpu_ms: Option<f64>,
    pub ao_ms: Option<f64>,
}

impl Medians {
    fn of(frames: &[&FrameRecord]) -> Medians {
        let of = |time: fn(&FrameRecord) -> Option<f64>| {
            median(&frames.iter().filter_map(|f| time(f)).collect::<Vec<_>>())
        };
        Medians { frame_wall_ms: of(|f| f.wall_ms), gpu_ms: of(|f| f.gpu_ms), ao_ms: of(|f| f.ao_ms) }
    }
}

/// A whole walk: one method along the path, and what it sums up to. The orbit shows two views:
/// the one before the cut, and a closer one from the cut on, where every method's frame costs
/// about twice as much. One median over both would fall in whichever view has more frames, or
/// between them; so the times are summed up per view, and over the whole path as a mean, which
/// weighs every frame as the mean error does.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Walk {
    pub method: String,
    pub frames: Vec<FrameRecord>,
    /// The frames before the cut (all of them, on a path without one).
    pub before_cut: Medians,
    /// The frames from the cut on.
    pub after_cut: Option<Medians>,
    /// The mean GPU time of a frame over the path, the cut's own frame included.
    pub gpu_mean_ms: Option<f64>,
    pub error_mean: Option<f64>,
    pub error_worst: Option<f64>,
    pub flip_mean: Option<f64>,
}
// ANCHOR_END: views

/// The median of `samples`, as the reports compute it (none of nothing).
pub fn median(samples: &[f64]) -> Option<f64> {
    (!samples.is_empty()).then(|| common::clocks::timestamps::median_p95(samples).0)
}

fn mean(samples: &[f64]) -> Option<f64> {
    (!samples.is_empty()).then(|| samples.iter().sum::<f64>() / samples.len() as f64)
}

impl Walk {
    /// A walk's frames summed up, the path's cut at `cut`; errors over every `every`th frame.
    pub fn new(method: String, frames: Vec<FrameRecord>, cut: Option<u32>, every: u32) -> Walk {
        // The mean over the path: over every `every`th frame alone, so that the frames measured
        // besides them around the cut (for `frames_to_recover`) do not weigh the cut twice.
        let along = || frames.iter().filter(|f| f.frame % every == 0);
        let errors: Vec<f64> = along().filter_map(|f| f.rmse).collect();
        let flips: Vec<f64> = along().filter_map(|f| f.flip).collect();
        let worst = frames.iter().filter_map(|f| f.rmse).reduce(f64::max);
        let mut walk = Walk {
            method,
            frames,
            before_cut: Medians::default(),
            after_cut: None,
            gpu_mean_ms: None,
            error_mean: mean(&errors),
            error_worst: worst,
            flip_mean: mean(&flips),
        };
        walk.sum_up_times(cut);
        walk
    }

    /// The medians before and after `cut`, and the mean GPU time, from the frames' times.
    fn sum_up_times(&mut self, cut: Option<u32>) {
        let (before, after): (Vec<&FrameRecord>, Vec<&FrameRecord>) =
            self.frames.iter().partition(|f| cut.is_none_or(|c| f.frame < c));
        self.before_cut = Medians::of(&before);
        self.after_cut = (!after.is_empty()).then(|| Medians::of(&after));
        self.gpu_mean_ms = mean(&self.frames.iter().filter_map(|f| f.gpu_ms).collect::<Vec<_>>());
    }

    /// How many frames after `cut` the error takes to come back within `within` (None: never,
    /// or not measured).
    pub fn frames_to_recover(&self, cut: u32, within: f64) -> Option<u32> {
        self.frames
            .iter()
            .filter(|f| f.frame >= cut)
            .find(|f| f.rmse.is_some_and(|e| e <= within))
            .map(|f| f.frame - cut)
    }
}

/// Whether a frame's error is measured: every `every`th frame, and every frame just after a cut
/// (where the error changes fastest).
pub fn measured(frame: u32, every: u32, cut: Option<u32>) -> bool {
    frame % every == 0 || cut.is_some_and(|c| (c.saturating_sub(1)..c + 16).contains(&frame))
}

// ANCHOR: error
/// The converged trace of a frame, kept for the other methods walking the same path: the
/// blurred occlusion as the composite shows it, which pixels are covered, and the final picture.
#[derive(Default)]
pub struct References(BTreeMap<u32, Converged>);

pub struct Converged {
    occlusion: Vec<u8>,
    covered: Vec<bool>,
    picture: Vec<u8>,
}

/// What measuring a frame's error uses: the composite (to blur the two alike), chapter 12's
/// tracer (for the converged trace: per-pixel rotations of another salt, so that its errors are
/// independent of every method's) and the frame's settings.
pub struct ErrorProbe<'a> {
    pub composite: &'a ComputeComposite,
    pub uniforms: Uniforms,
    pub reference: u32,
    pub radius: f32,
    pub scene_scale: f32,
}

impl ErrorProbe<'_> {
    /// The RMS difference of the frame's blurred occlusion (the surface as the frame left it)
    /// from the converged one's, over the covered pixels, and FLIP between the two final
    /// pictures (where built with it). Overwrites the surface.
    pub fn measure(
        &self,
        apis: Apis,
        (targets, tracer): (&Targets, &mut SurfaceTracer),
        (camera, frame): (&Camera, u32),
        references: &mut References,
    ) -> Result<(f64, FlipJob)> {
        let gl = &apis.gl.gl;
        let shown = |view: View| {
            let uniforms = Uniforms { view, far_depth: camera.far, ..self.uniforms };
            self.composite.draw(gl, targets, &uniforms);
            read_picture(gl, targets)
        };
        let (ours, picture) = (shown(View::Ao), shown(View::Final));
        if let std::collections::btree_map::Entry::Vacant(slot) = references.0.entry(frame) {
            let rays = Rays {
                samples: self.reference.min(256),
                radius: self.radius,
                scene_scale: self.scene_scale,
                pattern: Pattern::PerPixel,
                salt: 1,
            };
            tracer.retrace(apis, targets, camera, rays, self.reference)?;
            let covered = fast_frame::check::read_ids(gl, targets).iter().map(|&id| id != 0).collect();
            let (occlusion, picture) = (shown(View::Ao), shown(View::Final));
            slot.insert(Converged { occlusion, covered, picture });
        }
        let Converged { occlusion: converged, covered, picture: converged_picture } = &references.0[&frame];
        let (mut sum, mut n) = (0.0, 0usize);
        for (i, _) in covered.iter().enumerate().filter(|(_, c)| **c) {
            sum += ((ours[i * 4] as f64 - converged[i * 4] as f64) / 255.0).powi(2);
            n += 1;
        }
        anyhow::ensure!(n > 0, "frame {frame}: the scene covers no pixel, so it has no error to measure");
        let size = (targets.extent.width, targets.extent.height);
        Ok(((sum / n as f64).sqrt(), flip_job(converged_picture, picture, size)))
    }
}

/// FLIP of one frame, worked out on a thread of its own: on one core it takes seconds at 4K,
/// longer than a walk's frame, so the walk goes on and collects it later. Without the `flip`
/// feature, no job: the report says `null`.
pub type FlipJob = Option<std::thread::JoinHandle<Option<f64>>>;

#[cfg(any(test, feature = "flip"))]
fn flip_job(reference: &[u8], picture: Vec<u8>, size: (u32, u32)) -> FlipJob {
    let reference = reference.to_vec();
    Some(std::thread::spawn(move || flip_mean(&reference, &picture, size)))
}

#[cfg(not(any(test, feature = "flip")))]
fn flip_job(_: &[u8], _: Vec<u8>, _: (u32, u32)) -> FlipJob {
    None
}

/// The FLIP jobs a walk has started, at most one per core running at once, each for the record
/// it belongs to.
#[derive(Default)]
pub struct Flips(std::collections::VecDeque<(usize, std::thread::JoinHandle<Option<f64>>)>);

impl Flips {
    /// Adds `job` for `records[index]`, and, while more are running than there are cores,
    /// finishes the oldest into its record.
    pub fn add(&mut self, job: FlipJob, index: usize, records: &mut [FrameRecord]) -> Result<()> {
        self.0.extend(job.map(|job| (index, job)));
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        while self.0.len() > cores {
            self.finish_oldest(records)?;
        }
        Ok(())
    }

    /// Every job finished into its record.
    pub fn finish(mut self, records: &mut [FrameRecord]) -> Result<()> {
        while !self.0.is_empty() {
            self.finish_oldest(records)?;
        }
        Ok(())
    }

    fn finish_oldest(&mut self, records: &mut [FrameRecord]) -> Result<()> {
        if let Some((index, job)) = self.0.pop_front() {
            let flip = job.join().map_err(|_| anyhow::anyhow!("FLIP's thread panicked"))?;
            records[index].flip = flip;
        }
        Ok(())
    }
}

/// FLIP's mean over two RGBA8 pictures of `size` (the alpha left out), at FLIP's default viewing
/// conditions (67 pixels per degree).
#[cfg(any(test, feature = "flip"))]
fn flip_mean(reference: &[u8], test: &[u8], (width, height): (u32, u32)) -> Option<f64> {
    let rgb = |p: &[u8]| -> Vec<u8> { p.chunks_exact(4).flat_map(|c| [c[0], c[1], c[2]]).collect() };
    let image = |p: &[u8]| nv_flip::FlipImageRgb8::with_data(width, height, &rgb(p));
    let map = nv_flip::flip(image(reference), image(test), nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    Some(nv_flip::FlipPool::from_image(&map).mean() as f64)
}
// ANCHOR_END: error

/// compare.md, compare.csv and compare.svg (error per frame) and compare-time.svg (mean error
/// against mean GPU time per frame), for every walk.
pub fn write(dir: &Path, walks: &[Walk], cut: Option<u32>, device: &str) -> Result<String> {
    output::create_dir(dir)?;
    let mut csv = format!("{CSV_HEADER}\n");
    for w in walks {
        for f in &w.frames {
            let o = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
            let (wall, gpu, ao, rmse, flip) = (o(f.wall_ms), o(f.gpu_ms), o(f.ao_ms), o(f.rmse), o(f.flip));
            writeln!(csv, "\"{}\",{},{wall},{gpu},{ao},{rmse},{flip}", w.method, f.frame)?;
        }
    }
    let base = walks.first().and_then(|w| w.error_mean);
    let mut table = format!("Measured on {device}.\n\n");
    table.push_str(
        "| method | frame ms (wall), before the cut | from the cut on | GPU ms, before the cut | from the cut on \
         | GPU ms, mean over the path | mean error | worst error | mean FLIP | frames back within 1.5x |\n",
    );
    table.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for w in walks {
        let o = |v: Option<f64>, d: usize| v.map_or("-".into(), |v| format!("{v:.d$}"));
        let back = match (cut, base) {
            (Some(c), Some(e)) => w.frames_to_recover(c, 1.5 * e).map_or("never".into(), |k| k.to_string()),
            _ => "-".into(),
        };
        let after = w.after_cut.unwrap_or_default();
        writeln!(
            table,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {back} |",
            w.method,
            o(w.before_cut.frame_wall_ms, 2),
            o(after.frame_wall_ms, 2),
            o(w.before_cut.gpu_ms, 2),
            o(after.gpu_ms, 2),
            o(w.gpu_mean_ms, 2),
            o(w.error_mean, 4),
            o(w.error_worst, 4),
            o(w.flip_mean, 4)
        )?;
    }
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        output::write_file(&path, text)
    };
    write("compare.csv", &csv)?;
    write("compare.md", &table)?;
    if walks.iter().any(|w| w.error_mean.is_some()) {
        let path = dir.join("compare.svg");
        output::draw_plot(&path, |path| plot_per_frame(path, walks, device))?;
        let path = dir.join("compare-time.svg");
        output::draw_plot(&path, |path| plot_against_time(path, walks, device))?;
    }
    eprintln!("wrote {}/compare.{{md,csv,svg}}", dir.display());
    Ok(table)
}

/// The header of compare.csv, as [`write`] writes it.
const CSV_HEADER: &str = "method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip";

/// Each method's times, frame by frame, from the compare.csv at `path` of a run without
/// `--error-against` (`--times-from`): a run that measures the error reads frames back between
/// frames, and FLIP keeps the CPU busy, both of which slow the GPU.
pub fn read_times(path: &Path) -> Result<Times> {
    let text = fail::call("reading --times-from", || std::fs::read_to_string(path))
        .with_context(|| format!("reading {}", path.display()))?;
    parse_times(&text).with_context(|| format!("{} (--times-from)", path.display()))
}

/// Per method, per frame: the wall clock, GPU and AO times, as far as the frame has them.
pub type Times = BTreeMap<String, BTreeMap<u32, [Option<f64>; 3]>>;

/// [`read_times`] on the text of a compare.csv.
fn parse_times(text: &str) -> Result<Times> {
    let mut lines = text.lines();
    ensure!(
        lines.next() == Some(CSV_HEADER),
        "not a compare.csv of this chapter: its first line is not {CSV_HEADER}"
    );
    let mut times = Times::new();
    for (n, line) in lines.enumerate() {
        // `"chapter 13, 2 rays",frame,wall,gpu,ao,rmse,flip`: the method is quoted, and holds a comma.
        let (method, rest) = line
            .strip_prefix('"')
            .and_then(|l| l.split_once("\","))
            .with_context(|| format!("line {}: no quoted method", n + 2))?;
        let fields: Vec<&str> = rest.split(',').collect();
        ensure!(fields.len() == 6, "line {}: {} fields after the method, not 6", n + 2, fields.len());
        let frame =
            fields[0].parse().with_context(|| format!("line {}: the frame is not a number", n + 2))?;
        let time = |i: usize| fields[i].parse::<f64>().ok();
        times.entry(method.to_owned()).or_default().insert(frame, [time(1), time(2), time(3)]);
    }
    ensure!(times.values().flat_map(|t| t.values()).flatten().any(|t| t.is_some()), "no frame has a time");
    Ok(times)
}

/// Each walk's frames given the times `times` has for the same frame of the same method, and
/// summed up again (`cut`: the path's).
pub fn take_times(walks: &mut [Walk], times: &Times, cut: Option<u32>) -> Result<()> {
    for walk in walks {
        let theirs = times.get(&walk.method).with_context(|| {
            format!(
                "--times-from has no times for '{}': write it with --compare and the same flags",
                walk.method
            )
        })?;
        for f in &mut walk.frames {
            let &[wall, gpu, ao] = theirs.get(&f.frame).with_context(|| {
                format!(
                    "--times-from has no frame {} of '{}': write it with --compare and the same --frames",
                    f.frame, walk.method
                )
            })?;
            (f.wall_ms, f.gpu_ms, f.ao_ms) = (wall, gpu, ao);
        }
        walk.sum_up_times(cut);
    }
    Ok(())
}

const COLOURS: [RGBColor; 6] = [RED, MAGENTA, RGBColor(230, 140, 0), BLUE, CYAN, GREEN];

// ANCHOR: plot
/// Error after the blur at every measured frame, one line per method.
fn plot_per_frame(path: &Path, walks: &[Walk], device: &str) -> Result<()> {
    let points = |w: &Walk| -> Vec<(f64, f64)> {
        w.frames.iter().filter_map(|f| f.rmse.map(|e| (f.frame as f64, e))).collect()
    };
    let last = walks.iter().flat_map(|w| &w.frames).map(|f| f.frame).max().unwrap_or(1) as f64;
    let worst = walks.iter().filter_map(|w| w.error_worst).fold(0.0, f64::max).max(1e-3);
    let root = SVGBackend::new(path, (720, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("AO error after the blur, frame by frame ({device})"), ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..last, 0.0..worst * 1.1)?;
    chart.configure_mesh().x_desc("frame along the path").y_desc("RMSE of visibility").draw()?;
    for (i, w) in walks.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        chart
            .draw_series(LineSeries::new(points(w), colour.stroke_width(2)))?
            .label(w.method.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}

/// Mean error over the path against the mean GPU time of a frame over it: one point per method.
fn plot_against_time(path: &Path, walks: &[Walk], device: &str) -> Result<()> {
    let points: Vec<(f64, f64, usize)> = walks
        .iter()
        .enumerate()
        .filter_map(|(i, w)| Some((w.gpu_mean_ms?, w.error_mean?, i)))
        .filter(|(t, e, _)| *t > 0.0 && *e > 0.0)
        .collect();
    let caption = format!("Mean AO error against GPU time per frame ({device})");
    let axes = ("mean GPU time per frame, ms", "mean RMSE over the path");
    let labels: (output::TickLabel, output::TickLabel) = (&|v| format!("{v:.2}"), &|v| format!("{v:.3}"));
    let span = points.iter().map(|&(t, e, _)| (t, e));
    output::log_log_plot(path, ((720, 420), &caption), axes, labels, span, |chart| {
        for &(t, e, i) in &points {
            let colour = COLOURS[i % COLOURS.len()];
            chart
                .draw_series([Circle::new((t, e), 5, colour.filled())])?
                .label(walks[i].method.clone())
                .legend(move |(x, y)| Circle::new((x + 8, y), 4, colour.filled()));
        }
        Ok(())
    })
}
// ANCHOR_END: plot

#[cfg(test)]
mod tests {
    use super::*;

    /// Each method's times frame by frame, an empty field none; anything but a compare.csv
    /// refused.
    #[test]
    fn times_are_read_back_from_a_compare_csv() {
        let csv = "method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip\n\
                   \"chapter 13, 2 rays\",0,13.0,12.5,9.5,0.02,\n\
                   \"chapter 13, 2 rays\",1,5.5,5.0,2.5,,\n\
                   \"chapter 12, 16 rays\",0,,,,0.01,\n\
                   \"chapter 12, 16 rays\",1,14.5,14.0,11.0,,\n";
        let times = parse_times(csv).unwrap();
        assert_eq!(times["chapter 13, 2 rays"][&1], [Some(5.5), Some(5.0), Some(2.5)]);
        assert_eq!(times["chapter 12, 16 rays"][&0], [None, None, None]);
        assert_eq!(times["chapter 12, 16 rays"][&1], [Some(14.5), Some(14.0), Some(11.0)]);
        // llvmpipe's: no GPU time of a whole frame.
        let ao_only =
            parse_times("method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip\n\"chapter 13, 1 ray\",0,3.0,,2.5,,\n")
                .unwrap();
        assert_eq!(ao_only["chapter 13, 1 ray"][&0], [Some(3.0), None, Some(2.5)]);
        assert!(parse_times("frame,gpu_ms\n1,2\n").is_err());
        // The header of a build before the wall clock was kept per frame.
        assert!(parse_times("method,frame,gpu_ms,ao_ms,rmse,flip\n\"chapter 13, 1 ray\",0,1,1,,\n").is_err());
        assert!(parse_times("method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip\nchapter 13,0,1,1,1,,\n").is_err());
        assert!(
            parse_times("method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip\n\"chapter 13, 1 ray\",x,1,1,1,,\n")
                .is_err()
        );
        assert!(parse_times("method,frame,wall_ms,gpu_ms,ao_ms,rmse,flip\n").is_err());
    }

    fn record(frame: u32, wall: f64, gpu: f64) -> FrameRecord {
        FrameRecord {
            frame,
            wall_ms: Some(wall),
            gpu_ms: Some(gpu),
            ao_ms: Some(gpu / 2.0),
            rmse: None,
            flip: None,
        }
    }

    /// A path of two views: each view's medians come from its own frames alone, however many
    /// each has, and the mean GPU time weighs every frame, the cut's too.
    #[test]
    fn each_view_of_the_path_has_its_own_medians() {
        // 3 frames of a quick view, the cut's frame (slow), then 5 of a view twice as costly.
        let mut frames: Vec<FrameRecord> = (0..3).map(|f| record(f, 1.8 + f as f64 * 0.01, 1.4)).collect();
        frames.push(record(3, 90.0, 12.0));
        frames.extend((4..9).map(|f| record(f, 2.6, 2.1)));
        let walk = Walk::new("chapter 13, 2 rays".into(), frames.clone(), Some(3), 1);
        assert_eq!(walk.before_cut.frame_wall_ms, Some(1.81));
        assert_eq!(walk.before_cut.gpu_ms, Some(1.4));
        assert_eq!(walk.before_cut.ao_ms, Some(0.7));
        let after = walk.after_cut.unwrap();
        assert_eq!((after.frame_wall_ms, after.gpu_ms), (Some(2.6), Some(2.1)));
        let mean = (3.0 * 1.4 + 12.0 + 5.0 * 2.1) / 9.0;
        assert!((walk.gpu_mean_ms.unwrap() - mean).abs() < 1e-12);
        // No cut: one view, every frame in it.
        let whole = Walk::new("m".into(), frames, None, 1);
        assert_eq!(whole.after_cut, None);
        assert_eq!(whole.before_cut.frame_wall_ms, Some(2.6));
    }

    /// `--times-from`: every frame takes the time run's times for the same frame, and the views
    /// are summed up from those; a frame the time run did not draw is refused, naming it.
    #[test]
    fn times_from_another_run_replace_each_frames() {
        let frames: Vec<FrameRecord> = (0..4)
            .map(|frame| FrameRecord {
                frame,
                wall_ms: None,
                gpu_ms: None,
                ao_ms: None,
                rmse: Some(0.01),
                flip: None,
            })
            .collect();
        let mut walks = vec![Walk::new("m".into(), frames, Some(2), 1)];
        let mut times = Times::new();
        let run: BTreeMap<u32, [Option<f64>; 3]> =
            (0..4).map(|f| (f, [Some(2.0 + f as f64), Some(1.0 + f as f64), Some(0.5)])).collect();
        times.insert("m".into(), run.clone());
        take_times(&mut walks, &times, Some(2)).unwrap();
        assert_eq!(walks[0].frames[3].wall_ms, Some(5.0));
        // Of two, the median the reports take is the upper one.
        assert_eq!(walks[0].before_cut.frame_wall_ms, Some(3.0));
        assert_eq!(walks[0].after_cut.unwrap().gpu_ms, Some(4.0));
        assert_eq!(walks[0].error_mean, Some(0.01));
        let short: BTreeMap<u32, [Option<f64>; 3]> = run.into_iter().take(3).collect();
        times.insert("m".into(), short);
        let error = take_times(&mut walks, &times, Some(2)).unwrap_err();
        assert!(format!("{error}").contains("no frame 3 of 'm'"), "{error}");
        let error = take_times(&mut walks, &Times::new(), Some(2)).unwrap_err();
        assert!(format!("{error}").contains("no times for 'm'"), "{error}");
    }

    /// FLIP sees nothing between a picture and itself, and sees a changed region.
    #[test]
    fn flip_sees_a_difference_and_no_other() {
        let grey: Vec<u8> = [128u8, 128, 128, 255].repeat(32 * 32);
        let mut marked = grey.clone();
        marked[..4 * 32 * 8].iter_mut().step_by(4).for_each(|r| *r = 255);
        assert_eq!(super::flip_mean(&grey, &grey, (32, 32)), Some(0.0));
        assert!(super::flip_mean(&grey, &marked, (32, 32)).is_some_and(|e| e > 0.05));
    }

    /// Jobs finished on other threads, more at once than there are cores, land in their own
    /// records: each record gets its own frame's FLIP, and a record without a job keeps none.
    #[test]
    fn flips_land_in_their_own_records() {
        let grey: Vec<u8> = [128u8, 128, 128, 255].repeat(16 * 16);
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut records: Vec<super::FrameRecord> = (0..cores as u32 * 2 + 3)
            .map(|frame| super::FrameRecord {
                frame,
                wall_ms: None,
                gpu_ms: None,
                ao_ms: None,
                rmse: None,
                flip: None,
            })
            .collect();
        let mut flips = super::Flips::default();
        for i in 0..records.len() {
            if i % 3 == 2 {
                continue; // a frame not measured
            }
            // Frame i's picture differs from the reference in i rows: FLIP grows with i.
            let mut picture = grey.clone();
            picture[..4 * 16 * i.min(16)].iter_mut().step_by(4).for_each(|r| *r = 255);
            flips.add(super::flip_job(&grey, picture, (16, 16)), i, &mut records).unwrap();
        }
        flips.finish(&mut records).unwrap();
        for (i, record) in records.iter().enumerate() {
            let expected = (i % 3 != 2).then(|| {
                let mut picture = grey.clone();
                picture[..4 * 16 * i.min(16)].iter_mut().step_by(4).for_each(|r| *r = 255);
                super::flip_mean(&grey, &picture, (16, 16)).unwrap()
            });
            assert_eq!(record.flip, expected, "record {i}");
        }
    }
}
