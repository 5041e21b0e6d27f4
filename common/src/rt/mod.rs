//! The ray-tracing layer: acceleration structures and ray-tracing pipelines (Vulkan only,
//! chapters 06 and 09-10), the scene they trace shared with GL, and ambient occlusion traced
//! from GL's G-buffers (chapter 07).

pub mod accel;
pub mod ao;
pub mod raytrace;
mod traced_scene;

pub use traced_scene::RayTracedScene;
