//! Chapter 13's flags and what it makes from them before its first frame, shared with
//! `convergence temporal`, which varies this frame rather than making its own: the scene, the
//! path and the rays' budget (the chapter's step 1), then the shared scene with its structures,
//! chapter 12's images and passes, and the history (steps 3 and 4).

use super::frame::{Motion, Passes, Sized};
use super::path::{Path, PathArgs};
use super::tracer::{Budget, RayArgs, TemporalTracer};
use anyhow::{Result, ensure};
use ash::vk;
use common::base::commands::Commands;
use common::base::gl::GlContext;
use common::base::vulkan::VulkanContext;
use common::clocks::timestamps::Timestamps;
use common::frame::overlay::Overlays;
use common::instruments::report::Report;
use common::interop::handoff::{Apis, Handoff};
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, BuildInputs, InPlace, TlasFlags, instances_geometry};
use common::rt::ao::AoArgs;
use common::scene::{Camera, Instance, Scene, SceneArgs};
use fast_frame::composite::{ComputeComposite, Uniforms};
use fast_frame::trace::SurfaceTracer;
use fast_frame::visibility::{self, MeshIds, Targets, VisibilityPass};

/// Chapter 13's flags, the ones its reader turns. `convergence temporal` flattens them as well,
/// beside the flags it measures with.
#[derive(clap::Args, Debug, Clone)]
pub struct TemporalArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub rays: RayArgs,
    #[command(flatten)]
    pub path: PathArgs,
    /// How far an occluder counts, in world units [default: 5% of the scene's diagonal].
    #[arg(long, value_parser = common::base::cli::number::<f32>(0.0..=1e6), allow_negative_numbers = true)]
    pub radius: Option<f32>,
    /// Contrast: the picture shows visibility to this power (1-3).
    #[arg(long, default_value_t = 2.0, value_parser = common::base::cli::number::<f32>(1.0..=3.0), allow_negative_numbers = true)]
    pub power: f32,
    /// Blur radius in pixels (0 skips the blur), as chapter 12's.
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=8))]
    pub blur: u32,
    /// As chapter 12's `--blas`; only the per-mesh layout lets an instance move.
    #[arg(long, value_enum, default_value = "per-mesh")]
    pub blas: BlasLayout,
}

/// What the frames are drawn from, before any GPU work: the scene, the camera the path starts
/// from, the path, the occlusion radius and the rays' budget.
pub struct Stage {
    pub scene: Scene,
    pub start: Camera,
    pub path: Path,
    pub radius: f32,
    pub budget: Budget,
}

impl TemporalArgs {
    /// The scene, the path the camera and one instance follow, and the rays' budget, for
    /// pictures of `aspect` (width over height). The moving instance stands where frame 0 has it.
    pub fn stage(&self, aspect: f32, report: &mut Report) -> Result<Stage> {
        let mut scene = self.scene.load()?;
        let start = Camera::framing(scene.bounds, aspect);
        let path = Path::new(&scene, start, &self.path);
        if let Some(moving) = &path.moving {
            ensure!(
                self.blas == BlasLayout::PerMesh,
                "--blas flat holds every instance in one tree, so none can move: use --blas per-mesh, or --mover none"
            );
            // Where it stands at frame 0, before the scene is shared and its structures built.
            scene.instances[moving.index].transform = Instance::new(moving.at(0), [0; 3]).transform;
        }
        let ao =
            AoArgs { samples: self.rays.samples, radius: self.radius, power: self.power, max_samples: 1 };
        let radius = ao.radius(&scene)?;
        let budget = Budget::new(&self.rays, radius, scene.size() / 2.0);
        if let Some(reason) = common::rt::ao::nothing_to_trace(budget.fresh, radius) {
            eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
        }
        report.set("path", self.path.path);
        report.set("moving_instance", path.moving.as_ref().map(|m| m.index));
        Ok(Stage { scene, start, path, radius, budget })
    }
}

/// Everything the frames draw with, owned from birth and dropped in the order written: the
/// command buffers, the passes, the images of one size, the structures, the shared scene last.
// ANCHOR: objects
pub struct Objects {
    /// First: its `Drop` waits for the last frame's Vulkan work before anything below goes.
    pub commands: Commands,
    pub updates: Commands,
    pub timestamps: Option<Timestamps>,
    pub overlays: Overlays,
    pub composite: ComputeComposite,
    /// The images, and the two tracers that point at them (the history is the temporal one's).
    pub sized: Sized,
    pub visibility: VisibilityPass,
    pub tlas: Option<InPlace>,
    pub ids: Vec<MeshIds>,
    /// The structures, then the shared buffers, each GL side first.
    pub shared: RayTracedScene,
}
// ANCHOR_END: objects

impl Objects {
    /// The shared scene and its structures, with a TLAS updated in place where an instance moves;
    /// then chapter 12's images and passes for pictures of `extent`, the history, and the
    /// command buffers.
    pub fn new(
        (vk, gl, handoff): (&VulkanContext, &GlContext, &Handoff),
        stage: &Stage,
        blas: BlasLayout,
        extent: vk::Extent2D,
    ) -> Result<Objects> {
        let scene = &stage.scene;
        // ANCHOR: structures
        let flags = if stage.path.moving.is_some() { TlasFlags::UPDATABLE } else { TlasFlags::STATIC };
        let shared = RayTracedScene::with_layout(vk, gl, scene, flags, blas)?;
        let ids = visibility::number_triangles(vk, scene, &shared.buffers)?;
        let loader = &shared.structures.loader;
        let tlas = match stage.path.moving {
            Some(_) => {
                let inputs = BuildInputs {
                    handle: *shared.structures.tlas.handle,
                    ty: vk::AccelerationStructureTypeKHR::TOP_LEVEL,
                    flags: flags.0,
                    geometry: instances_geometry(vk, &shared.buffers.instances.vk),
                    primitives: scene.instances.len() as u32,
                };
                Some(InPlace::new(vk, &shared.allocator, loader, inputs)?)
            }
            None => None,
        };
        // ANCHOR_END: structures

        let targets = Targets::new(vk, gl, handoff, extent)?;
        let visibility = VisibilityPass::new(gl, &shared.buffers)?;
        let fresh = SurfaceTracer::new(vk, &shared, &ids, &targets)?;
        let temporal =
            TemporalTracer::new(vk, &shared, fresh.mesh_table(), &targets, stage.budget.fresh_pass)?;
        let sized = Sized { targets, fresh, temporal };
        let composite = ComputeComposite::new(&gl.gl)?;
        let overlays = Overlays::new(&gl.gl, scene, if scene.instances.len() > 1 { 1 } else { 0 })?;
        let timestamps = Timestamps::new(vk)?;
        let updates = Commands::new(vk)?;
        let commands = Commands::new(vk)?;
        Ok(Objects {
            commands,
            updates,
            timestamps,
            overlays,
            composite,
            sized,
            visibility,
            tlas,
            ids,
            shared,
        })
    }

    /// What a frame draws with, and apart from it (a resize remakes them) the images of one size.
    /// `ids_ahead`: whether a frame draws the next one's ids before it waits (chapter 13's does).
    pub fn passes<'a>(
        &'a mut self,
        (vk, gl, handoff): (&'a VulkanContext, &'a GlContext, &'a Handoff),
        stage: &'a Stage,
        uniforms: Uniforms,
        ids_ahead: bool,
    ) -> (Passes<'a>, &'a mut Sized) {
        let passes = Passes {
            apis: Apis { vk, gl, handoff, commands: &self.commands },
            scene: &stage.scene,
            shared: &self.shared,
            ids: &self.ids,
            visibility: &self.visibility,
            composite: &self.composite,
            overlays: Some(&self.overlays),
            path: &stage.path,
            motion: self.tlas.as_ref().map(|tlas| Motion {
                instances: &self.shared.buffers.instances.vk,
                tlas,
                loader: &self.shared.structures.loader,
                updates: &self.updates,
            }),
            timestamps: self.timestamps.as_ref(),
            ids_ahead,
            uniforms,
            radius: stage.radius,
        };
        (passes, &mut self.sized)
    }
}
