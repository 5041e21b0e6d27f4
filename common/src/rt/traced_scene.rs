//! Chapters 05 and 06 in one call: the scene's buffers shared with GL and readable by
//! acceleration-structure builds, and the structures built from them. Here, above both the
//! scene layer (GL's side of the buffers) and the Vulkan-only structures.

use super::accel::{
    BlasLayout, BuildOptions, GpuAllocator, SceneAccel, TlasFlags, allocator, build_with, check_limits,
};
use crate::base::commands::Commands;
use crate::base::gl::GlContext;
use crate::base::vulkan::VulkanContext;
use crate::scene::Scene;
use crate::scene::gbuffer::SceneBuffers;
use anyhow::Result;
use ash::vk;

/// Chapters 05 and 06 in one call, for the chapters after them: the scene's buffers shared with
/// GL and readable by acceleration-structure builds, the structures built from them, and the
/// allocator their memory came from. Dropped, the structures go first, then the shared buffers
/// (each GL side first). The builds are done (waited for): the chapter's own `Commands`, made
/// after this, submits its frames.
pub struct RayTracedScene {
    pub structures: SceneAccel,
    pub allocator: GpuAllocator,
    pub buffers: SceneBuffers,
}

impl RayTracedScene {
    pub fn new(vk: &VulkanContext, gl: &GlContext, scene: &Scene) -> Result<Self> {
        Self::with_tlas(vk, gl, scene, TlasFlags::STATIC)
    }

    /// [`RayTracedScene::new`], with the TLAS built with `tlas_flags`.
    pub fn with_tlas(
        vk: &VulkanContext,
        gl: &GlContext,
        scene: &Scene,
        tlas_flags: TlasFlags,
    ) -> Result<Self> {
        Self::with_layout(vk, gl, scene, tlas_flags, BlasLayout::PerMesh)
    }

    /// [`RayTracedScene::with_tlas`], with the BLASes laid out as `layout` says.
    pub fn with_layout(
        vk: &VulkanContext,
        gl: &GlContext,
        scene: &Scene,
        tlas_flags: TlasFlags,
        layout: BlasLayout,
    ) -> Result<Self> {
        check_limits(vk, scene)?;
        let allocator = allocator(vk)?;
        let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        let buffers = SceneBuffers::share(vk, gl, scene, usage)?;
        // For the builds only (each waited for): dropped at the end of this call.
        let commands = Commands::new(vk)?;
        let structures =
            build_with(vk, &allocator, &commands, scene, &buffers, BuildOptions { tlas_flags, layout })?;
        Ok(RayTracedScene { structures, allocator, buffers })
    }
}
