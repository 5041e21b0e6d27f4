//! The scene layer: meshes, instances and the camera (plain CPU data), and the scene GL
//! rasterises into G-buffers Vulkan can read (chapter 05).

pub mod builtin;
pub mod gbuffer;
mod model;

pub use model::*;
