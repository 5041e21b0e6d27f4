//! Structures that move (chapters 09 and 10): one structure rebuilt or updated in place every
//! frame, with a persistent scratch buffer.

use super::memory::GpuAllocator;
use super::structure::Scratch;
use super::structure::build_sizes;
use crate::base::commands::Commands;
use crate::base::vulkan::VulkanContext;
use crate::clocks::timestamps::{Timestamps, timed};
use anyhow::Result;
use ash::vk;

/// How [`InPlace::record`] refreshes a structure: a full build, or an update of the one there.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Refresh {
    /// `MODE_BUILD`: a new tree for the geometry as it is now. Slower; traces as fast as a
    /// first build.
    Rebuild,
    /// `MODE_UPDATE` with src = dst: the same tree, its boxes refitted around the geometry as it
    /// is now. Fast; the tree keeps the shape it had when built, so it traces slower the further
    /// things have moved since.
    Update,
}

// ANCHOR: in_place
/// One structure's build as [`InPlace`] repeats it every frame: the structure, its type, the
/// flags of its first build (an update must use the same), its geometry, and how many triangles
/// or instances that geometry holds.
#[derive(Clone, Copy)]
pub struct BuildInputs {
    pub handle: vk::AccelerationStructureKHR,
    pub ty: vk::AccelerationStructureTypeKHR,
    pub flags: vk::BuildAccelerationStructureFlagsKHR,
    pub geometry: vk::AccelerationStructureGeometryKHR<'static>,
    pub primitives: u32,
}

/// What it takes to rebuild or update one acceleration structure in place, every frame, without
/// allocating: the inputs of its first build and one persistent scratch buffer, large enough
/// for either (`buildScratchSize`, `updateScratchSize`).
pub struct InPlace {
    inputs: BuildInputs,
    scratch: Scratch,
    /// The driver's scratch sizes for an update and for a build, for the report.
    pub update_scratch_bytes: u64,
    pub build_scratch_bytes: u64,
}

impl InPlace {
    /// For `inputs.handle`. Without ALLOW_UPDATE in `inputs.flags` it can only be rebuilt.
    pub fn new(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        loader: &ash::khr::acceleration_structure::Device,
        inputs: BuildInputs,
    ) -> Result<Self> {
        let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(inputs.ty)
            .flags(inputs.flags)
            .geometries(std::slice::from_ref(&inputs.geometry));
        let sizes = build_sizes(loader, &info, &[inputs.primitives]);
        // One region, as large as the larger need: an update and a rebuild never run at once.
        let bytes = sizes.update_scratch_size.max(sizes.build_scratch_size);
        let scratch = Scratch::new(vk, allocator, &[bytes])?;
        Ok(InPlace {
            inputs,
            scratch,
            update_scratch_bytes: sizes.update_scratch_size,
            build_scratch_bytes: sizes.build_scratch_size,
        })
    }

    /// Records the rebuild or the update. The caller records the barriers around it: before,
    /// whatever wrote the inputs (and last read or wrote the structure or the scratch); after,
    /// whatever reads the result.
    pub fn record(
        &self,
        loader: &ash::khr::acceleration_structure::Device,
        cb: vk::CommandBuffer,
        refresh: Refresh,
    ) {
        let BuildInputs { handle, ty, flags, geometry, primitives } = &self.inputs;
        let updatable = flags.contains(vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE);
        assert!(refresh == Refresh::Rebuild || updatable, "updating a structure built without ALLOW_UPDATE");
        let (mode, source) = match refresh {
            Refresh::Rebuild => {
                (vk::BuildAccelerationStructureModeKHR::BUILD, vk::AccelerationStructureKHR::null())
            }
            // src = dst: updated in place, no second structure needed.
            Refresh::Update => (vk::BuildAccelerationStructureModeKHR::UPDATE, *handle),
        };
        let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(*ty)
            .flags(*flags) // an update must use the flags of the build it updates
            .mode(mode)
            .src_acceleration_structure(source)
            .dst_acceleration_structure(*handle)
            .geometries(std::slice::from_ref(geometry))
            .scratch_data(vk::DeviceOrHostAddressKHR { device_address: self.scratch.address(0) });
        let range = vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(*primitives);
        unsafe { loader.cmd_build_acceleration_structures(cb, &[info], &[&[range]]) };
    }

    // ANCHOR: refresh
    /// Records and submits the update (or rebuild), in its own command buffer, ahead of the
    /// frame's trace on the same queue (chapter 09's; chapter 13 moves an instance with it too).
    /// Queue order and the barriers below order it against the traces before and after it.
    pub fn submit(
        &self,
        vk: &VulkanContext,
        updates: &Commands,
        loader: &ash::khr::acceleration_structure::Device,
        refresh: Refresh,
        timer: Option<&Timestamps>,
    ) -> Result<()> {
        let cb = updates.begin(vk)?;
        let build = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
        let rays = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
        // Before: everything the update reads or overwrites must be ready.
        // - HOST / HOST_WRITE: the transforms the CPU just wrote, which the build reads as
        //   SHADER_READ. vkQueueSubmit already makes earlier host writes visible to the work it
        //   submits; the barrier states the dependency where the reader can see it.
        // - ACCELERATION_STRUCTURE_BUILD / _WRITE: the previous update wrote the TLAS and the
        //   scratch, which this one reads (src = dst) and writes again.
        // - RAY_TRACING_SHADER: the previous frame's rays read the TLAS this overwrites; a
        //   write-after-read needs only the execution dependency, no access flags.
        let before = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::HOST_WRITE | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR
                    | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
            );
        // After: the trace, submitted next, reads the TLAS from the ray tracing shaders. (A barrier
        // orders everything later in submission order on this queue, the next submission included.)
        let after = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
            .dst_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR);
        let none = vk::DependencyFlags::empty();
        unsafe {
            let host = vk::PipelineStageFlags::HOST;
            vk.device.cmd_pipeline_barrier(cb, host | build | rays, build, none, &[before], &[], &[]);
            timed(vk, cb, timer, build, || self.record(loader, cb, refresh));
            vk.device.cmd_pipeline_barrier(cb, build, rays, none, &[after], &[], &[]);
        }
        // No semaphore: the update reads nothing GL writes. It may run while GL draws.
        updates.submit(vk, None, None)
    }
    // ANCHOR_END: refresh
}
// ANCHOR_END: in_place
