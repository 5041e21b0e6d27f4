//! One acceleration structure in its own buffer, the geometries it is built from, and what a
//! build needs around it: sizes, scratch space, barriers, the device's limits, the instances' BLAS
//! addresses.

use super::memory::{BufferDesc, DeviceBuffer, GpuAllocator};
use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::interop::exportable::ExportedBuffer;
use crate::scene::{Instance, Scene};
use anyhow::Result;
use ash::vk;
use gpu_allocator::MemoryLocation;

/// One acceleration structure and the buffer that holds it; destroyed when dropped (the
/// structure, then its buffer). The GPU must be done with it.
pub struct AccelerationStructure {
    pub handle: Owned<vk::AccelerationStructureKHR>,
    pub buffer: DeviceBuffer,
    pub address: vk::DeviceAddress,
    pub bytes: u64,
}

impl AccelerationStructure {
    /// An acceleration structure of `bytes` bytes (from `vkGetAccelerationStructureBuildSizesKHR`)
    /// in a buffer of its own, not yet built.
    pub fn new(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        ty: vk::AccelerationStructureTypeKHR,
        flags: vk::BuildAccelerationStructureFlagsKHR,
        bytes: u64,
    ) -> Result<Self> {
        let loader = ash::khr::acceleration_structure::Device::new(&vk.instance, &vk.device);
        let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR;
        let location = MemoryLocation::GpuOnly;
        let desc = BufferDesc { name: "acceleration structure", size: bytes, usage, location };
        let buffer = DeviceBuffer::new(vk, allocator, desc)?;
        let info =
            vk::AccelerationStructureCreateInfoKHR::default().buffer(*buffer.buffer).size(bytes).ty(ty);
        // On failure `buffer` is dropped, which destroys it.
        let what = format!("vkCreateAccelerationStructureKHR ({ty:?})");
        let handle = create(&loader, &what, || unsafe { loader.create_acceleration_structure(&info, None) })?;
        // Its bytes are counted with its buffer; the kind says what was built, and how.
        crate::instruments::resources::created(&format!("vk_acceleration_structure: {ty:?}, {flags:?}"), 0);
        let address_info =
            vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(*handle);
        let address = unsafe { loader.get_acceleration_structure_device_address(&address_info) };
        Ok(AccelerationStructure { handle, buffer, address, bytes })
    }
}

/// A TLAS geometry of the instances at `address`.
pub(super) fn instances_at(address: vk::DeviceAddress) -> vk::AccelerationStructureGeometryKHR<'static> {
    let data = vk::AccelerationStructureGeometryInstancesDataKHR::default()
        .array_of_pointers(false)
        .data(vk::DeviceOrHostAddressConstKHR { device_address: address });
    vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::INSTANCES)
        .geometry(vk::AccelerationStructureGeometryDataKHR { instances: data })
}

// ANCHOR: instances_geometry
/// The TLAS's one geometry: every instance, read in place from the shared instance buffer.
pub fn instances_geometry(
    vk: &VulkanContext,
    instances: &ExportedBuffer,
) -> vk::AccelerationStructureGeometryKHR<'static> {
    // An array of VkAccelerationStructureInstanceKHR, as Instance is (not of pointers).
    instances_at(instances.device_address(vk))
}
// ANCHOR_END: instances_geometry

pub(super) fn build_sizes(
    loader: &ash::khr::acceleration_structure::Device,
    info: &vk::AccelerationStructureBuildGeometryInfoKHR,
    primitives: &[u32],
) -> vk::AccelerationStructureBuildSizesInfoKHR<'static> {
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    unsafe {
        loader.get_acceleration_structure_build_sizes(
            vk::AccelerationStructureBuildTypeKHR::DEVICE,
            info,
            primitives,
            &mut sizes,
        )
    };
    sizes
}

/// Acceleration-structure writes finish before later builds, copies or queries read them.
pub(super) fn build_barrier(vk: &VulkanContext, cb: vk::CommandBuffer) {
    let barrier = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
        .dst_access_mask(
            vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR
                | vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR,
        );
    let stage = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
    unsafe {
        vk.device.cmd_pipeline_barrier(cb, stage, stage, vk::DependencyFlags::empty(), &[barrier], &[], &[])
    };
}

/// The TLAS build's writes, made visible to the ray-tracing shaders that trace against it (in this
/// or any later submission) and to later builds (an update, chapter 09).
pub(super) fn tlas_built_barrier(vk: &VulkanContext, cb: vk::CommandBuffer) {
    let barrier = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
        .dst_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR);
    let src = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
    let dst = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR
        | vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
    unsafe {
        vk.device.cmd_pipeline_barrier(cb, src, dst, vk::DependencyFlags::empty(), &[barrier], &[], &[])
    };
}

/// Writes `Instance::blas_address` of instance `index` through Vulkan's mapping.
pub fn set_blas_address(instances: &ExportedBuffer, index: usize, address: vk::DeviceAddress) {
    let offset = index * size_of::<Instance>() + std::mem::offset_of!(Instance, blas_address);
    assert!(offset + 8 <= instances.bytes as usize, "instance {index} is outside the buffer");
    // SAFETY: in bounds (checked above) of the coherent mapping; no GPU work is using it now.
    unsafe { instances.mapped.add(offset).cast::<u64>().write_unaligned(address) };
}

/// The device's acceleration-structure limits (`VkPhysicalDeviceAccelerationStructurePropertiesKHR`).
pub fn properties(vk: &VulkanContext) -> vk::PhysicalDeviceAccelerationStructurePropertiesKHR<'static> {
    let mut properties = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
    let mut properties2 = vk::PhysicalDeviceProperties2::default().push_next(&mut properties);
    unsafe { vk.instance.get_physical_device_properties2(vk.physical_device, &mut properties2) };
    properties
}

/// Refuses, before anything is allocated, a scene whose structures the device cannot build:
/// more instances than a TLAS holds (`maxInstanceCount`), or a mesh with more triangles than a
/// BLAS geometry holds (`maxPrimitiveCount`).
pub fn check_limits(vk: &VulkanContext, scene: &Scene) -> Result<()> {
    let properties = properties(vk);
    let device = &vk.info.name;
    let instances = scene.instances.len() as u64;
    anyhow::ensure!(
        instances <= properties.max_instance_count,
        "the scene has {instances} instances; {device} builds a TLAS of at most {} (maxInstanceCount)",
        properties.max_instance_count
    );
    for mesh in &scene.meshes {
        let triangles = mesh.indices.len() as u64 / 3;
        anyhow::ensure!(
            triangles <= properties.max_primitive_count,
            "mesh {:?} has {triangles} triangles; {device} builds a BLAS geometry of at most {} \
             (maxPrimitiveCount)",
            mesh.name,
            properties.max_primitive_count
        );
    }
    Ok(())
}

/// One mesh's triangles as a BLAS geometry, read in place from the buffers GL draws (as chapter
/// 06's `build` does).
pub fn triangles_geometry(
    vk: &VulkanContext,
    mesh: &crate::scene::Mesh,
    vertices: &ExportedBuffer,
    indices: &ExportedBuffer,
) -> vk::AccelerationStructureGeometryKHR<'static> {
    let triangles = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
        .vertex_format(vk::Format::R32G32B32_SFLOAT)
        .vertex_data(vk::DeviceOrHostAddressConstKHR { device_address: vertices.device_address(vk) })
        .vertex_stride(size_of::<crate::scene::Vertex>() as u64)
        .max_vertex(mesh.vertices.len() as u32 - 1)
        .index_type(vk::IndexType::UINT32)
        .index_data(vk::DeviceOrHostAddressConstKHR { device_address: indices.device_address(vk) });
    vk::AccelerationStructureGeometryKHR::default()
        .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
        .geometry(vk::AccelerationStructureGeometryDataKHR { triangles })
        .flags(vk::GeometryFlagsKHR::OPAQUE)
}

/// The size an acceleration structure of `ty`, built with `flags` from `geometry` with
/// `primitives` triangles or instances, needs.
pub fn structure_size(
    loader: &ash::khr::acceleration_structure::Device,
    ty: vk::AccelerationStructureTypeKHR,
    flags: vk::BuildAccelerationStructureFlagsKHR,
    geometry: &vk::AccelerationStructureGeometryKHR,
    primitives: u32,
) -> u64 {
    let info = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(ty)
        .flags(flags)
        .geometries(std::slice::from_ref(geometry));
    build_sizes(loader, &info, &[primitives]).acceleration_structure_size
}

/// Scratch memory for several builds: one buffer, each region aligned as the device requires.
pub(super) struct Scratch {
    buffer: DeviceBuffer,
    offsets: Vec<u64>,
}

impl Scratch {
    pub(super) fn new(vk: &VulkanContext, allocator: &GpuAllocator, sizes: &[u64]) -> Result<Self> {
        let properties = properties(vk);
        let alignment = properties.min_acceleration_structure_scratch_offset_alignment.max(1) as u64;
        let mut offsets = Vec::new();
        let mut total = 0;
        for size in sizes {
            offsets.push(total);
            total += size.next_multiple_of(alignment);
        }
        // Room to slide the start up to the next aligned address.
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let (size, location) = (total + alignment, MemoryLocation::GpuOnly);
        let desc = BufferDesc { name: "build scratch", size, usage, location };
        let buffer = DeviceBuffer::new(vk, allocator, desc)?;
        let start = buffer.address.next_multiple_of(alignment) - buffer.address;
        Ok(Scratch { buffer, offsets: offsets.into_iter().map(|o| o + start).collect() })
    }

    pub(super) fn address(&self, i: usize) -> vk::DeviceAddress {
        self.buffer.address + self.offsets[i]
    }
}
