//! Recording and submitting Vulkan work: one command buffer reused every frame, guarded by a
//! fence, plus one-shot submissions for set-up.

use crate::VulkanContext;
use anyhow::{Context as _, Result};
use ash::vk;

/// A command pool with one primary command buffer and the fence of its last submission.
pub struct Commands {
    pub pool: vk::CommandPool,
    pub buffer: vk::CommandBuffer,
    /// Signalled when the last submission of `buffer` has finished.
    pub fence: vk::Fence,
}

impl Commands {
    pub fn new(vk: &VulkanContext) -> Result<Self> {
        unsafe {
            let pool_info = vk::CommandPoolCreateInfo::default()
                .queue_family_index(vk.queue_family_index)
                .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
            let pool = vk.device.create_command_pool(&pool_info, None).context("vkCreateCommandPool")?;
            let allocate = vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1);
            let buffer = vk.device.allocate_command_buffers(&allocate).context("vkAllocateCommandBuffers")?[0];
            // Created signalled, so that the first `begin` need not wait for anything.
            let fence_info = vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED);
            let fence = vk.device.create_fence(&fence_info, None).context("vkCreateFence")?;
            Ok(Commands { pool, buffer, fence })
        }
    }

    /// Waits until the previous submission is done (the buffer and what it uses are free
    /// again), then starts recording.
    pub fn begin(&self, vk: &VulkanContext) -> Result<vk::CommandBuffer> {
        unsafe {
            vk.device.wait_for_fences(&[self.fence], true, u64::MAX).context("vkWaitForFences")?;
            vk.device.reset_fences(&[self.fence])?;
            vk.device.reset_command_buffer(self.buffer, vk::CommandBufferResetFlags::empty())?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            vk.device.begin_command_buffer(self.buffer, &begin)?;
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
            vk.device.end_command_buffer(self.buffer)?;
            vk.device.queue_submit(vk.queue, &[submit], self.fence).context("vkQueueSubmit")
        }
    }

    /// Records with `record`, submits, and waits for the GPU: for set-up work, not for frames.
    pub fn run_once(&self, vk: &VulkanContext, record: impl FnOnce(vk::CommandBuffer)) -> Result<()> {
        let cb = self.begin(vk)?;
        record(cb);
        self.submit(vk, None, None)?;
        unsafe { vk.device.wait_for_fences(&[self.fence], true, u64::MAX) }.context("vkWaitForFences")
    }

    /// Waits for the last submission, then destroys the fence and the pool (and its buffer).
    pub fn destroy(self, vk: &VulkanContext) {
        unsafe {
            let _ = vk.device.wait_for_fences(&[self.fence], true, u64::MAX);
            vk.device.destroy_fence(self.fence, None);
            vk.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// The whole colour image, one mip level, one layer.
pub const COLOR_RANGE: vk::ImageSubresourceRange = vk::ImageSubresourceRange {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    base_mip_level: 0,
    level_count: 1,
    base_array_layer: 0,
    layer_count: 1,
};
