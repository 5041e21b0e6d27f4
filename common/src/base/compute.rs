//! A compute pipeline over storage images, with push constants: the kind chapter 04 builds step
//! by step, for the compute shaders later chapters dispatch (chapter 12's Vulkan composite).

use super::fail;
use super::vulkan::VulkanContext;
use anyhow::{Context as _, Result};
use ash::vk;

/// A shader module, destroyed when dropped: once the pipeline made from it exists (which keeps
/// what it needs), or on the way out of a failed one.
pub struct ShaderModule {
    pub module: vk::ShaderModule,
    device: ash::Device,
}

/// SPIR-V bytes as a shader module; `stage` names it in errors. `read_spv` copies the bytes into
/// `u32` words: `include_bytes!` promises no 4-byte alignment.
pub fn shader_module(vk: &VulkanContext, spirv: &[u8], stage: &str) -> Result<ShaderModule> {
    let words = ash::util::read_spv(&mut std::io::Cursor::new(spirv)).context("reading SPIR-V")?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    let what = format!("vkCreateShaderModule for the {stage} shader");
    let module = fail::call(&what, || unsafe { vk.device.create_shader_module(&info, None) })?;
    Ok(ShaderModule { module, device: vk.device.clone() })
}

impl Drop for ShaderModule {
    fn drop(&mut self) {
        unsafe { self.device.destroy_shader_module(self.module, None) };
    }
}

/// One compute shader, its storage images (bindings 0, 1, ... of set 0) and its push constants,
/// with the one descriptor set that points at the images.
pub struct ComputePipeline {
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    set_layout: vk::DescriptorSetLayout,
    pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
    images: u32,
    device: ash::Device,
}

impl ComputePipeline {
    /// For the shader `spirv`, which reads or writes `images` storage images and `push_bytes`
    /// of push constants.
    pub fn new(vk: &VulkanContext, spirv: &[u8], images: u32, push_bytes: u32) -> Result<Self> {
        let device = &vk.device;
        let compute = vk::ShaderStageFlags::COMPUTE;
        // The guard holds each object as it is made: an early return destroys those that exist.
        let mut this = ComputePipeline {
            pipeline: vk::Pipeline::null(),
            layout: vk::PipelineLayout::null(),
            set_layout: vk::DescriptorSetLayout::null(),
            pool: vk::DescriptorPool::null(),
            set: vk::DescriptorSet::null(),
            images,
            device: device.clone(),
        };
        let bindings: Vec<_> = (0..images)
            .map(|binding| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(binding)
                    .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
                    .descriptor_count(1)
                    .stage_flags(compute)
            })
            .collect();
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        this.set_layout = fail::call("vkCreateDescriptorSetLayout for a compute pipeline", || unsafe {
            device.create_descriptor_set_layout(&info, None)
        })?;
        let push = [vk::PushConstantRange::default().stage_flags(compute).size(push_bytes)];
        let set_layouts = [this.set_layout];
        let info =
            vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts).push_constant_ranges(&push);
        this.layout = fail::call("vkCreatePipelineLayout for a compute pipeline", || unsafe {
            device.create_pipeline_layout(&info, None)
        })?;
        let module = shader_module(vk, spirv, "compute")?;
        let stage =
            vk::PipelineShaderStageCreateInfo::default().stage(compute).module(module.module).name(c"main");
        let info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(this.layout);
        this.pipeline = fail::call("vkCreateComputePipelines", || unsafe {
            device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None).map_err(|(_, e)| e)
        })?[0];
        drop(module); // the pipeline keeps what it needs of it
        super::resources::created("vk_pipeline: compute", 0);
        let sizes =
            [vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_IMAGE, descriptor_count: images }];
        let info = vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&sizes);
        this.pool = fail::call("vkCreateDescriptorPool for a compute pipeline", || unsafe {
            device.create_descriptor_pool(&info, None)
        })?;
        let info =
            vk::DescriptorSetAllocateInfo::default().descriptor_pool(this.pool).set_layouts(&set_layouts);
        this.set = fail::call("vkAllocateDescriptorSets for a compute pipeline", || unsafe {
            device.allocate_descriptor_sets(&info)
        })?[0];
        Ok(this)
    }

    /// Points the bindings at `views`, in order, each in GENERAL (the layout storage images are
    /// read and written in). Not while a submission that uses the set is in flight.
    pub fn write_images(&self, vk: &VulkanContext, views: &[vk::ImageView]) {
        assert_eq!(views.len() as u32, self.images, "one view per storage image binding");
        let infos: Vec<_> = views
            .iter()
            .map(|&view| {
                [vk::DescriptorImageInfo::default().image_view(view).image_layout(vk::ImageLayout::GENERAL)]
            })
            .collect();
        let writes: Vec<_> = infos
            .iter()
            .enumerate()
            .map(|(binding, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(self.set)
                    .dst_binding(binding as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
                    .image_info(info)
            })
            .collect();
        unsafe { vk.device.update_descriptor_sets(&writes, &[]) };
    }

    /// Records the pipeline, its images and `push`, and one 16x16 group per 16x16 pixels of
    /// `extent` (the shader skips the overhang).
    pub fn dispatch(&self, vk: &VulkanContext, cb: vk::CommandBuffer, push: &[u8], extent: vk::Extent2D) {
        let compute = vk::PipelineBindPoint::COMPUTE;
        unsafe {
            vk.device.cmd_bind_pipeline(cb, compute, self.pipeline);
            vk.device.cmd_bind_descriptor_sets(cb, compute, self.layout, 0, &[self.set], &[]);
            vk.device.cmd_push_constants(cb, self.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            vk.device.cmd_dispatch(cb, extent.width.div_ceil(16), extent.height.div_ceil(16), 1);
        }
    }
}

impl Drop for ComputePipeline {
    /// The pool (and its set), the pipeline, its layouts. The GPU must be done with them.
    fn drop(&mut self) {
        unsafe {
            self.device.destroy_descriptor_pool(self.pool, None);
            self.device.destroy_pipeline(self.pipeline, None);
            self.device.destroy_pipeline_layout(self.layout, None);
            self.device.destroy_descriptor_set_layout(self.set_layout, None);
        }
        if self.pipeline != vk::Pipeline::null() {
            super::resources::destroyed("vk_pipeline: compute");
        }
    }
}
