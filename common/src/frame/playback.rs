//! A window's animation, as chapters 09 and 10 play theirs: the wall clock moves it on, Space
//! stops and starts it, `+` and `-` change the rays a frame; and a new window size for chapter
//! 08's frame (G-buffers, occlusion, composite), made as chapter 08 makes it.

use super::composite::Composite;
use super::panel::{self, Control};
use crate::base::cli::Size;
use crate::base::window::{Key, NamedKey};
use crate::instruments::report::Report;
use crate::interop::handoff::Apis;
use crate::rt::ao::AoTracer;
use crate::scene::gbuffer::{GBuffers, SceneBuffers};
use anyhow::Result;
use std::time::Instant;

/// Whether the animation runs, the rays a frame the keys left, and when time was last taken.
pub struct Playback {
    pub running: bool,
    pub samples: u32,
    last: Instant,
}

impl Playback {
    /// Running, unless `step` is 0 (`--step 0` stands still in a window too).
    pub fn new(step: f32, samples: u32) -> Playback {
        Playback { running: step > 0.0, samples, last: Instant::now() }
    }

    /// One key: Space stops or starts, `+` and `-` double and halve the rays a frame (1 to 256).
    pub fn key(&mut self, key: &Key) {
        match key.as_ref() {
            Key::Named(NamedKey::Space) => self.running = !self.running,
            Key::Character("+" | "=") => self.samples = (self.samples * 2).min(256),
            Key::Character("-") => self.samples = (self.samples / 2).max(1),
            _ => {}
        }
    }

    /// `time` moved on by the wall-clock seconds since the last call, while running.
    pub fn advance(&mut self, time: &mut f32) {
        let now = Instant::now();
        if self.running {
            *time += (now - self.last).as_secs_f32();
        }
        self.last = now;
    }

    /// What a window's run reports instead of the motion check: its frames follow the wall clock,
    /// so `frames_differ_over_time` is not judged; and the rays a frame the keys or panel left.
    pub fn report(&self, report: &mut Report) {
        let why = "a window's frames follow the wall clock; --headless checks the motion at --step";
        report.not_judged("frames_differ_over_time", why);
        report.set("rays_a_frame", self.samples);
    }

    /// The panel's controls for these, one a row beside its key, then the chapter's `more`.
    pub fn controls<'a>(
        &'a mut self,
        ui: &mut egui::Ui,
        more: impl IntoIterator<Item = (&'a str, Control<'a>, &'a str)>,
    ) {
        let mut rows = vec![
            ("running", Control::Toggle(&mut self.running), "Space"),
            ("rays a frame", Control::Count(&mut self.samples, 1..=256), "+ -"),
        ];
        rows.extend(more);
        panel::controls(ui, &mut rows);
    }
}

/// A new size for chapter 08's frame: every shared image made anew at `size` (the G-buffers
/// with `usage`, as they were made), once neither API uses the old ones (chapter 08's resize step
/// says why each part).
pub fn resize(
    apis: Apis,
    (buffers, usage): (&SceneBuffers, ash::vk::ImageUsageFlags),
    (gbuffers, tracer, composite): (&mut GBuffers, &mut AoTracer, &mut Composite),
    size: Size,
) -> Result<()> {
    let Apis { vk, gl, handoff, commands } = apis;
    unsafe { glow::HasContext::finish(&*gl.gl) };
    commands.wait(vk, "vkWaitForFences before a resize")?;
    let fresh = GBuffers::new(vk, gl, handoff, buffers, size.extent(), usage)?;
    let old = std::mem::replace(gbuffers, fresh);
    tracer.resize(vk, gl, gbuffers)?;
    composite.resize(&gl.gl, gbuffers)?;
    drop(old); // GL's objects, then each image, GL's side first
    Ok(())
}
