//! A frame's passes, GL's and Vulkan's, on one clock, as JSON and SVG: `bench --timeline N`
//! (chapter 08's frame and chapter 12's) and `convergence temporal --timeline N` (chapter 13's). A frame is GL's raster pass, Vulkan's
//! trace, then GL's composite (with the overlays).
//!
//! GL's passes are stamped with `glQueryCounter(GL_TIMESTAMP)` before and after; Vulkan's trace
//! with the frame's own timestamps. The two APIs count on clocks of their own, so the offset
//! between them is measured once at the end: GL's time is read, Vulkan writes a timestamp, GL's
//! time is read again, and Vulkan's stamp lies between the two readings.

use super::timestamps::{Timestamps, median_p95};
use crate::base::commands::Commands;
use crate::base::gl::{Owned, create_n};
use crate::base::vulkan::VulkanContext;
use crate::instruments::output;
use anyhow::{Result, ensure};
use ash::vk;
use glow::HasContext;
use plotters::prelude::*;
use std::path::Path;
use std::rc::Rc;

/// Stamps GL's clock at point `which` (0 and 1 around the raster pass, 2 and 3 around the
/// composite and overlays) of the timeline's frame `slot`, when there is a timeline and this
/// frame is in it.
pub fn stamp(timeline: &Option<Timeline>, slot: Option<u32>, which: usize) {
    stamp_into(timeline.as_ref(), slot, which);
}

/// [`stamp`], for a timeline held by reference.
pub fn stamp_into(timeline: Option<&Timeline>, slot: Option<u32>, which: usize) {
    if let (Some(t), Some(slot)) = (timeline, slot) {
        unsafe { t.gl.query_counter(*t.queries[slot as usize][which], glow::TIMESTAMP) };
    }
}

/// One pass of one frame, in nanoseconds of its API's clock.
#[derive(Clone, Copy, Debug)]
struct Span {
    frame: u32,
    vulkan: bool,
    pass: &'static str,
    start: f64,
    end: f64,
}

/// The stamps of the last `frames` frames (GL's as queries until they are read).
pub struct Timeline {
    frames: u32,
    /// GL's two passes, as the report and the picture name them: the raster pass, the composite.
    passes: [&'static str; 2],
    /// Per frame: the raster pass (before, after), the composite and overlays (before, after).
    queries: Vec<[Owned<glow::Query>; 4]>,
    vulkan: Vec<(u32, [f64; 2])>,
    gl: Rc<glow::Context>,
}

impl Timeline {
    /// For the last `frames` frames, GL's passes named `passes` (the raster pass, the composite).
    pub fn new(gl: &Rc<glow::Context>, frames: u32, passes: [&'static str; 2]) -> Result<Self> {
        let mut timeline =
            Timeline { frames, passes, queries: Vec::new(), vulkan: Vec::new(), gl: gl.clone() };
        for _ in 0..frames {
            let made = create_n(gl, "glGenQueries for the timeline", 4, |gl| unsafe { gl.create_query() })?;
            timeline.queries.push(made.try_into().map_err(|_| ()).expect("four queries"));
        }
        Ok(timeline)
    }

    /// The trace's start and end of frame `slot`, read once its fence has signalled.
    pub fn trace_done(&mut self, vk: &VulkanContext, slot: u32, stamps: &Timestamps) -> Result<()> {
        self.vulkan.push((slot, stamps.read_ns(vk)?));
        Ok(())
    }

    /// The frame slot of frame `frame` of `count`, if it is one of the last `frames`.
    pub fn slot(&self, frame: u32, count: u32) -> Option<u32> {
        (frame + self.frames >= count && frame < count).then(|| frame + self.frames - count)
    }

    /// GL's clock minus Vulkan's, in nanoseconds, and how far off it may be: Vulkan stamps once,
    /// between two readings of GL's clock; the tightest of a few tries counts. Both APIs idle.
    fn offset(&self, vk: &VulkanContext, commands: &Commands, stamps: &Timestamps) -> Result<(f64, f64)> {
        let mut best = (0.0, f64::INFINITY);
        for _ in 0..8 {
            let before = unsafe { self.gl.get_parameter_i64(glow::TIMESTAMP) } as f64;
            commands.run_once(vk, |cb| {
                stamps.reset(vk, cb);
                stamps.start(vk, cb, vk::PipelineStageFlags::TOP_OF_PIPE);
                stamps.end(vk, cb);
            })?;
            let after = unsafe { self.gl.get_parameter_i64(glow::TIMESTAMP) } as f64;
            let [stamped, _] = stamps.read_ns(vk)?;
            let half = (after - before) / 2.0;
            if half < best.1 {
                best = ((before + after) / 2.0 - stamped, half);
            }
        }
        Ok(best)
    }

    /// Reads everything (both APIs idle), puts it on GL's clock, writes `<out>.json` and
    /// `<out>.svg` (`out` a path without extension), and returns the gaps between the passes,
    /// for the report.
    pub fn finish(
        self,
        vk: &VulkanContext,
        commands: &Commands,
        stamps: &Timestamps,
        out: &Path,
    ) -> Result<serde_json::Map<String, serde_json::Value>> {
        let [raster, composite] = self.passes;
        let (offset, uncertainty) = self.offset(vk, commands, stamps)?;
        let mut spans = Vec::new();
        for (slot, q) in self.queries.iter().enumerate() {
            let read =
                |i: usize| unsafe { self.gl.get_query_parameter_u64(*q[i], glow::QUERY_RESULT) } as f64;
            let frame = slot as u32;
            spans.push(Span { frame, vulkan: false, pass: raster, start: read(0), end: read(1) });
            spans.push(Span { frame, vulkan: false, pass: composite, start: read(2), end: read(3) });
        }
        for &(frame, [start, end]) in &self.vulkan {
            spans.push(Span {
                frame,
                vulkan: true,
                pass: "ao_trace",
                start: start + offset,
                end: end + offset,
            });
        }
        ensure!(!spans.is_empty(), "--timeline: no frame was recorded");
        let origin = spans.iter().map(|s| s.start).fold(f64::INFINITY, f64::min);
        let ms = |ns: f64| (ns - origin) / 1e6;
        // The GPU's idle time at each hand-over: from the raster pass to the trace, from the
        // trace to the composite (negative: the passes overlapped).
        let find = |frame, pass| spans.iter().find(|s| s.frame == frame && s.pass == pass);
        let (mut to_vulkan, mut to_gl) = (Vec::new(), Vec::new());
        for frame in 0..self.frames {
            if let (Some(drawn), Some(trace), Some(shown)) =
                (find(frame, raster), find(frame, "ao_trace"), find(frame, composite))
            {
                to_vulkan.push((trace.start - drawn.end) / 1e6);
                to_gl.push((shown.start - trace.end) / 1e6);
            }
        }
        let mut summary = serde_json::Map::new();
        summary.insert("frames".into(), self.frames.into());
        summary.insert("clock_offset_uncertainty_us".into(), (uncertainty / 1e3).into());
        summary.insert(format!("gap_{raster}_to_trace_ms_median"), median_p95(&to_vulkan).0.into());
        summary.insert(format!("gap_trace_to_{composite}_ms_median"), median_p95(&to_gl).0.into());
        let rows: Vec<_> = spans
            .iter()
            .map(|s| {
                let api = if s.vulkan { "vulkan" } else { "gl" };
                serde_json::json!({ "frame": s.frame, "api": api, "pass": s.pass, "start_ms": ms(s.start), "end_ms": ms(s.end) })
            })
            .collect();
        if let Some(dir) = out.parent() {
            output::create_dir(dir)?;
        }
        let path = out.with_extension("json");
        output::write_file(&path, serde_json::to_string_pretty(&rows)?)?;
        let path = out.with_extension("svg");
        let bars: Vec<_> = spans.iter().map(|s| (s.vulkan, s.pass, ms(s.start), ms(s.end))).collect();
        output::draw_plot(&path, |path| draw(path, &bars, self.passes))?;
        eprintln!("wrote {}.{{json,svg}}", out.display());
        Ok(summary)
    }
}

/// Two lanes, GL above and Vulkan below, one bar per pass, time in milliseconds across.
fn draw(path: &Path, bars: &[(bool, &str, f64, f64)], [raster, _]: [&str; 2]) -> Result<()> {
    let end = bars.iter().map(|b| b.3).fold(0.0, f64::max);
    let root = SVGBackend::new(path, (900, 220)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("GPU passes on one clock: GL (top), Vulkan (bottom)", ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..end * 1.02, 0.0..2.0)?;
    chart
        .configure_mesh()
        .x_desc("ms")
        .y_labels(2)
        .y_label_formatter(&|y| if *y >= 1.0 { "GL".into() } else { "Vulkan".into() })
        .disable_y_mesh()
        .draw()?;
    chart.draw_series(bars.iter().map(|&(vulkan, pass, start, end)| {
        let (low, high) = if vulkan { (0.2, 0.8) } else { (1.2, 1.8) };
        let colour = match (vulkan, pass == raster) {
            (true, _) => RED,
            (false, true) => BLUE,
            (false, false) => GREEN,
        };
        Rectangle::new([(start, low), (end, high)], colour.filled())
    }))?;
    root.present()?;
    Ok(())
}
