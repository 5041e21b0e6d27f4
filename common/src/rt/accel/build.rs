//! The scene's structures built in one go: one compacted BLAS per mesh (or one flat BLAS for
//! the whole scene) and the TLAS over the shared instance buffer.

use super::memory::{BufferDesc, DeviceBuffer, GpuAllocator, query_pool};
use super::structure::{
    AccelerationStructure, Scratch, build_barrier, build_sizes, instances_at, instances_geometry,
    set_blas_address, tlas_built_barrier, triangles_geometry,
};
use crate::base::commands::Commands;
use crate::base::vulkan::VulkanContext;
use crate::clocks::timestamps::Timestamps;
use crate::instruments::fail;
use crate::scene::Scene;
use crate::scene::gbuffer::SceneBuffers;
use anyhow::{Context as _, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;

/// The scene's acceleration structures and what building them cost. Dropped, the TLAS goes
/// first (it refers to the BLASes), then its instance buffer, then the BLASes.
pub struct SceneAccel {
    pub loader: ash::khr::acceleration_structure::Device,
    pub tlas: AccelerationStructure,
    /// [`BlasLayout::Flat`]: the TLAS's one instance.
    pub flat_instance: Option<DeviceBuffer>,
    pub blases: Vec<AccelerationStructure>,
    pub stats: AccelStats,
}

#[derive(Debug, Default, Clone, serde::Serialize)]
pub struct AccelStats {
    /// How the BLASes hold the triangles (`None` for structures not built by [`build_with`]).
    pub layout: Option<BlasLayout>,
    pub blas_count: usize,
    /// Every BLAS as built, before compaction.
    pub blas_bytes: u64,
    /// Every BLAS after compaction.
    pub compacted_bytes: u64,
    pub tlas_bytes: u64,
    /// GPU time of the BLAS builds, the compaction copies and the TLAS build (None without
    /// timestamps). Not serialised: the report lists timings under `timings_ms`.
    #[serde(skip)]
    pub blas_build_ms: Option<f64>,
    #[serde(skip)]
    pub compaction_ms: Option<f64>,
    #[serde(skip)]
    pub tlas_build_ms: Option<f64>,
}

/// Builds, compacts and links the scene's acceleration structures. The BLASes read the meshes'
/// shared vertex and index buffers; each instance's BLAS address is written into the shared
/// instance buffer, which the TLAS then reads as it is.
pub fn build(
    vk: &VulkanContext,
    allocator: &GpuAllocator,
    commands: &Commands,
    scene: &Scene,
    buffers: &SceneBuffers,
) -> Result<SceneAccel> {
    build_with(vk, allocator, commands, scene, buffers, BuildOptions::STATIC)
}

/// Which bottom-level structures hold the scene's triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum BlasLayout {
    /// One BLAS per mesh and one TLAS instance per scene instance, as the scene itself is built
    /// (chapters 06-10): the only layout whose instances can move.
    PerMesh,
    /// One BLAS holding every instance's triangles (each instance one geometry, placed by its own
    /// transform) under a TLAS of one instance: for a static scene of many small instances, a
    /// ray walks one tree instead of a TLAS and then thousands of tiny BLASes.
    Flat,
}

/// The TLAS's build flags: [`TlasFlags::STATIC`] for a scene that stands still (chapters
/// 06-08), [`TlasFlags::UPDATABLE`] for instances that move (chapter 09).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TlasFlags(pub vk::BuildAccelerationStructureFlagsKHR);

impl TlasFlags {
    pub const STATIC: TlasFlags = TlasFlags(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE);
    /// ALLOW_UPDATE: the TLAS may later be updated in place (`MODE_UPDATE`); it can cost some
    /// trace speed and memory, so the static chapters do without it.
    pub const UPDATABLE: TlasFlags = TlasFlags(vk::BuildAccelerationStructureFlagsKHR::from_raw(
        vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE.as_raw()
            | vk::BuildAccelerationStructureFlagsKHR::ALLOW_UPDATE.as_raw(),
    ));
}

/// How [`build_with`] builds the scene's structures: the TLAS's flags, and which BLASes hold
/// the triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildOptions {
    pub tlas_flags: TlasFlags,
    pub layout: BlasLayout,
}

impl BuildOptions {
    /// What chapters 06-08 build: a static TLAS over one BLAS per mesh.
    pub const STATIC: BuildOptions =
        BuildOptions { tlas_flags: TlasFlags::STATIC, layout: BlasLayout::PerMesh };
}

/// [`build`], as `options` say.
pub fn build_with(
    vk: &VulkanContext,
    allocator: &GpuAllocator,
    commands: &Commands,
    scene: &Scene,
    buffers: &SceneBuffers,
    options: BuildOptions,
) -> Result<SceneAccel> {
    let BuildOptions { tlas_flags, layout } = options;
    let loader = ash::khr::acceleration_structure::Device::new(&vk.instance, &vk.device);
    let timestamps = Timestamps::with_count(vk, 2)?;
    let mut stats = AccelStats { layout: Some(layout), ..Default::default() };

    // ANCHOR: blas_geometry
    // One geometry per mesh: its triangles, read in place from the buffers GL draws.
    let geometries: Vec<vk::AccelerationStructureGeometryKHR> = scene
        .meshes
        .iter()
        .zip(&buffers.meshes)
        .map(|(mesh, [vertices, indices])| {
            let triangles = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
                .vertex_format(vk::Format::R32G32B32_SFLOAT) // Vertex::position, at offset 0
                .vertex_data(vk::DeviceOrHostAddressConstKHR {
                    device_address: vertices.vk.device_address(vk),
                })
                .vertex_stride(size_of::<crate::scene::Vertex>() as u64) // skipping the normal
                .max_vertex(mesh.vertices.len() as u32 - 1)
                .index_type(vk::IndexType::UINT32)
                .index_data(vk::DeviceOrHostAddressConstKHR {
                    device_address: indices.vk.device_address(vk),
                });
            vk::AccelerationStructureGeometryKHR::default()
                .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
                .geometry(vk::AccelerationStructureGeometryDataKHR { triangles })
                // Opaque: no any-hit shader will ever be asked about these triangles.
                .flags(vk::GeometryFlagsKHR::OPAQUE)
        })
        .collect();
    // ANCHOR_END: blas_geometry
    // Each BLAS's geometries and their triangle counts: one BLAS per mesh, or one for everything.
    let inputs: Vec<(Vec<vk::AccelerationStructureGeometryKHR>, Vec<u32>)> = match layout {
        BlasLayout::PerMesh => geometries
            .into_iter()
            .zip(&scene.meshes)
            .map(|(geometry, mesh)| (vec![geometry], vec![mesh.indices.len() as u32 / 3]))
            .collect(),
        BlasLayout::Flat => vec![flat_geometries(vk, scene, buffers)?],
    };
    stats.blas_count = inputs.len();

    // ANCHOR: blas_build
    let blas_flags = vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE
        | vk::BuildAccelerationStructureFlagsKHR::ALLOW_COMPACTION;
    let mut blases = Vec::new();
    let mut builds = Vec::new();
    let mut scratch_sizes = Vec::new();
    for (geometries, triangles) in &inputs {
        let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
            .ty(vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL)
            .flags(blas_flags)
            .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
            .geometries(geometries);
        let sizes = build_sizes(&loader, &info, triangles);
        let blas = AccelerationStructure::new(
            vk,
            allocator,
            info.ty,
            info.flags,
            sizes.acceleration_structure_size,
        )?;
        stats.blas_bytes += blas.bytes;
        scratch_sizes.push(sizes.build_scratch_size);
        builds.push((info.dst_acceleration_structure(*blas.handle), triangles));
        blases.push(blas);
    }
    // One scratch buffer, a separately aligned region for each build, so they may overlap on the GPU.
    let scratch = Scratch::new(vk, allocator, &scratch_sizes)?;
    let compacted_sizes =
        query_pool(vk, vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR, blases.len() as u32)?;
    commands.run_once(vk, |cb| unsafe {
        if let Some(t) = &timestamps {
            t.reset(vk, cb);
            t.write(vk, cb, vk::PipelineStageFlags::TOP_OF_PIPE, 0);
        }
        vk.device.cmd_reset_query_pool(cb, *compacted_sizes, 0, blases.len() as u32);
        for (i, (info, triangles)) in builds.iter().enumerate() {
            let info = info.scratch_data(vk::DeviceOrHostAddressKHR { device_address: scratch.address(i) });
            let ranges: Vec<_> = triangles
                .iter()
                .map(|&n| vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(n))
                .collect();
            loader.cmd_build_acceleration_structures(cb, &[info], &[&ranges]);
        }
        // The builds must finish before their compacted sizes can be read.
        build_barrier(vk, cb);
        let handles: Vec<_> = blases.iter().map(|b| *b.handle).collect();
        let query = vk::QueryType::ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR;
        loader.cmd_write_acceleration_structures_properties(cb, &handles, query, *compacted_sizes, 0);
        if let Some(t) = &timestamps {
            t.write(vk, cb, vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR, 1);
        }
    })?;
    // ANCHOR_END: blas_build
    stats.blas_build_ms = timestamps.as_ref().map(|t| t.between_ms(vk, 0, 1)).transpose()?;
    drop(scratch); // run_once waited: the builds are done with it

    // ANCHOR: compact
    // Compaction: a BLAS built with ALLOW_COMPACTION knows how small it can be; copy it into a
    // structure of that size and free the original.
    let mut sizes = vec![0u64; blases.len()];
    fail::call("vkGetQueryPoolResults for the compacted sizes", || unsafe {
        vk.device.get_query_pool_results(
            *compacted_sizes,
            0,
            &mut sizes,
            vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
        )
    })?;
    drop(compacted_sizes); // destroys the query pool
    let mut compacted = Vec::new();
    for &size in &sizes {
        compacted.push(AccelerationStructure::new(
            vk,
            allocator,
            vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
            blas_flags,
            size,
        )?);
        stats.compacted_bytes += size;
    }
    commands.run_once(vk, |cb| unsafe {
        if let Some(t) = &timestamps {
            t.reset(vk, cb);
            t.write(vk, cb, vk::PipelineStageFlags::TOP_OF_PIPE, 0);
        }
        for (from, to) in blases.iter().zip(&compacted) {
            let copy = vk::CopyAccelerationStructureInfoKHR::default()
                .src(*from.handle)
                .dst(*to.handle)
                .mode(vk::CopyAccelerationStructureModeKHR::COMPACT);
            loader.cmd_copy_acceleration_structure(cb, &copy);
        }
        if let Some(t) = &timestamps {
            t.write(vk, cb, vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR, 1);
        }
    })?;
    stats.compaction_ms = timestamps.as_ref().map(|t| t.between_ms(vk, 0, 1)).transpose()?;
    // The copies are done (run_once waited): the originals go.
    drop(std::mem::replace(&mut blases, compacted));
    // ANCHOR_END: compact

    // ANCHOR: instances
    // Each instance points at its mesh's BLAS. The write goes straight into the instance buffer
    // GL draws from (GL never reads these 8 bytes): the TLAS is built from the same buffer.
    let instances = &buffers.instances.vk;
    if layout == BlasLayout::PerMesh {
        for (blas, range) in blases.iter().zip(&scene.mesh_instances) {
            for i in range.clone() {
                set_blas_address(instances, i as usize, blas.address);
            }
        }
    }
    // ANCHOR_END: instances
    // Flat: the TLAS's one instance, the identity, in a buffer of its own (GL draws the scene's).
    let flat_instance = match layout {
        BlasLayout::PerMesh => None,
        BlasLayout::Flat => Some(one_instance(vk, allocator, blases[0].address)?),
    };

    // ANCHOR: tlas
    let geometry = match &flat_instance {
        None => instances_geometry(vk, instances),
        Some(buffer) => instances_at(buffer.address),
    };
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(vk::AccelerationStructureTypeKHR::TOP_LEVEL)
        .flags(tlas_flags.0) // PREFER_FAST_TRACE (and ALLOW_UPDATE for chapter 09)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(std::slice::from_ref(&geometry));
    let count = if flat_instance.is_some() { 1 } else { scene.instances.len() as u32 };
    let sizes = build_sizes(&loader, &info, &[count]);
    let tlas =
        AccelerationStructure::new(vk, allocator, info.ty, info.flags, sizes.acceleration_structure_size)?;
    let scratch = Scratch::new(vk, allocator, &[sizes.build_scratch_size])?;
    let info = info
        .dst_acceleration_structure(*tlas.handle)
        .scratch_data(vk::DeviceOrHostAddressKHR { device_address: scratch.address(0) });
    commands.run_once(vk, |cb| unsafe {
        if let Some(t) = &timestamps {
            t.reset(vk, cb);
            t.write(vk, cb, vk::PipelineStageFlags::TOP_OF_PIPE, 0);
        }
        // The compacting copies wrote the BLASes the TLAS build reads: a barrier is needed even
        // across submissions, as the earlier fence only ordered the CPU.
        build_barrier(vk, cb);
        let range = vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(count);
        loader.cmd_build_acceleration_structures(cb, &[info], &[&[range]]);
        // The traces of later submissions read the TLAS: its writes must reach the ray-tracing
        // stage too (a fence wait makes nothing visible to the device).
        tlas_built_barrier(vk, cb);
        if let Some(t) = &timestamps {
            t.write(vk, cb, vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR, 1);
        }
    })?;
    // ANCHOR_END: tlas
    stats.tlas_build_ms = timestamps.as_ref().map(|t| t.between_ms(vk, 0, 1)).transpose()?;
    stats.tlas_bytes = tlas.bytes;
    Ok(SceneAccel { loader, blases, tlas, flat_instance, stats })
}

/// A flat BLAS's geometries: every instance's mesh, each placed by the instance's transform,
/// read in place from the shared instance buffer (its first 48 bytes are a
/// `VkTransformMatrixKHR`, 16-byte aligned as `transformData` must be).
fn flat_geometries(
    vk: &VulkanContext,
    scene: &Scene,
    buffers: &SceneBuffers,
) -> Result<(Vec<vk::AccelerationStructureGeometryKHR<'static>>, Vec<u32>)> {
    let properties = super::structure::properties(vk);
    let (instances, triangles) = (scene.instances.len() as u64, scene.triangles());
    anyhow::ensure!(
        instances <= properties.max_geometry_count && triangles <= properties.max_primitive_count,
        "a flat BLAS of this scene needs {instances} geometries and {triangles} triangles; {} builds \
         at most {} (maxGeometryCount) and {} (maxPrimitiveCount): use the per-mesh layout",
        vk.info.name,
        properties.max_geometry_count,
        properties.max_primitive_count
    );
    let transforms = buffers.instances.vk.device_address(vk);
    let mut geometries = Vec::new();
    let mut counts = Vec::new();
    for ((mesh, [vertices, indices]), range) in
        scene.meshes.iter().zip(&buffers.meshes).zip(&scene.mesh_instances)
    {
        for i in range.clone() {
            let mut geometry = triangles_geometry(vk, mesh, &vertices.vk, &indices.vk);
            let at = transforms + i as u64 * size_of::<crate::scene::Instance>() as u64;
            // `triangles_geometry` made a TRIANGLES geometry: `triangles` is the union's live field.
            geometry.geometry.triangles.transform_data.device_address = at;
            geometries.push(geometry);
            counts.push(mesh.indices.len() as u32 / 3);
        }
    }
    Ok((geometries, counts))
}

/// One TLAS instance with the identity transform, pointing at `blas`, in a buffer of its own.
fn one_instance(
    vk: &VulkanContext,
    allocator: &GpuAllocator,
    blas: vk::DeviceAddress,
) -> Result<DeviceBuffer> {
    let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR;
    let size = size_of::<crate::scene::Instance>() as u64;
    let mut buffer = DeviceBuffer::new(
        vk,
        allocator,
        BufferDesc { name: "flat TLAS instance", size, usage, location: MemoryLocation::CpuToGpu },
    )?;
    let mut instance = crate::scene::Instance::new(glam::Mat4::IDENTITY, [255, 255, 255]);
    instance.blas_address = blas;
    let mapped = buffer.allocation.mapped_slice_mut().context("the instance buffer is mapped")?;
    mapped[..size as usize].copy_from_slice(bytemuck::bytes_of(&instance));
    Ok(buffer)
}
