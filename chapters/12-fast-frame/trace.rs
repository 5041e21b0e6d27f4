//! Chapter 12's Vulkan side: the ray tracing pipeline that rebuilds each pixel's hit from its id
//! and traces the occlusion, the table of mesh ids it reads, and one frame's hand-overs.

use super::visibility::{MeshIds, Targets};
use anyhow::Result;
use ash::vk;
use common::base::vulkan::VulkanContext;
use common::clocks::timestamps::Timestamps;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BufferDesc, DeviceBuffer};
use common::rt::ao::Traced;
use common::rt::raytrace::{RayPipeline, RayShaders, raygen_bindings};
use common::scene::Camera;
use gpu_allocator::MemoryLocation;

const RAYGEN: &[u8] = include_bytes!("../../shaders/visibility_ao.rgen.spv");
const MISS: &[u8] = include_bytes!("../../shaders/miss.rmiss.spv");

// ANCHOR: surface_rays
/// The push constants of `shaders/visibility_ao.rgen` (std430, 128 bytes: the most every
/// Vulkan device accepts).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SurfaceRays {
    pub inverse_view_projection: [f32; 16],
    pub eye: [f32; 3],
    pub radius: f32,
    pub forward: [f32; 3],
    pub scene_scale: f32,
    pub samples: u32,
    pub accumulated: u32,
    pub mesh_count: u32,
    pub pattern: u32,
    pub meshes: u64,
    pub instances: u64,
}
// ANCHOR_END: surface_rays

/// What a frame's rays are asked to do, beside the camera.
#[derive(Clone, Copy)]
pub struct Rays {
    pub samples: u32,
    pub radius: f32,
    pub scene_scale: f32,
    pub pattern: Pattern,
    /// 0 for the frame; another number draws other rotations of the sequence (a reference
    /// whose errors are independent of the frame's).
    pub salt: u32,
}

// ANCHOR: pattern
/// Which points of the sample sequence each pixel's rays take (`--pattern`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pattern {
    /// Chapter 07's: each pixel its own rotation of the sequence.
    PerPixel,
    /// One rotation per 8x8 tile: every pixel of a tile shoots the same directions.
    Tile,
    /// One rotation per tile, and each pixel of a 2x2 block its own run of the sequence.
    Tile2x2,
    /// The same with 4x4 blocks.
    Tile4x4,
    /// One point per step for the whole tile, each pixel of a 4x4 block moved from it across
    /// the gap between the steps' points.
    Jitter4x4,
    /// The same with the whole 8x8 tile as the block.
    Jitter8x8,
}

impl Pattern {
    pub const ALL: [Pattern; 6] = [
        Pattern::PerPixel,
        Pattern::Tile,
        Pattern::Tile2x2,
        Pattern::Tile4x4,
        Pattern::Jitter4x4,
        Pattern::Jitter8x8,
    ];

    /// The shader's `pattern`: 0 per pixel, else the side of the block (+ 128: jittered).
    fn side(self) -> u32 {
        match self {
            Pattern::PerPixel => 0,
            Pattern::Tile => 1,
            Pattern::Tile2x2 => 2,
            Pattern::Tile4x4 => 4,
            Pattern::Jitter4x4 => 4 | 128,
            Pattern::Jitter8x8 => 8 | 128,
        }
    }
}
// ANCHOR_END: pattern

/// The pipeline, the mesh table it reads, and how far the running mean has got. Dropped, the
/// pipeline goes, then the mesh table; the GPU must be done with both.
pub struct SurfaceTracer {
    pipeline: RayPipeline,
    meshes: DeviceBuffer,
    mesh_count: u32,
    instances: u64,
    /// Rays per pixel already in the running mean; 0 starts it again.
    pub accumulated: u32,
}

impl SurfaceTracer {
    pub fn new(
        vk: &VulkanContext,
        shared: &RayTracedScene,
        ids: &[MeshIds],
        targets: &Targets,
    ) -> Result<Self> {
        // ANCHOR: pipeline
        // Bindings 0-2: the TLAS, the ids (from GL), the surface (for GL).
        let image = vk::DescriptorType::STORAGE_IMAGE;
        let bindings = raygen_bindings(&[vk::DescriptorType::ACCELERATION_STRUCTURE_KHR, image, image]);
        let allocator = &shared.allocator;
        let shaders = RayShaders { raygen: RAYGEN, miss: MISS };
        let pipeline = RayPipeline::new(vk, allocator, shaders, &bindings, size_of::<SurfaceRays>() as u32)?;
        pipeline.write_tlas(vk, 0, *shared.structures.tlas.handle);
        // ANCHOR_END: pipeline
        // The mesh table, written once: the ray generation shader reads it by its address.
        let bytes = bytemuck::cast_slice(ids);
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let mut meshes = DeviceBuffer::new(
            vk,
            allocator,
            BufferDesc {
                name: "mesh ids",
                size: bytes.len() as u64,
                usage,
                location: MemoryLocation::CpuToGpu,
            },
        )?;
        let mapped =
            meshes.allocation.mapped_slice_mut().ok_or_else(|| anyhow::anyhow!("mesh ids unmapped"))?;
        mapped[..bytes.len()].copy_from_slice(bytes);
        let instances = shared.buffers.instances.vk.device_address(vk);
        let tracer =
            SurfaceTracer { pipeline, meshes, mesh_count: ids.len() as u32, instances, accumulated: 0 };
        tracer.point_at(vk, targets);
        Ok(tracer)
    }

    /// The mesh table's device address and its number of meshes, for chapter 13's tracer, which
    /// rebuilds its hits from the same table.
    pub fn mesh_table(&self) -> (u64, u32) {
        (self.meshes.address, self.mesh_count)
    }

    /// The descriptors at one size's images (after a resize too: accumulation starts again).
    pub fn point_at(&self, vk: &VulkanContext, targets: &Targets) {
        self.pipeline.write_storage_image(vk, 1, *targets.visibility.view);
        self.pipeline.write_storage_image(vk, 2, *targets.surface.view);
    }

    pub fn resized(&mut self, vk: &VulkanContext, targets: &Targets) {
        self.point_at(vk, targets);
        self.accumulated = 0;
    }

    // ANCHOR: frame
    /// One frame: GL hands over the ids it just drew (and the surface, once it has had it),
    /// Vulkan rebuilds each hit, adds `rays.samples` rays to the running mean and hands both back;
    /// GL is told to wait for that before it composites.
    pub fn trace(
        &mut self,
        apis: Apis,
        targets: &Targets,
        camera: &Camera,
        rays: Rays,
        timestamps: Option<&Timestamps>,
    ) -> Result<()> {
        hand_over_around(apis, targets, timestamps, |cb| self.record(apis.vk, cb, targets, camera, rays))
    }

    /// The frame's Vulkan work, recorded into `cb`: the ray generation shader told about the
    /// camera and the rays, launched once per pixel; the running mean counts the rays.
    /// (`bench --probe overlap` records it between hand-overs of its own.)
    pub fn record(
        &mut self,
        vk: &VulkanContext,
        cb: vk::CommandBuffer,
        targets: &Targets,
        camera: &Camera,
        rays: Rays,
    ) {
        let aspect = targets.extent.width as f32 / targets.extent.height as f32;
        let push = SurfaceRays {
            inverse_view_projection: camera.view_projection(aspect).inverse().to_cols_array(),
            eye: camera.eye.into(),
            radius: rays.radius,
            forward: (camera.target - camera.eye).normalize().into(),
            scene_scale: rays.scene_scale,
            samples: rays.samples,
            accumulated: self.accumulated,
            mesh_count: self.mesh_count,
            pattern: rays.pattern.side() | rays.salt << 8,
            meshes: self.meshes.address,
            instances: self.instances,
        };
        self.pipeline.trace(vk, cb, bytemuck::bytes_of(&push), targets.extent);
        self.accumulated += rays.samples;
    }
    // ANCHOR_END: frame

    /// `total` rays per pixel from scratch, `rays.samples` at a time, as that many frames would
    /// trace them (for the checks, after the frames).
    pub fn retrace(
        &mut self,
        apis: Apis,
        targets: &Targets,
        camera: &Camera,
        rays: Rays,
        total: u32,
    ) -> Result<()> {
        self.accumulated = 0;
        while self.accumulated < total && rays.samples > 0 {
            let rays = Rays { samples: rays.samples.min(total - self.accumulated), ..rays };
            self.trace(apis, targets, camera, rays, None)?;
        }
        Ok(())
    }
}

// ANCHOR: hand_over
/// One frame of Vulkan work between GL's passes, through chapter 07's hand-over: GL hands over
/// the ids it just drew (and the surface, once it has had it), Vulkan records `work` between the
/// barriers that take both from GL and give them back, and GL is told to wait for that before it
/// composites. Chapter 13's tracer hands the same two images over around its own work.
pub fn hand_over_around(
    apis: Apis,
    targets: &Targets,
    timestamps: Option<&Timestamps>,
    work: impl FnOnce(vk::CommandBuffer),
) -> Result<()> {
    traced(targets, |images| common::rt::ao::hand_over_around(apis, images, timestamps, || {}, work))?;
    targets.gl_has_surface.set(true);
    Ok(())
}

/// Two images, where chapter 08 hands over three and reads 32 bytes a pixel: the ids in, the
/// surface (the running mean, and all the composite reads) out. (Public for the callers that
/// hand them over in halves: chapter 13, `bench --probe overlap`.)
pub fn traced<R>(targets: &Targets, hand_over: impl FnOnce(&Traced) -> R) -> R {
    let inputs = [&targets.visibility];
    hand_over(&Traced {
        inputs: &inputs,
        output: &targets.surface,
        gl_has_output: targets.gl_has_surface.get(),
        sampled: &[],
    })
}
// ANCHOR_END: hand_over

#[cfg(test)]
mod tests {
    use super::*;
    use common::base::shader_block::{assert_matches_spirv, rust_block};

    #[test]
    fn surface_rays_match_the_glsl_block() {
        let rust = rust_block!(SurfaceRays {
            inverse_view_projection,
            eye,
            radius,
            forward,
            scene_scale,
            samples,
            accumulated,
            mesh_count,
            pattern,
            meshes,
            instances,
        });
        assert_matches_spirv(RAYGEN, "SurfaceRays", rust);
    }

    #[test]
    fn mesh_ids_match_the_glsl_struct() {
        let rust = rust_block!(MeshIds { vertices, indices, first_id, triangles, first_instance, instances });
        assert_matches_spirv(RAYGEN, "MeshIds", rust);
    }
}
