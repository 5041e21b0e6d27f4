//! Per-pass GPU times: how long each pass of a frame ran on the GPU, over many frames, reported
//! as median and 95th percentile (`timings_ms` in the report: `<pass>_median`, `<pass>_p95`).
//!
//! Measuring must not change what it measures, so nothing here makes the CPU wait for the GPU:
//! GL's `GL_TIME_ELAPSED` queries are read a few frames later, once `GL_QUERY_RESULT_AVAILABLE`
//! says so ([`GlPassTimer`]), and Vulkan's timestamps are read after the fence wait the frame
//! already has ([`VkPassTimer`]).

use crate::base::commands;
use crate::base::gl::{Owned, create, create_n};
use crate::base::vulkan::VulkanContext;
use crate::clocks::timestamps::{Timestamps, median_p95};
use crate::instruments::report::Report;
use anyhow::{Context as _, Result};
use ash::vk;
use glow::HasContext as _;
use std::collections::VecDeque;
use std::rc::Rc;

/// Every pass's GPU times, in the order the passes first ran, and the frames' wall-clock times.
#[derive(Debug)]
pub struct PassTimes {
    passes: Vec<(&'static str, Vec<f64>)>,
    /// How many answers each pass had thrown away as impossible ([`PassTimes::reject`]).
    rejected: Vec<(&'static str, u32)>,
    /// When the current frame started (for `frame_wall`).
    frame_started: std::time::Instant,
}

impl PassTimes {
    pub fn new() -> Self {
        PassTimes { passes: Vec::new(), rejected: Vec::new(), frame_started: std::time::Instant::now() }
    }

    /// Ends a frame: adds `frame_wall`, the wall-clock time since the last frame ended (or since
    /// `new`), which is the whole frame as the CPU sees it, waits included.
    pub fn frame_done(&mut self) {
        let now = std::time::Instant::now();
        self.add("frame_wall", (now - self.frame_started).as_secs_f64() * 1e3);
        self.frame_started = now;
    }

    /// The most samples kept per pass: a window that runs for hours forgets the oldest half.
    const KEEP: usize = 1 << 16;

    /// Adds one frame's time for `pass`.
    pub fn add(&mut self, pass: &'static str, ms: f64) {
        match self.passes.iter_mut().find(|(name, _)| *name == pass) {
            Some((_, samples)) => {
                if samples.len() == Self::KEEP {
                    samples.drain(..Self::KEEP / 2);
                }
                samples.push(ms)
            }
            None => self.passes.push((pass, vec![ms])),
        }
    }

    /// Throws away an answer for `pass` that it cannot have taken: a GPU time longer than the
    /// wall clock allowed. llvmpipe answers a GL time query that follows a compute dispatch with
    /// the time since the machine booted; a median with those in it would mean nothing.
    pub fn reject(&mut self, pass: &'static str) {
        if !self.passes.iter().any(|(name, _)| *name == pass) {
            self.passes.push((pass, Vec::new()));
        }
        match self.rejected.iter_mut().find(|(name, _)| *name == pass) {
            Some((_, count)) => *count += 1,
            None => self.rejected.push((pass, 1)),
        }
    }

    /// Moves every sample of `other` into these (keeping `other`'s lists for reuse).
    pub fn take_from(&mut self, other: &mut PassTimes) {
        for (pass, samples) in &mut other.passes {
            for ms in samples.drain(..) {
                self.add(pass, ms);
            }
        }
        for (pass, count) in other.rejected.drain(..) {
            (0..count).for_each(|_| self.reject(pass));
        }
    }

    /// The samples of `pass` (empty when it never ran).
    pub fn samples(&self, pass: &str) -> &[f64] {
        self.passes.iter().find(|(name, _)| *name == pass).map_or(&[], |(_, s)| s)
    }

    /// Median and 95th percentile of each pass, in the order they first ran.
    pub fn summary(&self) -> Vec<(&'static str, f64, f64)> {
        self.passes
            .iter()
            .map(|(name, samples)| {
                let (median, p95) = median_p95(samples);
                (*name, median, p95)
            })
            .collect()
    }

    /// Writes `<pass>_median` and `<pass>_p95` into the report's `timings_ms`: `null` for a pass
    /// whose every answer was rejected, and a line on stderr for each pass that had any.
    pub fn record(&self, report: &mut Report) {
        for (name, median, p95) in self.summary() {
            // NaN is written as JSON's null: no time, rather than a made-up 0.
            let timed = !self.samples(name).is_empty();
            report.time_ms(&format!("{name}_median"), if timed { median } else { f64::NAN });
            report.time_ms(&format!("{name}_p95"), if timed { p95 } else { f64::NAN });
        }
        for (name, count) in &self.rejected {
            let of = *count as usize + self.samples(name).len();
            eprintln!(
                "timing: {count} of {of} GPU times for {name} were longer than the wall clock allowed, \
                 and are left out (llvmpipe answers so for a GL pass after a compute dispatch)"
            );
        }
    }

    /// One line for a window's title bar or the terminal, the medians of the last 60 frames:
    /// "raster 1.20 · ao 3.10 ms (GPU)".
    pub fn line(&self) -> String {
        let parts: Vec<String> = self
            .recent()
            .into_iter()
            .map(|(name, ms)| match ms {
                None => format!("{name} -"), // every answer rejected
                Some(ms) => format!("{name} {ms:.2}"),
            })
            .collect();
        if parts.is_empty() { "no GPU times yet".into() } else { format!("{} ms (GPU)", parts.join(" · ")) }
    }
}

impl PassTimes {
    /// Each pass's median over its last 60 frames, in ms, in the order the passes first ran:
    /// `None` for a pass whose every answer was rejected.
    pub fn recent(&self) -> Vec<(&'static str, Option<f64>)> {
        let recent = |s: &[f64]| median_p95(&s[s.len().saturating_sub(60)..]).0;
        self.passes.iter().map(|(name, s)| (*name, (!s.is_empty()).then(|| recent(s)))).collect()
    }
}

impl Default for PassTimes {
    fn default() -> Self {
        Self::new()
    }
}

/// Adds the GPU time `stamps` measured (between its first two timestamps) to `pass`, once
/// `fence` has signalled. Call it just before the next submission that waits for `fence` anyway
/// (or after the last frame), so that reading adds no wait.
pub fn read_after(
    vk: &VulkanContext,
    fence: vk::Fence,
    stamps: Option<&Timestamps>,
    pass: &'static str,
    times: &mut PassTimes,
) -> Result<()> {
    if let Some(stamps) = stamps {
        commands::wait_for(vk, fence, "vkWaitForFences before reading a pass's time")?;
        times.add(pass, stamps.read_ms(vk)?);
    }
    Ok(())
}

/// GL passes timed with `GL_TIME_ELAPSED` queries. A frame's queries are read when their
/// results are available (a frame or two later), never waited for while frames still run; the
/// queries are made once, up front, so that a long run makes no more GL objects as it goes.
pub struct GlPassTimer {
    /// Queries whose results are not read yet, oldest frame first.
    pending: VecDeque<Vec<Pass>>,
    /// The frame being recorded.
    current: Vec<Pass>,
    /// Queries read and ready to use again.
    free: Vec<glow::Query>,
    /// Every query made, held only so that each deletes itself when the timer is dropped.
    _all: Vec<Owned<glow::Query>>,
    /// Times read early (to free queries), handed over at the next `end_frame`.
    early: PassTimes,
    /// Emptied frame lists, kept so that a frame allocates nothing once the first few have run.
    spare: Vec<Vec<Pass>>,
}

/// A timed GL pass: its name, its query, and when the CPU began it (no GPU time measured by the
/// query can be longer than the wall clock from there until its answer is read).
struct Pass {
    name: &'static str,
    query: glow::Query,
    began: std::time::Instant,
}

impl GlPassTimer {
    /// Queries made up front: 8 passes a frame for 4 frames in flight. When all are in use, the
    /// oldest frame's are read, waiting for them: the GPU is then 4 frames behind anyway.
    const QUERIES: usize = 32;

    pub fn new(gl: &Rc<glow::Context>) -> Result<Self> {
        let all = create_n(gl, "glGenQueries for the GL pass timer", Self::QUERIES, |gl| unsafe {
            gl.create_query()
        })?;
        let free = all.iter().map(|q| **q).collect();
        let mut timer = GlPassTimer {
            pending: VecDeque::new(),
            current: Vec::new(),
            free,
            _all: all,
            early: PassTimes::new(),
            spare: Vec::new(),
        };
        // llvmpipe answers the first GL_TIME_ELAPSED query around a context's first drawing with
        // a time since boot: time a clear of a 1x1 target, and throw the answers away.
        let target = create(gl, "glGenRenderbuffers for the timer's warm-up", |gl| unsafe {
            gl.create_renderbuffer()
        })?;
        let framebuffer =
            create(gl, "glGenFramebuffers for the timer's warm-up", |gl| unsafe { gl.create_framebuffer() })?;
        unsafe {
            gl.bind_renderbuffer(glow::RENDERBUFFER, Some(*target));
            gl.renderbuffer_storage(glow::RENDERBUFFER, glow::RGBA8, 1, 1);
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*framebuffer));
            gl.framebuffer_renderbuffer(
                glow::FRAMEBUFFER,
                glow::COLOR_ATTACHMENT0,
                glow::RENDERBUFFER,
                Some(*target),
            );
            // Every query once: a name from glGenQueries becomes a query object at its first
            // use, and a leak check counting GL's objects would see them appear one by one.
            for _ in 0..Self::QUERIES {
                timer.time(gl, "warm-up", || gl.clear(glow::COLOR_BUFFER_BIT))?;
            }
            timer.finish(gl, &mut PassTimes::new());
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
        drop((framebuffer, target)); // warmed up
        Ok(timer)
    }

    /// Starts timing `pass`. GL time queries do not nest: end one pass before the next.
    pub fn begin(&mut self, gl: &glow::Context, pass: &'static str) -> Result<()> {
        if self.free.is_empty() {
            let oldest = self
                .pending
                .pop_front()
                .context("more GL passes in one frame than GlPassTimer has queries")?;
            let mut early = std::mem::take(&mut self.early);
            self.read(gl, oldest, &mut early);
            self.early = early;
        }
        let query = self.free.pop().expect("a query was freed above");
        unsafe { gl.begin_query(glow::TIME_ELAPSED, query) };
        self.current.push(Pass { name: pass, query, began: std::time::Instant::now() });
        Ok(())
    }

    /// Ends the pass begun last.
    pub fn end(&mut self, gl: &glow::Context) {
        unsafe { gl.end_query(glow::TIME_ELAPSED) };
    }

    /// Times the GL commands `pass` issues: `begin`, `pass()`, `end`.
    pub fn time<R>(&mut self, gl: &glow::Context, name: &'static str, pass: impl FnOnce() -> R) -> Result<R> {
        self.begin(gl, name)?;
        let result = pass();
        self.end(gl);
        Ok(result)
    }

    /// Ends the frame: reads every earlier frame whose results have arrived, without waiting.
    pub fn end_frame(&mut self, gl: &glow::Context, times: &mut PassTimes) {
        let next = self.spare.pop().unwrap_or_default();
        self.pending.push_back(std::mem::replace(&mut self.current, next));
        times.take_from(&mut self.early);
        while let Some(frame) = self.pending.front() {
            // A frame's queries finish in order: when its last one is available, all are.
            let available = frame.last().is_none_or(|pass| unsafe {
                gl.get_query_parameter_u32(pass.query, glow::QUERY_RESULT_AVAILABLE) != 0
            });
            if !available {
                break;
            }
            let frame = self.pending.pop_front().expect("front exists");
            self.read(gl, frame, times);
        }
    }

    /// Reads what is left, waiting for it: call after the last measured frame.
    pub fn finish(&mut self, gl: &glow::Context, times: &mut PassTimes) {
        if !self.current.is_empty() {
            self.pending.push_back(std::mem::take(&mut self.current));
        }
        times.take_from(&mut self.early);
        while let Some(frame) = self.pending.pop_front() {
            self.read(gl, frame, times);
        }
    }

    /// Reads a frame's queries into `times` (waiting for them if need be) and frees them.
    fn read(&mut self, gl: &glow::Context, mut frame: Vec<Pass>, times: &mut PassTimes) {
        for pass in frame.drain(..) {
            // GL_QUERY_RESULT of a GL_TIME_ELAPSED query: nanoseconds, 64 bits.
            let ns = unsafe { gl.get_query_parameter_u64(pass.query, glow::QUERY_RESULT) };
            let (ms, wall_ms) = (ns as f64 / 1e6, pass.began.elapsed().as_secs_f64() * 1e3);
            if ms <= wall_ms {
                times.add(pass.name, ms)
            } else {
                times.reject(pass.name)
            }
            self.free.push(pass.query);
        }
        self.spare.push(frame);
    }
}

/// Vulkan passes timed with timestamps: two per pass, read after the frame's fence has signalled
/// (the wait the frame has anyway), so reading them costs the GPU nothing.
pub struct VkPassTimer {
    stamps: Timestamps,
    max_passes: u32,
    /// The passes recorded into the command buffer since the last reset.
    recorded: Vec<&'static str>,
}

impl VkPassTimer {
    /// Room for `max_passes` passes a frame; `None` when the queue cannot write timestamps.
    pub fn new(vk: &VulkanContext, max_passes: u32) -> Result<Option<Self>> {
        Ok(Timestamps::with_count(vk, 2 * max_passes)?.map(|stamps| VkPassTimer {
            stamps,
            max_passes,
            recorded: Vec::new(),
        }))
    }

    /// Resets the queries: record first in the frame's command buffer.
    pub fn reset(&mut self, vk: &VulkanContext, cb: vk::CommandBuffer) {
        self.stamps.reset(vk, cb);
        self.recorded.clear();
    }

    /// Starts `pass`: the timestamp is written once every earlier command has finished, so the
    /// pass's time does not include them.
    pub fn begin(&mut self, vk: &VulkanContext, cb: vk::CommandBuffer, pass: &'static str) {
        assert!((self.recorded.len() as u32) < self.max_passes, "more passes than VkPassTimer::new allowed");
        let index = 2 * self.recorded.len() as u32;
        self.stamps.write(vk, cb, vk::PipelineStageFlags::ALL_COMMANDS, index);
        self.recorded.push(pass);
    }

    /// Ends the pass begun last, once all its commands have finished.
    pub fn end(&mut self, vk: &VulkanContext, cb: vk::CommandBuffer) {
        let index = 2 * self.recorded.len() as u32 - 1;
        self.stamps.write(vk, cb, vk::PipelineStageFlags::ALL_COMMANDS, index);
    }

    /// Reads the passes of the finished submission into `times`: call after its fence signalled.
    pub fn read(&self, vk: &VulkanContext, times: &mut PassTimes) -> Result<()> {
        for (i, pass) in self.recorded.iter().enumerate() {
            let i = i as u32;
            times.add(pass, self.stamps.between_ms(vk, 2 * i, 2 * i + 1)?);
        }
        Ok(())
    }
}

/// The median and the largest of `values` (milliseconds), and how many, for a report: what a
/// handful of rare events took (chapter 14's deaths to the next frame).
pub fn median_max(values: &[f64]) -> serde_json::Value {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    serde_json::json!({ "median": median, "max": sorted.last().copied().unwrap_or(0.0), "n": sorted.len() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pass_times_keep_first_run_order_and_summarise_each_pass() {
        let mut times = PassTimes::default();
        for i in 0..20 {
            times.add("raster", 1.0 + i as f64);
            times.add("ao", 10.0);
        }
        let summary = times.summary();
        assert_eq!(summary.iter().map(|s| s.0).collect::<Vec<_>>(), ["raster", "ao"]);
        // 1..=20: the median is element 10 of 0..19 rounded (10 -> 11.0), p95 element 18 (19.0).
        assert_eq!(summary[0].1, 11.0);
        assert_eq!(summary[0].2, 19.0);
        assert_eq!(summary[1].1, 10.0);
        // The line shows the last 60 frames only: all 20 here.
        assert_eq!(times.line(), "raster 11.00 · ao 10.00 ms (GPU)");
        for _ in 0..PassTimes::KEEP {
            times.add("ao", 2.0);
        }
        assert_eq!(times.samples("ao").len(), PassTimes::KEEP / 2 + 20, "the oldest half forgotten");
        assert_eq!(times.line(), "raster 11.00 · ao 2.00 ms (GPU)");
        assert!(times.samples("blur").is_empty());
    }

    /// An impossible answer is left out, not averaged in; a pass with no answer left is null in
    /// the report (not 0), and the rejections survive `take_from`, as a frame's early reads do.
    #[test]
    fn rejected_times_are_left_out_and_a_pass_without_any_is_null() {
        let mut early = PassTimes::default();
        early.add("composite", 0.5);
        early.reject("overlays");
        let mut times = PassTimes::default();
        times.take_from(&mut early);
        times.reject("composite");
        assert_eq!(times.samples("composite"), [0.5]);
        assert_eq!(times.rejected, [("overlays", 1), ("composite", 1)]);
        assert_eq!(times.line(), "composite 0.50 · overlays - ms (GPU)");
        let mut report = Report::new("timing-test");
        times.record(&mut report);
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(json["timings_ms"]["composite_median"], 0.5);
        assert!(json["timings_ms"]["overlays_median"].is_null());
        assert!(json["timings_ms"]["overlays_p95"].is_null());
    }
}
