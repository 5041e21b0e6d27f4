//! One frame of chapter 13, drawn by either method: the moving instance and its TLAS update,
//! GL's ids, the rays (reused or all new), chapter 12's composite and overlays, each timed; and,
//! where nothing is read back before the next frame, that frame's ids, drawn early.

use super::path::Path;
use super::tracer::{Budget, TemporalTracer, release_to_vulkan};
use anyhow::Result;
use common::base::cli::Size;
use common::base::commands::Commands;
use common::base::gl::{Owned, create};
use common::clocks::timeline::{Timeline, stamp_into as stamp};
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes, read_after};
use common::frame::overlay::Overlays;
use common::instruments::fail;
use common::interop::exportable::ExportedBuffer;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{InPlace, Refresh};
use common::scene::{Camera, Scene};
use fast_frame::composite::{ComputeComposite, Uniforms, View};
use fast_frame::trace::{Pattern, Rays, SurfaceTracer};
use fast_frame::visibility::{MeshIds, Targets, VisibilityPass};
use glow::HasContext;

/// How a frame's occlusion is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Drawn {
    /// This chapter's: the history reused, its rays per pixel as the budget says.
    Temporal(Budget),
    /// Chapter 12's: this many new rays per pixel, nothing kept.
    Fresh(u32),
}

impl Drawn {
    /// The method's short name, as the measured tables' rows give it: "chapter 13, 2 rays".
    pub fn name(self) -> String {
        let rays = |n: u32| if n == 1 { "1 ray".to_owned() } else { format!("{n} rays") };
        match self {
            Drawn::Temporal(b) => format!("chapter 13, {}", rays(b.samples)),
            Drawn::Fresh(n) => format!("chapter 12, {}", rays(n)),
        }
    }

    /// What the method traces, in words a line of output can stand on.
    pub fn described(self) -> String {
        match self {
            Drawn::Temporal(b) => {
                format!("chapter 13's reuse, {} new rays a pixel while its history fills", b.samples)
            }
            Drawn::Fresh(n) => format!("chapter 12's fresh frames, {n} rays a pixel"),
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
    pub shared: &'a RayTracedScene,
    pub ids: &'a [MeshIds],
    pub visibility: &'a VisibilityPass,
    pub composite: &'a ComputeComposite,
    pub overlays: Option<&'a Overlays>,
    pub path: &'a Path,
    pub motion: Option<Motion<'a>>,
    pub timestamps: Option<&'a Timestamps>,
    /// Whether this chapter's frame draws the next frame's ids before it waits (chapter 13
    /// does; `convergence temporal --next-ids late` does not, to measure what it buys).
    pub ids_ahead: bool,
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
/// last frames' passes on one clock (`convergence temporal --timeline`), with the walk's length.
pub struct Clock {
    pub gl: GlPassTimer,
    pub times: PassTimes,
    traced: Option<Option<u32>>,
    pub timeline: Option<(Timeline, u32)>,
    /// The frame whose ids GL has drawn and handed to Vulkan already (at the end of the one
    /// before), and a fence after the last ids GL drew.
    ids_ahead: Option<u32>,
    ids_done: Option<Owned<glow::Fence>>,
    /// How many frames of the walk had their ids drawn ahead.
    pub frames_drawn_ahead: u32,
}

impl Clock {
    pub fn new(gl: &std::rc::Rc<glow::Context>, timeline: Option<(Timeline, u32)>) -> Result<Clock> {
        Ok(Clock {
            gl: GlPassTimer::new(gl)?,
            times: PassTimes::new(),
            traced: None,
            timeline,
            ids_ahead: None,
            ids_done: None,
            frames_drawn_ahead: 0,
        })
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

    /// Waits, on the CPU, until GL has drawn the last ids it was given (the fence after them).
    fn wait_for_ids(&mut self, gl: &glow::Context) -> Result<()> {
        let Some(fence) = self.ids_done.take() else { return Ok(()) };
        fail::step("glClientWaitSync for GL's ids")?;
        loop {
            // FLUSH: the fence is sent to the GPU, or the wait could outlast every timeout.
            match unsafe { gl.client_wait_sync(*fence, glow::SYNC_FLUSH_COMMANDS_BIT, 1_000_000_000) } {
                glow::ALREADY_SIGNALED | glow::CONDITION_SATISFIED => return Ok(()),
                glow::TIMEOUT_EXPIRED => eprintln!("frame: GL's ids take over a second; waiting on"),
                _ => anyhow::bail!("glClientWaitSync for GL's ids failed (GL_WAIT_FAILED)"),
            }
        }
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
    /// A new picture size: every image of the old size goes, once neither API uses it, and the
    /// tracers point at the new ones (the history starts again).
    pub fn resize(&self, sized: &mut Sized, size: Size) -> Result<()> {
        let Apis { vk, gl, commands, .. } = self.apis;
        unsafe { gl.gl.finish() };
        commands.wait(vk, "vkWaitForFences before a resize")?;
        drop(std::mem::replace(&mut sized.targets, Targets::new(vk, gl, self.apis.handoff, size.extent())?));
        sized.fresh.resized(vk, &sized.targets);
        sized.temporal.resized(vk, &self.shared.allocator, &sized.targets)
    }

    /// The uniforms of the composite for `camera` (its far plane shows depth).
    pub fn uniforms(&self, camera: &Camera, view: View) -> Uniforms {
        Uniforms { far_depth: camera.far, view, ..self.uniforms }
    }

    // ANCHOR: frame
    /// Frame `frame` of the path, drawn by `drawn`. Returns the camera it was drawn with. `next`:
    /// the caller draws frame `frame + 1` next and reads nothing of this one back before it, so
    /// this frame may draw the next one's ids before it returns (this chapter's method alone).
    pub fn draw(
        &self,
        sized: &mut Sized,
        drawn: Drawn,
        frame: u32,
        clock: &mut Clock,
        next: bool,
    ) -> Result<Camera> {
        let Apis { vk, gl, .. } = self.apis;
        let g = &gl.gl;
        // The previous frame's Vulkan work is done, and with it the GL ids it waited for.
        self.apis.commands.wait(vk, "vkWaitForFences at the top of a frame")?;
        clock.read_trace(self)?;
        let camera = self.path.camera(frame);
        // This frame's ids: drawn and handed over at the end of the previous frame, or now.
        let drawn_ahead = clock.ids_ahead.take() == Some(frame);
        if !drawn_ahead {
            self.place_instances(sized, frame, true)?;
            self.draw_ids(sized, frame, &camera, clock)?;
        }
        let slot = clock.timeline.as_ref().and_then(|(t, frames)| t.slot(frame, *frames));
        let targets = &sized.targets;
        match drawn {
            Drawn::Temporal(budget) => {
                let moved =
                    self.path.moving.as_ref().filter(|_| self.motion.is_some()).map(|m| m.swept(frame));
                let handed = (self.timestamps, drawn_ahead);
                sized.temporal.trace(self.apis, targets, (&camera, frame), (&budget, moved), handed)?
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
        stamp(clock.timeline.as_ref().map(|(t, _)| t), slot, 2);
        clock.gl.time(g, "composite", || self.composite.draw(g, targets, &uniforms))?;
        if let Some(overlays) = self.overlays {
            let (w, h) = (targets.extent.width as f32, targets.extent.height as f32);
            let target = targets.overlay_target();
            clock.gl.time(g, "overlays", || overlays.draw(g, &target, camera.view_projection(w / h)))?;
        }
        stamp(clock.timeline.as_ref().map(|(t, _)| t), slot, 3);
        clock.gl.end_frame(g, &mut clock.times);
        if next && self.ids_ahead && matches!(drawn, Drawn::Temporal(_)) {
            // The next frame's ids now, before the CPU waits for this frame's trace: GL draws
            // them right after this composite, however long the CPU takes to wake up. The
            // shared instance buffer is read by GL's ids and the TLAS update alone (the rays
            // read copies), so the CPU may write the next transform once this frame's are done.
            clock.wait_for_ids(g)?;
            if let Some(motion) = &self.motion {
                motion.updates.wait(vk, "vkWaitForFences for the TLAS update")?;
            }
            self.place_instances(sized, frame + 1, false)?;
            self.draw_ids(sized, frame + 1, &self.path.camera(frame + 1), clock)?;
            release_to_vulkan(self.apis, &sized.targets);
            clock.ids_ahead = Some(frame + 1);
            clock.frames_drawn_ahead += 1;
        }
        clock.times.frame_done();
        Ok(camera)
    }
    // ANCHOR_END: frame

    // ANCHOR: place
    /// The moving instance at `frame`: its transform written into the shared buffer and into
    /// this frame's copy of it for the rays, and the TLAS updated (in a submission of its own,
    /// which waits for nothing GL does). `top`: at the top of a frame, after its wait, when no
    /// trace is in flight and the previous frame's copy may be written too; at a walk's first
    /// frame that says nothing has moved yet.
    fn place_instances(&self, sized: &mut Sized, frame: u32, top: bool) -> Result<()> {
        let (Some(motion), Some(moving)) = (&self.motion, &self.path.moving) else { return Ok(()) };
        moving.write_shared(motion.instances, frame);
        moving.write(sized.temporal.transforms(frame)?, frame);
        if top {
            moving.write(sized.temporal.transforms(frame + 2)?, frame.saturating_sub(1));
        }
        motion.tlas.submit(self.apis.vk, motion.updates, motion.loader, Refresh::Update, None)
    }
    // ANCHOR_END: place

    /// GL's ids of frame `frame`, timed, and where ids are drawn early a fence after them, for the
    /// next ids drawn early to wait on (`Clock::wait_for_ids`).
    fn draw_ids(&self, sized: &Sized, frame: u32, camera: &Camera, clock: &mut Clock) -> Result<()> {
        let g = &self.apis.gl.gl;
        let slot = clock.timeline.as_ref().and_then(|(t, frames)| t.slot(frame, *frames));
        let targets = &sized.targets;
        stamp(clock.timeline.as_ref().map(|(t, _)| t), slot, 0);
        clock.gl.time(g, "visibility", || {
            self.visibility.draw(g, &targets.ids_target(), self.scene, self.ids, camera)
        })?;
        stamp(clock.timeline.as_ref().map(|(t, _)| t), slot, 1);
        if self.ids_ahead {
            let fence = create(g, "glFenceSync after GL's ids", |g| unsafe {
                g.fence_sync(glow::SYNC_GPU_COMMANDS_COMPLETE, 0)
            })?;
            clock.ids_done = Some(fence);
        }
        Ok(())
    }
}
