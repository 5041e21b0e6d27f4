//! Memory Vulkan keeps to itself: gpu-allocator, buffers in it with their device addresses,
//! scratch space for builds, and query pools.

use crate::base::vulkan::VulkanContext;
use anyhow::{Context as _, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};

/// gpu-allocator for everything Vulkan keeps to itself, with device addresses on.
pub fn allocator(vk: &VulkanContext) -> Result<Allocator> {
    Allocator::new(&AllocatorCreateDesc {
        instance: vk.instance.clone(),
        device: vk.device.clone(),
        physical_device: vk.physical_device,
        debug_settings: Default::default(),
        buffer_device_address: vk.device_addresses,
        allocation_sizes: Default::default(),
    })
    .context("creating gpu-allocator's allocator")
}

/// A buffer in memory from gpu-allocator, with its device address. Dropped without
/// [`DeviceBuffer::destroy`] (an early return), it destroys the buffer and leaves its memory to
/// the allocator, which frees all of its memory when it is dropped.
pub struct DeviceBuffer {
    pub buffer: vk::Buffer,
    pub allocation: Allocation,
    pub address: vk::DeviceAddress,
    pub(super) device: ash::Device,
}

impl DeviceBuffer {
    pub fn new(
        vk: &VulkanContext,
        allocator: &mut Allocator,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Self> {
        let usage = usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        let info = vk::BufferCreateInfo::default().size(size).usage(usage);
        let buffer = unsafe { vk.device.create_buffer(&info, None) }.context("vkCreateBuffer")?;
        let mut guarded =
            DeviceBuffer { buffer, allocation: Allocation::default(), address: 0, device: vk.device.clone() };
        let requirements = unsafe { vk.device.get_buffer_memory_requirements(buffer) };
        let description = AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        };
        guarded.allocation = allocator
            .allocate(&description)
            .with_context(|| format!("allocating {size} bytes for {name}"))?;
        let allocation = &guarded.allocation;
        crate::base::resources::created(&format!("vk_buffer: {name}"), allocation.size());
        unsafe { vk.device.bind_buffer_memory(buffer, allocation.memory(), allocation.offset()) }?;
        guarded.address = unsafe {
            vk.device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(buffer))
        };
        Ok(guarded)
    }

    /// The buffer, then its memory, given back to the allocator.
    pub fn destroy(mut self, _vk: &VulkanContext, allocator: &mut Allocator) {
        let allocation = std::mem::take(&mut self.allocation);
        drop(self); // destroys the buffer
        let _ = allocator.free(allocation);
    }
}

impl Drop for DeviceBuffer {
    fn drop(&mut self) {
        crate::base::commands::wait_idle(&self.device);
        unsafe { self.device.destroy_buffer(self.buffer, None) };
    }
}

/// A query pool, destroyed when dropped (also on an early return, once the device is idle).
pub(super) struct QueryPool {
    pub(super) pool: vk::QueryPool,
    device: ash::Device,
}

impl Drop for QueryPool {
    fn drop(&mut self) {
        crate::base::commands::wait_idle(&self.device);
        unsafe { self.device.destroy_query_pool(self.pool, None) };
    }
}

pub(super) fn query_pool(vk: &VulkanContext, ty: vk::QueryType, count: u32) -> Result<QueryPool> {
    let info = vk::QueryPoolCreateInfo::default().query_type(ty).query_count(count);
    let pool = unsafe { vk.device.create_query_pool(&info, None) }.context("vkCreateQueryPool")?;
    crate::base::resources::created(&format!("vk_query_pool: {ty:?}"), 0);
    Ok(QueryPool { pool, device: vk.device.clone() })
}

/// Scratch memory for several builds: one buffer, each region aligned as the device requires.
pub(super) struct Scratch {
    buffer: DeviceBuffer,
    offsets: Vec<u64>,
}

impl Scratch {
    pub(super) fn new(vk: &VulkanContext, allocator: &mut Allocator, sizes: &[u64]) -> Result<Self> {
        let mut properties = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
        let mut properties2 = vk::PhysicalDeviceProperties2::default().push_next(&mut properties);
        unsafe { vk.instance.get_physical_device_properties2(vk.physical_device, &mut properties2) };
        let alignment = properties.min_acceleration_structure_scratch_offset_alignment.max(1) as u64;
        let mut offsets = Vec::new();
        let mut total = 0;
        for size in sizes {
            offsets.push(total);
            total += size.next_multiple_of(alignment);
        }
        // Room to slide the start up to the next aligned address.
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let buffer = DeviceBuffer::new(
            vk,
            allocator,
            "build scratch",
            total + alignment,
            usage,
            MemoryLocation::GpuOnly,
        )?;
        let start = buffer.address.next_multiple_of(alignment) - buffer.address;
        Ok(Scratch { buffer, offsets: offsets.into_iter().map(|o| o + start).collect() })
    }

    pub(super) fn address(&self, i: usize) -> vk::DeviceAddress {
        self.buffer.address + self.offsets[i]
    }

    pub(super) fn destroy(self, vk: &VulkanContext, allocator: &mut Allocator) {
        self.buffer.destroy(vk, allocator);
    }
}
