//! Recording and submitting Vulkan work: one command buffer reused every frame, guarded by a
//! fence, plus one-shot submissions for set-up.

use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::Result;
use ash::vk;

/// A command pool with one primary command buffer and the fence of its last submission.
///
/// The one owner that waits: dropped, it waits for its last submission before destroying the
/// pool. A chapter makes the `Commands` its frames submit through after everything those frames
/// use, so that Rust, dropping locals newest first, drops it first: on an early return, the work
/// in flight is done before anything it uses is destroyed. No other owner waits.
pub struct Commands {
    /// Signalled when the last submission of `buffer` has finished.
    pub fence: Owned<vk::Fence>,
    /// Freed with its pool.
    pub buffer: vk::CommandBuffer,
    pub pool: Owned<vk::CommandPool>,
    /// Whether a submission is on its way to signalling `fence`. A failed `vkQueueSubmit` leaves
    /// an already reset fence unsignalled for ever: nothing may wait for it then.
    in_flight: std::cell::Cell<bool>,
    device: ash::Device,
}

impl Commands {
    pub fn new(vk: &VulkanContext) -> Result<Self> {
        let device = &vk.device;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(vk.queue_family_index)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let pool = create(device, "vkCreateCommandPool", || unsafe {
            device.create_command_pool(&pool_info, None)
        })?;
        let allocate = vk::CommandBufferAllocateInfo::default().command_pool(*pool).command_buffer_count(1);
        let buffer =
            fail::call("vkAllocateCommandBuffers", || unsafe { device.allocate_command_buffers(&allocate) })?
                [0];
        // Created signalled, so that waiting before the first submission returns at once.
        let fence_info = vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED);
        let fence = create(device, "vkCreateFence", || unsafe { device.create_fence(&fence_info, None) })?;
        Ok(Commands { fence, buffer, pool, in_flight: std::cell::Cell::new(false), device: device.clone() })
    }

    // ANCHOR: begin
    /// Waits until the previous submission is done (the buffer and what it uses are free
    /// again), then starts recording. The fence is reset later, by `submit`.
    pub fn begin(&self, vk: &VulkanContext) -> Result<vk::CommandBuffer> {
        unsafe {
            if self.in_flight.get() {
                self.wait(vk, "vkWaitForFences for the previous submission")?;
            }
            fail::call("vkResetCommandBuffer", || {
                vk.device.reset_command_buffer(self.buffer, vk::CommandBufferResetFlags::empty())
            })?;
            let begin =
                vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            fail::call("vkBeginCommandBuffer", || vk.device.begin_command_buffer(self.buffer, &begin))?;
        }
        Ok(self.buffer)
    }

    /// Ends recording and submits, waiting on `wait` (at `wait_stage`) and signalling `signal`
    /// and the fence.
    pub fn submit(
        &self,
        vk: &VulkanContext,
        wait: Option<(vk::Semaphore, vk::PipelineStageFlags)>,
        signal: Option<vk::Semaphore>,
    ) -> Result<()> {
        let waits: Vec<vk::Semaphore> = wait.iter().map(|(s, _)| *s).collect();
        let stages: Vec<vk::PipelineStageFlags> = wait.iter().map(|(_, stage)| *stage).collect();
        let signals: Vec<vk::Semaphore> = signal.into_iter().collect();
        let buffers = [self.buffer];
        let submit = vk::SubmitInfo::default()
            .wait_semaphores(&waits)
            .wait_dst_stage_mask(&stages)
            .command_buffers(&buffers)
            .signal_semaphores(&signals);
        unsafe {
            fail::call("vkEndCommandBuffer", || vk.device.end_command_buffer(self.buffer))?;
            // Reset only now, with only the submission left to fail: a fence reset earlier, then
            // not submitted, would never signal, and the next wait would hang. (A failed reset
            // leaves the fence signalled, and nothing in flight.)
            fail::call("vkResetFences", || vk.device.reset_fences(&[*self.fence]))?;
            fail::call("vkQueueSubmit", || vk.device.queue_submit(vk.queue, &[submit], *self.fence))?;
        }
        self.in_flight.set(true);
        Ok(())
    }
    // ANCHOR_END: begin

    /// Records with `record`, submits, and waits for the GPU: for set-up work, not for frames.
    pub fn run_once(&self, vk: &VulkanContext, record: impl FnOnce(vk::CommandBuffer)) -> Result<()> {
        let cb = self.begin(vk)?;
        record(cb);
        self.submit(vk, None, None)?;
        self.wait(vk, "vkWaitForFences for one-shot work")
    }

    /// Waits for the last submission (see [`wait_for`]); `what` names the wait.
    pub fn wait(&self, vk: &VulkanContext, what: &str) -> Result<()> {
        let waited = wait_for(vk, *self.fence, what);
        self.in_flight.set(false);
        waited
    }
}

/// Waits for `fence`, as one step of `instruments::fail` named `what`. Failed or not, the work is over
/// when it returns: a failed wait (device lost, or injected) waits once more, its result
/// ignored, so that whatever the caller drops on its way out is no longer in use.
pub fn wait_for(vk: &VulkanContext, fence: vk::Fence, what: &str) -> Result<()> {
    let waited = fail::call(what, || unsafe { vk.device.wait_for_fences(&[fence], true, u64::MAX) });
    if waited.is_err() {
        let _ = unsafe { vk.device.wait_for_fences(&[fence], true, u64::MAX) };
    }
    waited
}

impl Drop for Commands {
    /// Waits for the last submission; then (fields) the fence and the pool (and its buffer) go.
    fn drop(&mut self) {
        if self.in_flight.get() {
            let _ = unsafe { self.device.wait_for_fences(&[*self.fence], true, u64::MAX) };
        }
    }
}

// ANCHOR: image_barrier
/// A barrier over a whole buffer: the accesses to make available and visible `(src, dst)`, and
/// the queue families ownership moves between (`QUEUE_FAMILY_IGNORED` twice for none).
pub fn buffer_barrier<'a>(
    buffer: vk::Buffer,
    (src, dst): (vk::AccessFlags, vk::AccessFlags),
    (from, to): (u32, u32),
) -> vk::BufferMemoryBarrier<'a> {
    vk::BufferMemoryBarrier::default()
        .buffer(buffer)
        .offset(0)
        .size(vk::WHOLE_SIZE)
        .src_access_mask(src)
        .dst_access_mask(dst)
        .src_queue_family_index(from)
        .dst_queue_family_index(to)
}

/// A barrier over a whole colour image: the layout change `(old, new)`, the accesses to make
/// available and visible `(src, dst)`, and the queue families ownership moves between
/// (`QUEUE_FAMILY_IGNORED` twice for none).
pub fn image_barrier<'a>(
    image: vk::Image,
    (old, new): (vk::ImageLayout, vk::ImageLayout),
    (src, dst): (vk::AccessFlags, vk::AccessFlags),
    (from, to): (u32, u32),
) -> vk::ImageMemoryBarrier<'a> {
    vk::ImageMemoryBarrier::default()
        .image(image)
        .subresource_range(COLOR_RANGE)
        .old_layout(old)
        .new_layout(new)
        .src_access_mask(src)
        .dst_access_mask(dst)
        .src_queue_family_index(from)
        .dst_queue_family_index(to)
}

/// The barrier before the first use of an image nobody has used yet: UNDEFINED (its contents
/// may go), no ownership to take over.
pub fn first_use<'a>(
    image: vk::Image,
    layout: vk::ImageLayout,
    access: vk::AccessFlags,
) -> vk::ImageMemoryBarrier<'a> {
    let ignored = vk::QUEUE_FAMILY_IGNORED;
    image_barrier(
        image,
        (vk::ImageLayout::UNDEFINED, layout),
        (vk::AccessFlags::NONE, access),
        (ignored, ignored),
    )
}
// ANCHOR_END: image_barrier

/// The whole colour image, one mip level, one layer.
pub const COLOR_RANGE: vk::ImageSubresourceRange = vk::ImageSubresourceRange {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    base_mip_level: 0,
    level_count: 1,
    base_array_layer: 0,
    layer_count: 1,
};

/// The colour image's one mip level and one layer, as a copy to or from it names them.
pub const COLOR_LAYERS: vk::ImageSubresourceLayers = vk::ImageSubresourceLayers {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    mip_level: 0,
    base_array_layer: 0,
    layer_count: 1,
};

/// A plain (not shared) buffer in host-visible, host-coherent memory, mapped for its lifetime:
/// staging data in, reading results out. Destroyed when dropped (the buffer, then its memory,
/// which unmaps it); the GPU must be done with it.
pub struct HostBuffer {
    pub buffer: Owned<vk::Buffer>,
    pub memory: Owned<vk::DeviceMemory>,
    pub mapped: *mut u8,
    pub size: u64,
}

impl HostBuffer {
    pub fn new(vk: &VulkanContext, size: u64, usage: vk::BufferUsageFlags) -> Result<Self> {
        let device = &vk.device;
        let info = vk::BufferCreateInfo::default().size(size).usage(usage);
        let buffer =
            create(device, "vkCreateBuffer (host-visible)", || unsafe { device.create_buffer(&info, None) })?;
        let requirements = unsafe { device.get_buffer_memory_requirements(*buffer) };
        let flags = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        let memory_type = vk.find_memory_type(requirements.memory_type_bits, flags)?;
        let allocate = vk::MemoryAllocateInfo::default()
            .allocation_size(requirements.size)
            .memory_type_index(memory_type);
        let memory = create(device, "vkAllocateMemory (host-visible)", || unsafe {
            device.allocate_memory(&allocate, None)
        })?
        .counted("vk_memory_host", requirements.size);
        fail::call("vkBindBufferMemory (host-visible)", || unsafe {
            device.bind_buffer_memory(*buffer, *memory, 0)
        })?;
        let mapped = fail::call("vkMapMemory (host-visible)", || unsafe {
            device.map_memory(*memory, 0, size, vk::MemoryMapFlags::empty())
        })?
        .cast();
        Ok(HostBuffer { buffer, memory, mapped, size })
    }

    /// The mapped bytes. The GPU must not be writing them (wait for the fence first).
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: `mapped` is `size` bytes of coherent memory, mapped until dropped.
        unsafe { std::slice::from_raw_parts(self.mapped, self.size as usize) }
    }

    /// The mapped bytes as RGBA32F pixels.
    pub fn rgba32f(&self) -> Vec<[f32; 4]> {
        bytemuck::cast_slice(self.bytes()).to_vec()
    }

    /// The mapped bytes, to fill. The GPU must not be reading them.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as above, and `&mut self` makes this the only view.
        unsafe { std::slice::from_raw_parts_mut(self.mapped, self.size as usize) }
    }
}

/// Records a copy of a whole single-layer colour `image` (in `layout`) into `buffer`, tightly packed.
pub fn copy_image_to_buffer(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    image: vk::Image,
    layout: vk::ImageLayout,
    extent: vk::Extent2D,
    buffer: vk::Buffer,
) {
    let region = vk::BufferImageCopy::default().image_subresource(COLOR_LAYERS).image_extent(vk::Extent3D {
        width: extent.width,
        height: extent.height,
        depth: 1,
    });
    unsafe { vk.device.cmd_copy_image_to_buffer(cb, image, layout, buffer, &[region]) };
}

/// Makes transfer writes visible to the CPU, which reads them once the fence has signalled.
pub fn transfers_to_host(vk: &VulkanContext, cb: vk::CommandBuffer) {
    let barrier = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(vk::AccessFlags::HOST_READ);
    let (from, to) = (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::HOST);
    unsafe {
        vk.device.cmd_pipeline_barrier(cb, from, to, vk::DependencyFlags::empty(), &[barrier], &[], &[])
    };
}
