//! The clocks: GPU time on both APIs. Vulkan's timestamp queries, GL's pass timers and the
//! per-pass medians a report shows, and the timeline that puts both APIs' passes on one clock.

pub mod timeline;
pub mod timestamps;
pub mod timing;
