//! Chapters 05 and 06 in one call: the scene's buffers shared with GL and readable by
//! acceleration-structure builds, and the structures built from them. Here, above both the
//! scene layer (GL's side of the buffers) and the Vulkan-only structures.

use super::accel::{BlasLayout, BuildOptions, SceneAccel, TlasFlags, allocator, build_with, check_limits};
use crate::base::commands::Commands;
use crate::base::gl::GlContext;
use crate::base::vulkan::VulkanContext;
use crate::scene::Scene;
use crate::scene::gbuffer::SceneBuffers;
use anyhow::Result;
use ash::vk;
use gpu_allocator::vulkan::Allocator;

/// Chapters 05 and 06 in one call, for the chapters after them: the scene's buffers shared with
/// GL and readable by acceleration-structure builds, the structures built from them, and the
/// allocator and command buffer that took.
/// (Fields are dropped in this order on an early return: newest first, as in `destroy`.)
pub struct RayTracedScene {
    pub structures: SceneAccel,
    pub commands: Commands,
    pub allocator: Allocator,
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
        let mut allocator = allocator(vk)?;
        let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        let buffers = SceneBuffers::share(vk, gl, scene, usage)?;
        let commands = Commands::new(vk)?;
        let structures =
            build_with(vk, &mut allocator, &commands, scene, &buffers, BuildOptions { tlas_flags, layout })?;
        Ok(RayTracedScene { allocator, buffers, commands, structures })
    }

    /// Newest first: the structures, the command buffer (after its last submission), the
    /// allocator's memory, then the shared buffers, GL's side first.
    pub fn destroy(mut self, vk: &VulkanContext, gl: &GlContext) {
        self.structures.destroy(vk, &mut self.allocator);
        self.commands.destroy(vk);
        drop(self.allocator);
        self.buffers.destroy(vk, gl);
    }
}
