//! The scene layer: meshes, instances and the camera (plain CPU data), and the scene GL
//! rasterises into G-buffers Vulkan can read (chapter 05).

mod args;
pub mod builtin;
mod camera;
pub mod gbuffer;
mod model;
mod obj;

pub use args::*;
pub use builtin::{default_scene, ground_plane, tetrahedron};
pub use camera::*;
pub use model::*;
pub use obj::*;
