//! The scene layer: meshes, instances and the camera (plain CPU data), and the scene GL
//! rasterises into G-buffers Vulkan can read (chapter 05).

pub mod builtin;
mod camera;
pub mod gbuffer;
mod model;
mod obj;

pub use camera::*;
pub use model::*;
pub use obj::*;
