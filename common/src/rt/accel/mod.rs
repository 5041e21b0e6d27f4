//! Acceleration structures (taught in chapter 06): one BLAS per mesh, built straight from the
//! buffers GL draws from, compacted; one TLAS over the shared instance buffer.
//!
//! Nothing here is shared with GL, so it lives in ordinary memory from gpu-allocator.

mod build;
mod in_place;
mod memory;
mod structure;

pub use build::*;
pub use in_place::*;
pub use memory::*;
pub use structure::*;
