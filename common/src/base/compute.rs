//! A compute pipeline over storage images, with push constants: the kind chapter 04 builds step
//! by step, for the compute shaders later chapters dispatch (chapter 12's Vulkan composite).

use super::owned::{Owned, create};
use super::pipeline::{ShaderInterface, shader_module};
use super::vulkan::VulkanContext;
use anyhow::Result;
use ash::vk;

/// One compute shader, its storage images (bindings 0, 1, ... of set 0) and its push constants,
/// with the one descriptor set that points at the images. Dropped, it destroys the pipeline,
/// then (a field) its interface. The GPU must be done with them.
pub struct ComputePipeline {
    pub pipeline: Owned<vk::Pipeline>,
    pub interface: ShaderInterface,
    images: u32,
}

impl ComputePipeline {
    /// For the shader `spirv`, which reads or writes `images` storage images and `push_bytes`
    /// of push constants.
    pub fn new(vk: &VulkanContext, spirv: &[u8], images: u32, push_bytes: u32) -> Result<Self> {
        let compute = vk::ShaderStageFlags::COMPUTE;
        let bindings: Vec<_> = (0..images)
            .map(|binding| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(binding)
                    .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
                    .descriptor_count(1)
                    .stage_flags(compute)
            })
            .collect();
        let push = vk::PushConstantRange::default().stage_flags(compute).size(push_bytes);
        let interface = ShaderInterface::new(vk, &bindings, push, "compute")?;
        let module = shader_module(vk, spirv, "compute")?;
        let stage = vk::PipelineShaderStageCreateInfo::default().stage(compute).module(*module).name(c"main");
        let info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(*interface.layout);
        // On failure `interface` and `module` are dropped, which destroys them.
        let pipeline = create(&vk.device, "vkCreateComputePipelines", || unsafe {
            let pipelines = vk.device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None);
            pipelines.map(|p| p[0]).map_err(|(_, e)| e)
        })?
        .counted("vk_pipeline: compute", 0);
        drop(module); // the pipeline keeps what it needs of it
        Ok(ComputePipeline { pipeline, interface, images })
    }

    /// Points the bindings at `views`, in order, each in GENERAL. Not while a submission that
    /// uses the set is in flight.
    pub fn write_images(&self, vk: &VulkanContext, views: &[vk::ImageView]) {
        assert_eq!(views.len() as u32, self.images, "one view per storage image binding");
        for (binding, &view) in views.iter().enumerate() {
            self.interface.write_storage_image(vk, binding as u32, view);
        }
    }

    /// Records the pipeline, its images and `push`, and one 16x16 group per 16x16 pixels of
    /// `extent` (the shader skips the overhang).
    pub fn dispatch(&self, vk: &VulkanContext, cb: vk::CommandBuffer, push: &[u8], extent: vk::Extent2D) {
        let compute = vk::PipelineBindPoint::COMPUTE;
        unsafe { vk.device.cmd_bind_pipeline(cb, compute, *self.pipeline) };
        self.interface.bind(vk, cb, compute, push);
        unsafe { vk.device.cmd_dispatch(cb, extent.width.div_ceil(16), extent.height.div_ceil(16), 1) };
    }
}
