//! What every pipeline in `common` is made of besides its shaders: shader modules, and the
//! interface between the shaders and what they read and write (descriptor set 0 and push
//! constants). The compute pipeline (`base::compute`) and the ray tracing pipeline
//! (`rt::raytrace`) are both built on it.

use super::owned::{Owned, create};
use super::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::{Context as _, Result};
use ash::vk;

/// A shader module, destroyed when dropped: once the pipeline made from it exists (which keeps
/// what it needs), or on the way out of a failed one.
pub type ShaderModule = Owned<vk::ShaderModule>;

/// SPIR-V bytes as a shader module; `stage` names it in errors. `read_spv` copies the bytes into
/// `u32` words: `include_bytes!` promises no 4-byte alignment.
pub fn shader_module(vk: &VulkanContext, spirv: &[u8], stage: &str) -> Result<ShaderModule> {
    let words = ash::util::read_spv(&mut std::io::Cursor::new(spirv)).context("reading SPIR-V")?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    let what = format!("vkCreateShaderModule for the {stage} shader");
    create(&vk.device, &what, || unsafe { vk.device.create_shader_module(&info, None) })
}

/// Asserts that a `#[repr(C)]` struct another side reads without SPIR-V to check it against (a
/// CUDA kernel's parameters, Vulkan's instance record) has the size and byte offsets that side
/// declares: `assert_layout!(Instance is 64 bytes: blas_address at 56)`. For a unit test; the
/// message names the member whose offset is wrong. A struct a Vulkan shader reads is checked
/// against the shader itself instead ([`super::shader_block`]).
#[macro_export]
#[doc(hidden)]
macro_rules! __assert_layout {
    ($ty:ident is $size:literal bytes: $($field:ident at $offset:literal),* $(,)?) => {
        assert_eq!(::core::mem::size_of::<$ty>(), $size, concat!("the size of ", stringify!($ty)));
        $(assert_eq!(
            ::core::mem::offset_of!($ty, $field),
            $offset,
            concat!("the offset of ", stringify!($ty), "::", stringify!($field))
        );)*
    };
}
#[doc(inline)]
pub use __assert_layout as assert_layout;

/// A pipeline's interface: the layout of descriptor set 0, the pipeline layout that adds the
/// push constants, and the one set, from a pool sized for exactly it. Dropped, it destroys the
/// pool (and with it the set) and both layouts: after the pipeline, and once the GPU is done.
pub struct ShaderInterface {
    /// Freed with its pool.
    pub set: vk::DescriptorSet,
    _pool: Owned<vk::DescriptorPool>,
    pub layout: Owned<vk::PipelineLayout>,
    _set_layout: Owned<vk::DescriptorSetLayout>,
    /// The stages that read the push constants: what `vkCmdPushConstants` must name.
    push_stages: vk::ShaderStageFlags,
}

impl ShaderInterface {
    /// Set 0 holds `bindings`; `push` says which stages read how many bytes of push constants.
    /// `pipeline` names the pipeline in errors ("compute", "ray tracing").
    pub fn new(
        vk: &VulkanContext,
        bindings: &[vk::DescriptorSetLayoutBinding],
        push: vk::PushConstantRange,
        pipeline: &str,
    ) -> Result<Self> {
        let device = &vk.device;
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(bindings);
        let set_layout = create(device, &format!("vkCreateDescriptorSetLayout ({pipeline})"), || unsafe {
            device.create_descriptor_set_layout(&info, None)
        })?;
        let set_layouts = [*set_layout];
        let pushes = [push];
        let info =
            vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts).push_constant_ranges(&pushes);
        let layout = create(device, &format!("vkCreatePipelineLayout ({pipeline})"), || unsafe {
            device.create_pipeline_layout(&info, None)
        })?;
        // One pool entry per binding: room for exactly one set.
        let sizes: Vec<_> = bindings
            .iter()
            .map(|b| vk::DescriptorPoolSize { ty: b.descriptor_type, descriptor_count: b.descriptor_count })
            .collect();
        let info = vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&sizes);
        let pool = create(device, &format!("vkCreateDescriptorPool ({pipeline})"), || unsafe {
            device.create_descriptor_pool(&info, None)
        })?;
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(*pool).set_layouts(&set_layouts);
        let set = fail::call(&format!("vkAllocateDescriptorSets ({pipeline})"), || unsafe {
            device.allocate_descriptor_sets(&info)
        })?[0];
        Ok(ShaderInterface {
            set,
            _pool: pool,
            layout,
            _set_layout: set_layout,
            push_stages: push.stage_flags,
        })
    }

    /// Points `binding` at a storage image view, read and written in GENERAL (the layout storage
    /// images are used in). Not while a submission that uses the set is in flight.
    pub fn write_storage_image(&self, vk: &VulkanContext, binding: u32, view: vk::ImageView) {
        let images =
            [vk::DescriptorImageInfo::default().image_view(view).image_layout(vk::ImageLayout::GENERAL)];
        let write = vk::WriteDescriptorSet::default()
            .dst_set(self.set)
            .dst_binding(binding)
            .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
            .image_info(&images);
        unsafe { vk.device.update_descriptor_sets(&[write], &[]) };
    }

    /// Records the set and the push constants `push` for the pipeline bound at `bind_point`.
    pub fn bind(
        &self,
        vk: &VulkanContext,
        cb: vk::CommandBuffer,
        bind_point: vk::PipelineBindPoint,
        push: &[u8],
    ) {
        unsafe {
            vk.device.cmd_bind_descriptor_sets(cb, bind_point, *self.layout, 0, &[self.set], &[]);
            vk.device.cmd_push_constants(cb, *self.layout, self.push_stages, 0, push);
        }
    }
}
