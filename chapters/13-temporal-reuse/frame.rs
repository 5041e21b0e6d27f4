//! One frame of chapter 13, drawn by either method: the moving instance and its TLAS update,
//! GL's ids, the rays (reused or all new), chapter 12's composite and overlays, each timed.

use common::frame::fast::composite::{ComputeComposite, Uniforms, View};
use crate::path::Path;
use crate::temporal::{Budget, TemporalTracer};
use common::frame::fast::trace::{Pattern, Rays, SurfaceTracer};
use common::frame::fast::visibility::{MeshIds, Targets, VisibilityPass};
use anyhow::{Context as _, Result};
use common::base::commands::Commands;
use common::clocks::timeline::{Timeline, stamp_into as stamp};
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes, read_after};
use common::frame::Overlays;
use common::interop::exportable::ExportedBuffer;
use common::interop::handoff::Apis;
use common::rt::accel::{InPlace, Refresh};
use common::scene::{Camera, Scene};

/// How a frame's occlusion is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Drawn {
    /// This chapter's: the history reused, its rays per pixel as the budget says.
    Temporal(Budget),
    /// Chapter 12's: this many new rays per pixel, nothing kept.
    Fresh(u32),
}

impl Drawn {
    pub fn name(self) -> String {
        let rays = |n: u32| if n == 1 { "1 ray".to_owned() } else { format!("{n} rays") };
        match self {
            Drawn::Temporal(b) => format!("chapter 13, {}", rays(b.samples)),
            Drawn::Fresh(n) => format!("chapter 12, {}", rays(n)),
        }
    }
}

/// The moving instance's share of a frame: where its transforms go, and the TLAS update.
pub struct Motion<'a> {
    pub instances: &'a ExportedBuffer,
    pub tlas: &'a InPlace,
    pub loader: &'a ash::khr::acceleration_structure::Device,
    pub updates: &'a Commands,
}

/// Everything a frame draws with that stays the same from frame to frame.
pub struct Passes<'a> {
    pub apis: Apis<'a>,
    pub scene: &'a Scene,
    pub shared: &'a common::rt::RayTracedScene,
    pub ids: &'a [MeshIds],
    pub visibility: &'a VisibilityPass,
    pub composite: &'a ComputeComposite,
    pub overlays: Option<&'a Overlays>,
    pub path: &'a Path,
    pub motion: Option<Motion<'a>>,
    pub timestamps: Option<&'a Timestamps>,
    pub uniforms: Uniforms,
    pub radius: f32,
}

/// What changes size with the picture: the images and the two tracers that point at them.
pub struct Sized {
    pub targets: Targets,
    pub fresh: SurfaceTracer,
    pub temporal: TemporalTracer,
}

/// The GPU times of one walk, whether the last frame's trace time is still to be read, and the
/// last frames' passes on one clock (chapter 12's `--timeline`), with the walk's length.
pub struct Clock {
    pub gl: GlPassTimer,
    pub times: PassTimes,
    traced: Option<Option<u32>>,
    pub timeline: Option<(Timeline, u32)>,
}

impl Clock {
    pub fn new(gl: &std::rc::Rc<glow::Context>, timeline: Option<(Timeline, u32)>) -> Result<Clock> {
        Ok(Clock { gl: GlPassTimer::new(gl)?, times: PassTimes::new(), traced: None, timeline })
    }

    /// Waits for the last frame's Vulkan work and reads its trace time (into the timeline too,
    /// where that frame has a slot in it).
    fn read_trace(&mut self, p: &Passes) -> Result<()> {
        if let Some(slot) = self.traced.take() {
            read_after(p.apis.vk, *p.apis.commands.fence, p.timestamps, "ao_trace", &mut self.times)?;
            if let (Some((t, _)), Some(slot), Some(stamps)) = (self.timeline.as_mut(), slot, p.timestamps) {
                t.trace_done(p.apis.vk, slot, stamps)?;
            }
        }
        Ok(())
    }

    /// Reads every time still out, waiting for it: after the walk's last frame.
    pub fn finish(&mut self, p: &Passes) -> Result<()> {
        self.read_trace(p)?;
        self.gl.finish(&p.apis.gl.gl, &mut self.times);
        Ok(())
    }

    /// The timeline, read and written to `<out>.json` and `<out>.svg` (both APIs idle).
    pub fn finish_timeline(
        &mut self,
        p: &Passes,
        out: &std::path::Path,
    ) -> Result<Option<serde_json::Value>> {
        let (Some((timeline, _)), Some(stamps)) = (self.timeline.take(), p.timestamps) else {
            return Ok(None);
        };
        unsafe { glow::HasContext::finish(&*p.apis.gl.gl) };
        Ok(Some(timeline.finish(p.apis.vk, p.apis.commands, stamps, out)?.into()))
    }
}

impl Passes<'_> {
    /// The uniforms of the composite for `camera` (its far plane shows depth).
    pub fn uniforms(&self, camera: &Camera, view: View) -> Uniforms {
        Uniforms { far_depth: camera.far, view, ..self.uniforms }
    }

    // ANCHOR: frame
    /// Frame `frame` of the path, drawn by `drawn`. Returns the camera it was drawn with.
    pub fn draw(&self, sized: &mut Sized, drawn: Drawn, frame: u32, clock: &mut Clock) -> Result<Camera> {
        let Apis { vk, gl, .. } = self.apis;
        let g = &gl.gl;
        // The previous frame's Vulkan work is done, and with it GL's draw it waited for: nothing
        // reads the instance buffers now, so the CPU may write them.
        self.apis.commands.wait(vk, "vkWaitForFences at the top of a frame")?;
        clock.read_trace(self)?;
        let slot = clock.timeline.as_ref().and_then(|(t, frames)| t.slot(frame, *frames));
        let timeline = clock.timeline.as_ref().map(|(t, _)| t);
        if let (Some(motion), Some(moving)) = (&self.motion, &self.path.moving) {
            let previous = sized.temporal.previous_instances.allocation.mapped_slice_mut();
            let previous = previous.context("the previous instances are not mapped")?;
            moving.write(motion.instances, previous, frame);
            motion.tlas.submit(vk, motion.updates, motion.loader, Refresh::Update, None)?;
        }
        let camera = self.path.camera(frame);
        let targets = &sized.targets;
        stamp(timeline, slot, 0);
        clock.gl.time(g, "visibility", || self.visibility.draw(g, targets, self.scene, self.ids, &camera))?;
        stamp(timeline, slot, 1);
        match drawn {
            Drawn::Temporal(budget) => {
                let moved = self.path.moving.as_ref().filter(|_| self.motion.is_some()).map(|m| m.swept(frame));
                sized.temporal.trace(self.apis, targets, (&camera, frame), (&budget, moved), self.timestamps)?
            }
            Drawn::Fresh(samples) => {
                let scene_scale = self.scene.size() / 2.0;
                let pattern = Pattern::Tile4x4; // chapter 12's
                let rays = Rays { samples, radius: self.radius, scene_scale, pattern, salt: 0 };
                sized.fresh.accumulated = 0; // chapter 12 starts again whenever anything moves
                sized.fresh.trace(self.apis, targets, &camera, rays, self.timestamps)?;
            }
        }
        clock.traced = Some(slot);
        let uniforms = self.uniforms(&camera, self.uniforms.view);
        stamp(timeline, slot, 2);
        clock.gl.time(g, "composite", || self.composite.draw(g, targets, &uniforms))?;
        if let Some(overlays) = self.overlays {
            let (w, h) = (targets.extent.width as f32, targets.extent.height as f32);
            let target = targets.overlay_target();
            clock.gl.time(g, "overlays", || overlays.draw(g, &target, camera.view_projection(w / h)))?;
        }
        stamp(timeline, slot, 3);
        clock.gl.end_frame(g, &mut clock.times);
        clock.times.frame_done();
        Ok(camera)
    }
    // ANCHOR_END: frame
}
