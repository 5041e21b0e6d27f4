//! Memory Vulkan keeps to itself: gpu-allocator, buffers in it with their device addresses, and
//! query pools. It knows nothing of acceleration structures (`structure` stands on it).

use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::Result;
use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{
    Allocation, AllocationCreateDesc, AllocationScheme, Allocator, AllocatorCreateDesc,
};
use std::cell::RefCell;
use std::rc::Rc;

// ANCHOR: allocator
/// gpu-allocator's allocator, shared by everything that holds memory from it: each owner keeps
/// a handle and gives its memory back when dropped. The allocator itself, with the memory blocks
/// it holds, goes with the last handle: so no chapter frees it by hand, and none can free it
/// while memory from it is still in use.
#[derive(Clone)]
pub struct GpuAllocator(Rc<RefCell<Allocator>>);

/// gpu-allocator for everything Vulkan keeps to itself, with device addresses on.
pub fn allocator(vk: &VulkanContext) -> Result<GpuAllocator> {
    let description = AllocatorCreateDesc {
        instance: (*vk.instance).clone(),
        device: vk.device.clone(),
        physical_device: vk.physical_device,
        debug_settings: Default::default(),
        buffer_device_address: vk.device_addresses,
        allocation_sizes: Default::default(),
    };
    let allocator = fail::call("creating gpu-allocator's allocator", || Allocator::new(&description))?;
    Ok(GpuAllocator(Rc::new(RefCell::new(allocator))))
}

impl GpuAllocator {
    /// Memory for `description`, as one fallible step; given back when dropped.
    pub fn allocate(&self, description: &AllocationCreateDesc) -> Result<Memory> {
        let what = format!("allocating {} bytes for {}", description.requirements.size, description.name);
        let allocation = fail::call(&what, || self.0.borrow_mut().allocate(description))?;
        Ok(Memory { allocation, allocator: self.clone() })
    }
}

/// Memory from gpu-allocator, given back to it when dropped. The GPU must be done with it.
pub struct Memory {
    allocation: Allocation,
    allocator: GpuAllocator,
}

impl std::ops::Deref for Memory {
    type Target = Allocation;
    fn deref(&self) -> &Allocation {
        &self.allocation
    }
}

impl std::ops::DerefMut for Memory {
    fn deref_mut(&mut self) -> &mut Allocation {
        &mut self.allocation
    }
}

impl Drop for Memory {
    fn drop(&mut self) {
        // A failure to free leaves the block to the allocator, which frees every block when it goes.
        let _ = self.allocator.0.borrow_mut().free(std::mem::take(&mut self.allocation));
    }
}
// ANCHOR_END: allocator

/// A buffer in memory from gpu-allocator, with its device address. Dropped, it destroys the
/// buffer, then gives its memory back (fields, in order).
pub struct DeviceBuffer {
    pub buffer: Owned<vk::Buffer>,
    pub allocation: Memory,
    pub address: vk::DeviceAddress,
}

/// What a [`DeviceBuffer`] is for, as gpu-allocator's `AllocationCreateDesc` describes an
/// allocation: a name (in errors and the resource counts), a size, the buffer's usage, and where
/// its memory lives (`GpuOnly`, or `CpuToGpu` to write it from the CPU).
pub struct BufferDesc<'a> {
    pub name: &'a str,
    pub size: u64,
    pub usage: vk::BufferUsageFlags,
    pub location: MemoryLocation,
}

impl DeviceBuffer {
    pub fn new(vk: &VulkanContext, allocator: &GpuAllocator, desc: BufferDesc) -> Result<Self> {
        let BufferDesc { name, size, usage, location } = desc;
        let usage = usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        let info = vk::BufferCreateInfo::default().size(size).usage(usage);
        let what = format!("vkCreateBuffer for the {name}");
        let buffer = create(&vk.device, &what, || unsafe { vk.device.create_buffer(&info, None) })?;
        let requirements = unsafe { vk.device.get_buffer_memory_requirements(*buffer) };
        let description = AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        };
        let allocation = allocator.allocate(&description)?;
        crate::instruments::resources::created(&format!("vk_buffer: {name}"), allocation.size());
        fail::call(&format!("vkBindBufferMemory for the {name}"), || unsafe {
            vk.device.bind_buffer_memory(*buffer, allocation.memory(), allocation.offset())
        })?;
        let address = unsafe {
            vk.device.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(*buffer))
        };
        Ok(DeviceBuffer { buffer, allocation, address })
    }
}

/// A query pool, destroyed when dropped.
pub(super) type QueryPool = Owned<vk::QueryPool>;

pub(super) fn query_pool(vk: &VulkanContext, ty: vk::QueryType, count: u32) -> Result<QueryPool> {
    let info = vk::QueryPoolCreateInfo::default().query_type(ty).query_count(count);
    let what = format!("vkCreateQueryPool ({ty:?})");
    let pool = create(&vk.device, &what, || unsafe { vk.device.create_query_pool(&info, None) })?;
    crate::instruments::resources::created(&format!("vk_query_pool: {ty:?}"), 0);
    Ok(pool)
}
