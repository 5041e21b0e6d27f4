//! One mode's frames at one setting: chapter 08's frame drawn, handed over, traced and
//! composited `count` times, each pass timed on the GPU, into [`Samples`].

use crate::round_trip::RoundTrip;
use crate::{Mode, Row};
use anyhow::Result;
use ash::vk;
use common::base::cli::Size;
use common::clocks::timeline::{self, Timeline};
use common::clocks::timestamps::{Timestamps, median_p95};
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::frame::{Composite, Overlays, Uniforms};
use common::interop::handoff::{Apis, Handoff};
use common::rt::RayTracedScene;
use common::rt::ao::{AoRays, AoTracer};
use common::scene::gbuffer::GBuffers;
use common::scene::{Camera, Scene};
use common::{GlContext, VulkanContext};
use glow::HasContext;
use std::time::Instant;

/// One mode's measurements at one setting.
#[derive(Default)]
pub struct Samples {
    frame_ms: Vec<f64>,
    ao_ms: Vec<f64>,
    passes: PassTimes,
}

impl Samples {
    pub fn row(&self, mode: Mode, scene: &'static str, size: Size, spp: u32, covered: u64) -> Row {
        let (frame_ms, p95_ms) = median_p95(&self.frame_ms);
        let median = |pass| median_p95(self.passes.samples(pass)).0;
        let (raster_ms, composite_ms) = (median("raster"), median("composite"));
        let ao_ms = median_p95(&self.ao_ms).0;
        let rays = spp as f64 * covered as f64;
        Row {
            mode,
            scene,
            width: size.width,
            height: size.height,
            spp,
            frame_ms,
            p95_ms,
            raster_ms,
            handoff_ms: (frame_ms - raster_ms - ao_ms - composite_ms).max(0.0),
            ao_ms,
            composite_ms,
            grays_per_s: if ao_ms > 0.0 { rays / (ao_ms * 1e-3) / 1e9 } else { 0.0 },
        }
    }
}

/// How one run of frames is made.
#[derive(Clone, Copy)]
pub struct Setting {
    pub spp: u32,
    pub frames: u32,
    pub depth_prepass: bool,
}

/// What one size needs: chapter 08's G-buffers, tracer, composite and overlays, and the round
/// trip's buffers. Dropped newest first (fields drop in order); the GPU must be done with them.
pub struct Frame<'s> {
    pub mode: Mode,
    scene: &'s Scene,
    camera: Camera,
    gl_timer: GlPassTimer,
    /// `cpu-round-trip` only.
    round_trip: Option<RoundTrip>,
    overlays: Overlays,
    composite: Composite,
    tracer: AoTracer,
    gbuffers: GBuffers,
    uniforms: Uniforms,
}

impl<'s> Frame<'s> {
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        handoff: &Handoff,
        shared: &RayTracedScene,
        scene: &'s Scene,
        extent: vk::Extent2D,
        mode: Mode,
    ) -> Result<Self> {
        let camera = Camera::framing(scene.bounds, extent.width as f32 / extent.height as f32);
        let storage = vk::ImageUsageFlags::STORAGE;
        let gbuffers = GBuffers::new(vk, gl, handoff, &shared.buffers, extent, storage)?;
        let tracer = AoTracer::new(vk, gl, &shared.allocator, *shared.structures.tlas.handle, &gbuffers)?;
        let composite = Composite::new(&gl.gl, &gbuffers, scene.bounds)?;
        let overlays = Overlays::new(&gl.gl, scene, 0)?;
        let round_trip = match mode {
            Mode::CpuRoundTrip => Some(RoundTrip::new(vk, gl, &shared.allocator, extent)?),
            _ => None,
        };
        // Chapter 08's defaults: blur radius 2, power 2, the final view.
        let uniforms = Uniforms::final_picture(2.0, camera.far);
        Ok(Frame {
            mode,
            scene,
            camera,
            gl_timer: GlPassTimer::new(&gl.gl)?,
            round_trip,
            overlays,
            composite,
            tracer,
            gbuffers,
            uniforms,
        })
    }

    /// `setting.frames` measured frames after two to warm up, into `samples`; the last ones
    /// also on `timeline`, if there is one. Nothing waits inside a frame that the mode itself
    /// does not make wait.
    pub fn run(
        &mut self,
        apis: Apis,
        setting: Setting,
        stamps: &Timestamps,
        (samples, timeline): (&mut Samples, &mut Option<Timeline>),
    ) -> Result<()> {
        let Apis { vk, gl, .. } = apis;
        let Setting { spp, frames: count, depth_prepass } = setting;
        let g = &gl.gl;
        let radius = self.scene.size() * 0.05;
        let rays = AoRays { samples: spp, accumulated: 0, radius, scene_scale: self.scene.size() / 2.0 };
        let aspect = self.gbuffers.extent.width as f32 / self.gbuffers.extent.height as f32;
        let mut times = PassTimes::default();
        let mut last: Option<Instant> = None;
        let slots: Vec<_> =
            (0..count + 2).map(|f| timeline.as_ref().and_then(|t| t.slot(f, count + 2))).collect();
        let slot = |frame: u32| slots[frame as usize];
        for frame in 0..count + 2 {
            let measured = frame >= 2;
            timeline::stamp(timeline, slot(frame), 0);
            self.gl_timer.begin(g, "raster")?;
            if depth_prepass {
                self.gbuffers.draw_depth_first(g, self.scene, &self.camera);
            } else {
                self.gbuffers.draw(g, self.scene, &self.camera);
            }
            self.gl_timer.end(g);
            timeline::stamp(timeline, slot(frame), 1);
            if let Some(round_trip) = &mut self.round_trip {
                round_trip.gbuffers_to_vulkan(vk, gl, &self.gbuffers)?;
            }
            // The previous frame's trace time, read after its fence: the wait `trace` makes
            // anyway before it records again (one command buffer), once this frame's G-buffers
            // are queued, so the GPU has work while the CPU waits.
            if frame > 0 {
                unsafe { g.flush() };
                apis.commands.wait(vk, "vkWaitForFences for the previous frame")?;
                if frame > 2 {
                    samples.ao_ms.push(stamps.read_ms(vk)?);
                }
                if let (Some(t), Some(previous)) = (timeline.as_mut(), slot(frame - 1)) {
                    t.trace_done(vk, previous, stamps)?;
                }
            }
            // Each frame a fresh estimate (weight 1), as when the camera moves every frame.
            self.tracer.reset();
            self.tracer.trace(apis, &self.gbuffers, rays, Some(stamps))?;
            if let Some(round_trip) = &mut self.round_trip {
                round_trip.ao_to_gl(vk, gl)?;
            }
            timeline::stamp(timeline, slot(frame), 2);
            self.gl_timer.begin(g, "composite")?;
            self.composite.draw(g, &self.gbuffers, &self.tracer, &self.uniforms);
            self.overlays.draw(g, &self.composite.target(), self.camera.view_projection(aspect));
            self.gl_timer.end(g);
            timeline::stamp(timeline, slot(frame), 3);
            if measured {
                self.gl_timer.end_frame(g, &mut times);
            } else {
                self.gl_timer.finish(g, &mut PassTimes::default());
            }
            unsafe { g.flush() };
            let now = Instant::now();
            if let Some(start) = last.replace(now) {
                if measured {
                    samples.frame_ms.push(common::ms_since(start));
                }
            }
        }
        // The last frame: until both APIs are done with it.
        unsafe { g.finish() };
        apis.commands.wait(vk, "vkWaitForFences after the last frame")?;
        samples.ao_ms.push(stamps.read_ms(vk)?);
        if let (Some(t), Some(last)) = (timeline.as_mut(), slot(count + 1)) {
            t.trace_done(vk, last, stamps)?;
        }
        self.gl_timer.finish(g, &mut times);
        for pass in ["raster", "composite"] {
            for &ms in times.samples(pass) {
                samples.passes.add(pass, ms);
            }
        }
        Ok(())
    }

    /// The pixels the scene covers (position w, the view depth, is 0 where nothing was drawn):
    /// the ones that cast AO rays. The camera stands still, so this holds for every frame.
    pub fn covered_pixels(&self, gl: &glow::Context) -> u64 {
        let (w, h) = (self.gbuffers.extent.width, self.gbuffers.extent.height);
        self.gbuffers.draw(gl, self.scene, &self.camera);
        let positions =
            common::instruments::output::read_texture_f32(gl, self.gbuffers.textures()[0], w, h, 4);
        positions.chunks_exact(4).filter(|p| p[3] != 0.0).count() as u64
    }

    /// How many pixels `GBuffers::draw_depth_first` draws otherwise than `draw`, in any of the
    /// three G-buffers, bit for bit, before any frame (GL has the images). Where two triangles
    /// reach a pixel at exactly the same depth, one pass keeps the first (`GL_LESS`) and depth
    /// first keeps the last (`GL_EQUAL` passes both): those pixels may differ, no others should.
    pub fn depth_first_differences(&self, gl: &glow::Context) -> u64 {
        let (w, h) = (self.gbuffers.extent.width, self.gbuffers.extent.height);
        let read = || {
            let textures = self.gbuffers.textures();
            textures
                .iter()
                .map(|&t| common::instruments::output::read_texture_f32(gl, t, w, h, 4))
                .collect::<Vec<_>>()
        };
        self.gbuffers.draw(gl, self.scene, &self.camera);
        let one_pass = read();
        self.gbuffers.draw_depth_first(gl, self.scene, &self.camera);
        let depth_first = read();
        let pixel_differs = |i: usize| {
            one_pass.iter().zip(&depth_first).any(|(a, b)| {
                a[4 * i..4 * i + 4].iter().zip(&b[4 * i..4 * i + 4]).any(|(x, y)| x.to_bits() != y.to_bits())
            })
        };
        (0..(w * h) as usize).filter(|&i| pixel_differs(i)).count() as u64
    }
}
