//! GPU timestamps: the queries around a frame's Vulkan work, read back once its fence has
//! signalled, and the median and 95th percentile the reports give of them.

use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::Result;
use ash::vk;

/// Records `pass` between two timestamps when there are any: the queries reset, "start" once
/// earlier commands reach `stage` (record it after the barrier that waits for the other API,
/// so that waiting is not counted as work), "end" once `pass` has completed.
pub fn timed(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    timestamps: Option<&Timestamps>,
    stage: vk::PipelineStageFlags,
    pass: impl FnOnce(),
) {
    if let Some(t) = timestamps {
        t.reset(vk, cb);
        t.start(vk, cb, stage);
    }
    pass();
    if let Some(t) = timestamps {
        t.end(vk, cb);
    }
}

/// GPU timestamps around each frame's Vulkan work, read back once the frame's fence has signalled.
pub struct Timestamps {
    pub pool: Owned<vk::QueryPool>,
    count: u32,
    /// Nanoseconds per timestamp tick (`VkPhysicalDeviceLimits::timestampPeriod`).
    period_ns: f64,
    /// The bits of a timestamp that count (`timestampValidBits`); the rest are undefined, and a
    /// counter this narrow wraps.
    valid_mask: u64,
}

impl Timestamps {
    /// Two timestamps, start and end; `None` when the queue cannot write timestamps.
    pub fn new(vk: &VulkanContext) -> Result<Option<Self>> {
        Self::with_count(vk, 2)
    }

    /// `count` timestamps, written with [`Timestamps::write`]; `None` when the queue cannot
    /// write timestamps (`timestampValidBits` is 0).
    pub fn with_count(vk: &VulkanContext, count: u32) -> Result<Option<Self>> {
        let families = unsafe { vk.instance.get_physical_device_queue_family_properties(vk.physical_device) };
        let valid_bits = families[vk.queue_family_index as usize].timestamp_valid_bits;
        if valid_bits == 0 {
            return Ok(None);
        }
        let valid_mask = if valid_bits >= 64 { u64::MAX } else { (1u64 << valid_bits) - 1 };
        let limits = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }.limits;
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(count);
        let pool = create(&vk.device, "vkCreateQueryPool for timestamps", || unsafe {
            vk.device.create_query_pool(&info, None)
        })?;
        crate::instruments::resources::created("vk_query_pool: timestamps", 0);
        Ok(Some(Timestamps { pool, count, period_ns: limits.timestamp_period as f64, valid_mask }))
    }

    /// Resets the queries; record before anything else in the command buffer.
    pub fn reset(&self, vk: &VulkanContext, cb: vk::CommandBuffer) {
        unsafe { vk.device.cmd_reset_query_pool(cb, *self.pool, 0, self.count) };
    }

    /// Records the "start" timestamp, written once earlier commands reach `stage`. Record it
    /// after the barrier that waits for GL, so that waiting for GL is not counted as work.
    pub fn start(&self, vk: &VulkanContext, cb: vk::CommandBuffer, stage: vk::PipelineStageFlags) {
        unsafe { vk.device.cmd_write_timestamp(cb, stage, *self.pool, 0) };
    }

    /// Records the "end" timestamp, once all earlier commands have completed.
    pub fn end(&self, vk: &VulkanContext, cb: vk::CommandBuffer) {
        unsafe { vk.device.cmd_write_timestamp(cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, *self.pool, 1) };
    }

    /// Start and end of the last finished submission, in nanoseconds of the device's clock
    /// (only the valid bits, scaled by the timestamp period): for a timeline.
    pub fn read_ns(&self, vk: &VulkanContext) -> Result<[f64; 2]> {
        let mut ticks = [0u64; 2];
        fail::call("vkGetQueryPoolResults for a timeline's timestamps", || unsafe {
            vk.device.get_query_pool_results(*self.pool, 0, &mut ticks, vk::QueryResultFlags::TYPE_64)
        })?;
        Ok(ticks.map(|t| (t & self.valid_mask) as f64 * self.period_ns))
    }

    /// Milliseconds between start and end of the last finished submission.
    pub fn read_ms(&self, vk: &VulkanContext) -> Result<f64> {
        let mut ticks = [0u64; 2];
        fail::call("vkGetQueryPoolResults for a pass's timestamps", || unsafe {
            vk.device.get_query_pool_results(*self.pool, 0, &mut ticks, vk::QueryResultFlags::TYPE_64)
        })?;
        Ok(self.ms(ticks[0], ticks[1]))
    }

    /// Records timestamp `index`, written once earlier commands reach `stage`.
    pub fn write(
        &self,
        vk: &VulkanContext,
        cb: vk::CommandBuffer,
        stage: vk::PipelineStageFlags,
        index: u32,
    ) {
        unsafe { vk.device.cmd_write_timestamp(cb, stage, *self.pool, index) };
    }

    /// Milliseconds between timestamps `from` and `to` of the last finished submission.
    pub fn between_ms(&self, vk: &VulkanContext, from: u32, to: u32) -> Result<f64> {
        let mut ticks = [0u64; 1];
        let mut read = |i| {
            fail::call("vkGetQueryPoolResults for one timestamp", || unsafe {
                vk.device.get_query_pool_results(*self.pool, i, &mut ticks, vk::QueryResultFlags::TYPE_64)
            })
            .map(|()| ticks[0])
        };
        let (start, end) = (read(from)?, read(to)?);
        Ok(self.ms(start, end))
    }

    /// Milliseconds from tick `start` to tick `end`, counting only the valid bits (so a counter
    /// that wrapped between them still gives the right difference).
    fn ms(&self, start: u64, end: u64) -> f64 {
        ticks_to_ms(start, end, self.valid_mask, self.period_ns)
    }
}

/// Milliseconds from tick `start` to tick `end` of a counter with `valid_mask`'s bits, each tick
/// `period_ns` long.
fn ticks_to_ms(start: u64, end: u64, valid_mask: u64, period_ns: f64) -> f64 {
    let ticks = (end & valid_mask).wrapping_sub(start & valid_mask) & valid_mask;
    ticks as f64 * period_ns / 1e6
}

/// Median and 95th percentile of a series of timings, for the report.
pub fn median_p95(samples: &[f64]) -> (f64, f64) {
    if samples.is_empty() {
        return (0.0, 0.0);
    }
    let mut sorted = samples.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only `timestampValidBits` count: the bits above are undefined, and a narrow counter wraps.
    #[test]
    fn timestamps_count_only_their_valid_bits() {
        let ms = |start, end| ticks_to_ms(start, end, (1 << 36) - 1, 1.0);
        assert_eq!(ms(1_000_000, 3_000_000), 2.0);
        // Garbage above bit 36 is ignored.
        assert_eq!(ms(0xABC0_0000_0000_0000 | 1_000_000, 0x1230_0000_0000_0000 | 3_000_000), 2.0);
        // The counter wrapped from near 2^36 past 0.
        assert_eq!(ms((1 << 36) - 1_000_000, 1_000_000), 2.0);
    }
}
