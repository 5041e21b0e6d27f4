//! Chapter 04's compute pass: the shared image it writes, the pipeline that writes it, and one
//! frame's recording, with the two ownership barriers around the dispatch.

use anyhow::Result;
use ash::vk;
use common::base::commands::first_use;
use common::base::owned::{Owned, create};
use common::clocks::timestamps::Timestamps;
use common::instruments::fail;
use common::interop::{SharedFormat, SharedImage, acquire_from_gl, release_to_gl};
use common::{GlContext, VulkanContext};
use glow::HasContext;

const COMPUTE_SPIRV: &[u8] = include_bytes!("../../shaders/compute_triangle.comp.spv");

// ANCHOR: interface
/// The compute shader's push constants (`Push` in compute_triangle.comp).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push {
    time: f32,
}
const _: () = assert!(size_of::<Push>() == 4);
/// `local_size_x` and `local_size_y` in compute_triangle.comp.
const WORKGROUP: u32 = 16;
// ANCHOR_END: interface

/// The compute pipeline, its layout, and the one descriptor set that points at the shared image.
/// Destroyed when dropped, fields in the order written (the set goes with its pool), so that an
/// early return from `run` leaks nothing. The GPU must be done with it.
pub struct ComputePipeline {
    /// Written by `share_image` whenever the image is made (anew).
    pub set: vk::DescriptorSet,
    _descriptor_pool: Owned<vk::DescriptorPool>,
    pipeline: Owned<vk::Pipeline>,
    layout: Owned<vk::PipelineLayout>,
    _set_layout: Owned<vk::DescriptorSetLayout>,
}

impl ComputePipeline {
    pub fn new(vk: &VulkanContext) -> Result<Self> {
        // ANCHOR: pipeline
        let device = &vk.device;
        let compute = vk::ShaderStageFlags::COMPUTE;
        // Each object is owned as it is made (`owned::create`): a failure half-way destroys
        // what was made.
        let bindings = [vk::DescriptorSetLayoutBinding::default()
            .binding(0) // `binding = 0` in the shader: the image it writes
            .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
            .descriptor_count(1)
            .stage_flags(compute)];
        let set_layout_info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        let set_layout = create(device, "vkCreateDescriptorSetLayout", || unsafe {
            device.create_descriptor_set_layout(&set_layout_info, None)
        })?;
        let push_range =
            [vk::PushConstantRange::default().stage_flags(compute).size(size_of::<Push>() as u32)];
        let set_layouts = [*set_layout];
        let layout_info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&set_layouts)
            .push_constant_ranges(&push_range);
        let layout = create(device, "vkCreatePipelineLayout", || unsafe {
            device.create_pipeline_layout(&layout_info, None)
        })?;
        // SPIR-V to a shader module (common::base::compute), destroyed when dropped.
        let module = common::base::pipeline::shader_module(vk, COMPUTE_SPIRV, "compute")?;
        let stage = vk::PipelineShaderStageCreateInfo::default().stage(compute).module(*module).name(c"main");
        let pipeline_info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(*layout);
        let pipeline = create(device, "vkCreateComputePipelines", || unsafe {
            device
                .create_compute_pipelines(vk::PipelineCache::null(), &[pipeline_info], None)
                .map(|pipelines| pipelines[0])
                .map_err(|(_, e)| e)
        })?
        .counted("vk_pipeline: compute", 0); // for the report's list of resources
        drop(module); // the pipeline keeps what it needs
        let pool_sizes =
            [vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_IMAGE, descriptor_count: 1 }];
        let pool_info = vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&pool_sizes);
        let descriptor_pool = create(device, "vkCreateDescriptorPool", || unsafe {
            device.create_descriptor_pool(&pool_info, None)
        })?;
        let allocate = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(*descriptor_pool)
            .set_layouts(&set_layouts);
        let set =
            fail::call("vkAllocateDescriptorSets", || unsafe { device.allocate_descriptor_sets(&allocate) })?
                [0];
        // ANCHOR_END: pipeline
        Ok(ComputePipeline {
            set,
            _descriptor_pool: descriptor_pool,
            pipeline,
            layout,
            _set_layout: set_layout,
        })
    }

    // ANCHOR: record_compute
    /// Takes the image from its `previous` holder (GL, or nobody when it is new), runs the compute
    /// shader over it at `time`, and gives it to GL.
    pub fn record(
        &self,
        vk: &VulkanContext,
        cb: vk::CommandBuffer,
        (image, previous): (&SharedImage, Previous),
        time: f32,
        timestamps: Option<&Timestamps>,
    ) {
        let (compute, none) = (vk::PipelineStageFlags::COMPUTE_SHADER, vk::DependencyFlags::empty());
        let (read_only, general) = (vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL, vk::ImageLayout::GENERAL);
        let device = &vk.device;
        let acquire = if previous == Previous::Nobody {
            // Nothing to take over: UNDEFINED says the old contents may go, and the shader writes
            // every pixel anyway. No ownership transfer: Vulkan's first use claims it.
            first_use(*image.image, general, vk::AccessFlags::SHADER_WRITE)
        } else {
            // Acquire from GL: ownership moves from outside Vulkan (QUEUE_FAMILY_EXTERNAL) to our
            // queue family, and the image from the layout GL released it in to GENERAL, the layout
            // imageStore needs. No source access: GL only sampled it, and its semaphore (or glFinish)
            // already ordered that before us. Destination: the shader's writes.
            acquire_from_gl(vk, image, read_only, general, vk::AccessFlags::SHADER_WRITE)
        };
        let extent = image.extent;
        let push = Push { time };
        unsafe {
            // Source stage COMPUTE_SHADER: the stage the submission waits for GL at, so this barrier
            // (and its layout change) happens after GL's release. Destination: the dispatch below.
            device.cmd_pipeline_barrier(cb, compute, compute, none, &[], &[], &[acquire]);
            if let Some(t) = timestamps {
                t.start(vk, cb, compute); // after the wait for GL: time the dispatch, not the wait
            }
            device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, *self.pipeline);
            device.cmd_bind_descriptor_sets(
                cb,
                vk::PipelineBindPoint::COMPUTE,
                *self.layout,
                0,
                &[self.set],
                &[],
            );
            let bytes = bytemuck::bytes_of(&push);
            device.cmd_push_constants(cb, *self.layout, vk::ShaderStageFlags::COMPUTE, 0, bytes);
            // One invocation per pixel, in whole 16x16 workgroups; the shader skips the overhang.
            device.cmd_dispatch(cb, extent.width.div_ceil(WORKGROUP), extent.height.div_ceil(WORKGROUP), 1);
            // Release to GL: make the shader's writes available (source COMPUTE_SHADER, SHADER_WRITE),
            // move to SHADER_READ_ONLY_OPTIMAL, the layout GL's acquire will name, and hand ownership
            // back outside Vulkan. Destination: nothing more in this submission (BOTTOM_OF_PIPE, no
            // access); the semaphore signal (or fence) that ends it carries the rest to GL.
            let release = release_to_gl(vk, image, general, read_only, vk::AccessFlags::SHADER_WRITE);
            let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
            device.cmd_pipeline_barrier(cb, compute, bottom, none, &[], &[], &[release]);
            if let Some(t) = timestamps {
                t.end(vk, cb);
            }
        }
    }
    // ANCHOR_END: record_compute
}

/// Who had the compute image before this frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Previous {
    /// Nobody: it was just made (the first frame, or a resize) and holds nothing yet.
    Nobody,
    /// GL, which drew from it last frame and hands it over now.
    Gl,
}

// ANCHOR: share_image
/// The compute shader's output: a storage image that GL samples as a texture. Writes it into
/// the descriptor set, so a resize is this call again.
pub fn share_image(
    vk: &VulkanContext,
    gl: &GlContext,
    set: vk::DescriptorSet,
    extent: vk::Extent2D,
) -> Result<SharedImage> {
    // STORAGE: the compute shader's imageStore. SAMPLED: GL's texture().
    let usage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
    let image = SharedImage::new(vk, gl, SharedFormat::RGBA8, usage, extent)?;
    let texture = *image.texture.texture;
    for (parameter, value) in [
        (glow::TEXTURE_MIN_FILTER, glow::LINEAR), // one mip level: no mipmap filter
        (glow::TEXTURE_MAG_FILTER, glow::LINEAR),
        (glow::TEXTURE_WRAP_S, glow::CLAMP_TO_EDGE),
        (glow::TEXTURE_WRAP_T, glow::CLAMP_TO_EDGE),
    ] {
        unsafe { gl.gl.texture_parameter_i32(texture, parameter, value as i32) };
    }
    // GENERAL: the only layout in which a shader may write a storage image.
    let info =
        [vk::DescriptorImageInfo::default().image_view(*image.view).image_layout(vk::ImageLayout::GENERAL)];
    let write = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(0)
        .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
        .image_info(&info);
    unsafe { vk.device.update_descriptor_sets(&[write], &[]) };
    Ok(image)
}
// ANCHOR_END: share_image

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_matches_the_glsl_block() {
        use common::base::shader_block::{assert_matches_spirv, rust_block};
        assert_matches_spirv(COMPUTE_SPIRV, "Push", rust_block!(Push { time }));
    }
}
