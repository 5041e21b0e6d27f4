//! A ray tracing pipeline with a ray generation and a miss shader and no hit group at all (or,
//! from chapter 16, one hit group of an any-hit shader), its
//! shader binding table, and a storage image for results (taught in chapter 06; chapter 07
//! traces its ambient occlusion rays through the same kind of pipeline).

use crate::base::image::image_info;
use crate::base::owned::{Owned, create};
use crate::base::pipeline::{ShaderInterface, shader_module};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use crate::rt::accel::{BufferDesc, DeviceBuffer, GpuAllocator, Memory};
use anyhow::{Context as _, Result};
use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{AllocationCreateDesc, AllocationScheme};

/// Dropped, it destroys the pipeline, then its interface and the shader binding table (fields,
/// in order). The GPU must be done with it.
pub struct RayPipeline {
    pub loader: ash::khr::ray_tracing_pipeline::Device,
    pub pipeline: Owned<vk::Pipeline>,
    pub interface: ShaderInterface,
    /// The shader binding table's buffer (read through `regions`).
    _sbt: DeviceBuffer,
    /// Where the shader binding table's ray generation, miss, hit and callable records are.
    pub regions: [vk::StridedDeviceAddressRegionKHR; 4],
}

/// The descriptor set layout of a ray generation shader: binding `i` of `types[i]`, one
/// descriptor each, seen by the ray generation stage only (chapter 06 writes its two out).
pub fn raygen_bindings(types: &[vk::DescriptorType]) -> Vec<vk::DescriptorSetLayoutBinding<'static>> {
    let binding = |(i, ty): (usize, &vk::DescriptorType)| {
        vk::DescriptorSetLayoutBinding::default()
            .binding(i as u32)
            .descriptor_type(*ty)
            .descriptor_count(1)
            .stage_flags(vk::ShaderStageFlags::RAYGEN_KHR)
    };
    types.iter().enumerate().map(binding).collect()
}

/// The two shaders of a [`RayPipeline`], as SPIR-V.
pub struct RayShaders<'a> {
    pub raygen: &'a [u8],
    pub miss: &'a [u8],
}

impl RayPipeline {
    /// `bindings`: descriptor set 0; `push_bytes`: the push constants both shaders may read.
    pub fn new(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        shaders: RayShaders,
        bindings: &[vk::DescriptorSetLayoutBinding],
        push_bytes: u32,
    ) -> Result<Self> {
        Self::build(vk, allocator, shaders, None, bindings, push_bytes)
    }

    /// [`RayPipeline::new`] with one hit group of `any_hit` alone (chapter 16's cut-outs): it
    /// runs for every candidate hit on geometry that is not opaque, and may ignore the hit.
    /// The ray generation shader's specialization constant 0 (`RAY_OPACITY` in `ao.rgen`) is set
    /// to `gl_RayFlagsNoneEXT`, so that its rays stop forcing every hit opaque.
    pub fn with_any_hit(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        shaders: RayShaders,
        any_hit: &[u8],
        bindings: &[vk::DescriptorSetLayoutBinding],
        push_bytes: u32,
    ) -> Result<Self> {
        Self::build(vk, allocator, shaders, Some(any_hit), bindings, push_bytes)
    }

    fn build(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        shaders: RayShaders,
        any_hit: Option<&[u8]>,
        bindings: &[vk::DescriptorSetLayoutBinding],
        push_bytes: u32,
    ) -> Result<Self> {
        let loader = ash::khr::ray_tracing_pipeline::Device::new(&vk.instance, &vk.device);
        let stages = vk::ShaderStageFlags::RAYGEN_KHR | vk::ShaderStageFlags::MISS_KHR;
        let push = vk::PushConstantRange::default().stage_flags(stages).size(push_bytes);
        let interface = ShaderInterface::new(vk, bindings, push, "ray tracing")?;
        let layout = *interface.layout;

        // ANCHOR: pipeline
        let raygen = shader_module(vk, shaders.raygen, "ray generation")?;
        let miss = shader_module(vk, shaders.miss, "miss")?;
        let any_hit = any_hit.map(|code| shader_module(vk, code, "any-hit")).transpose()?;
        // With an any-hit shader, the ray generation shader's constant 0, the opacity its rays ask
        // for, is gl_RayFlagsNoneEXT (a uint of 4 bytes at 0).
        let ray_opacity = [0u32];
        let entries = [vk::SpecializationMapEntry { constant_id: 0, offset: 0, size: 4 }];
        let specialization =
            vk::SpecializationInfo::default().map_entries(&entries).data(bytemuck::bytes_of(&ray_opacity));
        let mut raygen_stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::RAYGEN_KHR)
            .module(*raygen)
            .name(c"main");
        if any_hit.is_some() {
            raygen_stage = raygen_stage.specialization_info(&specialization);
        }
        let mut stages = vec![
            raygen_stage,
            vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::MISS_KHR)
                .module(*miss)
                .name(c"main"),
        ];
        // Two "general" groups, one shader each. No hit group: with SkipClosestHitShader and
        // opaque geometry, a hit calls no shader at all, so there is nothing to put in one.
        let general = |shader| {
            vk::RayTracingShaderGroupCreateInfoKHR::default()
                .ty(vk::RayTracingShaderGroupTypeKHR::GENERAL)
                .general_shader(shader)
                .closest_hit_shader(vk::SHADER_UNUSED_KHR)
                .any_hit_shader(vk::SHADER_UNUSED_KHR)
                .intersection_shader(vk::SHADER_UNUSED_KHR)
        };
        let mut groups = vec![general(0), general(1)];
        if let Some(module) = &any_hit {
            stages.push(
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::ANY_HIT_KHR)
                    .module(**module)
                    .name(c"main"),
            );
            // A triangle hit group of the any-hit shader alone (stage 2): no closest-hit shader,
            // as before, and no intersection shader (the geometry is triangles).
            groups.push(
                vk::RayTracingShaderGroupCreateInfoKHR::default()
                    .ty(vk::RayTracingShaderGroupTypeKHR::TRIANGLES_HIT_GROUP)
                    .general_shader(vk::SHADER_UNUSED_KHR)
                    .closest_hit_shader(vk::SHADER_UNUSED_KHR)
                    .any_hit_shader(2)
                    .intersection_shader(vk::SHADER_UNUSED_KHR),
            );
        }
        let info = vk::RayTracingPipelineCreateInfoKHR::default()
            .stages(&stages)
            .groups(&groups)
            .max_pipeline_ray_recursion_depth(1) // rays start in raygen only
            .layout(layout);
        // Destroyed with `vkDestroyPipeline`, as every pipeline is: the device, not the loader.
        let pipeline = create(&vk.device, "vkCreateRayTracingPipelinesKHR", || unsafe {
            loader
                .create_ray_tracing_pipelines(
                    vk::DeferredOperationKHR::null(),
                    vk::PipelineCache::null(),
                    &[info],
                    None,
                )
                .map(|pipelines| pipelines[0])
                .map_err(|(_, e)| e)
        })?;
        drop((raygen, miss, any_hit)); // the pipeline keeps what it needs of them
        crate::instruments::resources::created("vk_pipeline: ray tracing", 0);
        // ANCHOR_END: pipeline
        let (sbt, regions) = shader_binding_table(vk, &loader, allocator, *pipeline, groups.len() as u32)?;
        Ok(RayPipeline { loader, pipeline, interface, _sbt: sbt, regions })
    }

    /// Points binding `binding` at the TLAS.
    pub fn write_tlas(&self, vk: &VulkanContext, binding: u32, tlas: vk::AccelerationStructureKHR) {
        let structures = [tlas];
        let mut tlas_info =
            vk::WriteDescriptorSetAccelerationStructureKHR::default().acceleration_structures(&structures);
        let mut write = vk::WriteDescriptorSet::default()
            .dst_set(self.interface.set)
            .dst_binding(binding)
            .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
            .push_next(&mut tlas_info);
        write.descriptor_count = 1; // the count lives in the chained struct's array
        unsafe { vk.device.update_descriptor_sets(&[write], &[]) };
    }

    /// Points binding `binding` at a storage image view, used in the GENERAL layout.
    pub fn write_storage_image(&self, vk: &VulkanContext, binding: u32, view: vk::ImageView) {
        self.interface.write_storage_image(vk, binding, view);
    }

    // ANCHOR: trace
    /// Records one ray generation invocation per pixel of `extent`.
    pub fn trace(&self, vk: &VulkanContext, cb: vk::CommandBuffer, push: &[u8], extent: vk::Extent2D) {
        let bind = vk::PipelineBindPoint::RAY_TRACING_KHR;
        let [raygen, miss, hit, callable] = &self.regions;
        unsafe { vk.device.cmd_bind_pipeline(cb, bind, *self.pipeline) };
        self.interface.bind(vk, cb, bind, push);
        unsafe {
            self.loader.cmd_trace_rays(cb, raygen, miss, hit, callable, extent.width, extent.height, 1)
        };
    }
    // ANCHOR_END: trace
}

// ANCHOR: sbt
/// The shader binding table: the pipeline's group handles copied into a buffer, each region
/// starting at the device's base alignment. Group 0 is ray generation, group 1 miss, group 2 (if
/// there are three) the hit group; the callable region stays empty (address 0, size 0), and so
/// does the hit region without a hit group.
fn shader_binding_table(
    vk: &VulkanContext,
    loader: &ash::khr::ray_tracing_pipeline::Device,
    allocator: &GpuAllocator,
    pipeline: vk::Pipeline,
    groups: u32,
) -> Result<(DeviceBuffer, [vk::StridedDeviceAddressRegionKHR; 4])> {
    let mut properties = vk::PhysicalDeviceRayTracingPipelinePropertiesKHR::default();
    let mut properties2 = vk::PhysicalDeviceProperties2::default().push_next(&mut properties);
    unsafe { vk.instance.get_physical_device_properties2(vk.physical_device, &mut properties2) };
    let handle_size = properties.shader_group_handle_size as u64;
    let record = handle_size.next_multiple_of(properties.shader_group_handle_alignment as u64);
    let region = record.next_multiple_of(properties.shader_group_base_alignment as u64);
    let handles = fail::call("vkGetRayTracingShaderGroupHandlesKHR", || unsafe {
        loader.get_ray_tracing_shader_group_handles(
            pipeline,
            0,
            groups,
            (groups as u64 * handle_size) as usize,
        )
    })?;
    let usage = vk::BufferUsageFlags::SHADER_BINDING_TABLE_KHR;
    // One region per group, plus room to align the start to the base alignment.
    let bytes = region * groups as u64 + properties.shader_group_base_alignment as u64;
    let mut buffer = DeviceBuffer::new(
        vk,
        allocator,
        BufferDesc { name: "shader binding table", size: bytes, usage, location: MemoryLocation::CpuToGpu },
    )?;
    let start =
        buffer.address.next_multiple_of(properties.shader_group_base_alignment as u64) - buffer.address;
    let mapped = buffer.allocation.mapped_slice_mut().context("the SBT's memory is not mapped")?;
    for g in 0..groups as u64 {
        let at = (start + g * region) as usize;
        let handle = &handles[(g * handle_size) as usize..((g + 1) * handle_size) as usize];
        mapped[at..at + handle.len()].copy_from_slice(handle);
    }
    let address = |g: u64| buffer.address + start + g * region;
    let regions = [
        // Ray generation: exactly one record, so size == stride.
        vk::StridedDeviceAddressRegionKHR { device_address: address(0), stride: record, size: record },
        vk::StridedDeviceAddressRegionKHR { device_address: address(1), stride: record, size: record },
        match groups {
            // One hit group: every instance's and geometry's offset is 0, so one record serves all.
            3 => {
                vk::StridedDeviceAddressRegionKHR { device_address: address(2), stride: record, size: record }
            }
            _ => vk::StridedDeviceAddressRegionKHR::default(), // no hit groups
        },
        vk::StridedDeviceAddressRegionKHR::default(), // no callable shaders
    ];
    Ok((buffer, regions))
}
// ANCHOR_END: sbt

/// An image only Vulkan uses (a ray tracer's output), in memory from gpu-allocator, with a view.
/// Dropped, it destroys the view and the image, then gives its memory back (fields, in order).
pub struct StorageImage {
    pub view: Owned<vk::ImageView>,
    pub image: Owned<vk::Image>,
    pub allocation: Memory,
    pub extent: vk::Extent2D,
}

impl StorageImage {
    pub fn new(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        extent: vk::Extent2D,
    ) -> Result<Self> {
        // Written by a ray generation shader (STORAGE), and only ever by Vulkan: no external
        // memory chained to the create-info, unlike an exported image's.
        let info = image_info(format, usage | vk::ImageUsageFlags::STORAGE, extent);
        let image =
            create(&vk.device, "vkCreateImage (storage)", || unsafe { vk.device.create_image(&info, None) })?;
        let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
        let description = AllocationCreateDesc {
            name: "storage image",
            requirements,
            location: MemoryLocation::GpuOnly,
            linear: false,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        };
        let allocation = allocator.allocate(&description)?;
        crate::instruments::resources::created("vk_image: storage", allocation.size());
        fail::call("vkBindImageMemory (storage)", || unsafe {
            vk.device.bind_image_memory(*image, allocation.memory(), allocation.offset())
        })?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(*image)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(format)
            .subresource_range(crate::base::commands::COLOR_RANGE);
        let view = create(&vk.device, "vkCreateImageView (storage)", || unsafe {
            vk.device.create_image_view(&view_info, None)
        })?;
        Ok(StorageImage { view, image, allocation, extent })
    }
}

// ANCHOR: primary_rays
/// The push constants of `shaders/primary.rgen`, laid out as GLSL lays out its push-constant
/// block (std430): a mat4, a vec4 and two floats, 88 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PrimaryRays {
    /// GL's clip space back to world space: the inverse of the camera's view-projection.
    pub inverse_view_projection: [f32; 16],
    /// The camera position (w unused).
    pub eye: [f32; 4],
    /// Ray extent: GL's near and far planes, so both renderers see the same slab of the scene.
    pub t_min: f32,
    pub t_max: f32,
}
// ANCHOR_END: primary_rays

impl PrimaryRays {
    pub fn new(camera: &crate::scene::Camera, aspect: f32) -> Self {
        PrimaryRays {
            inverse_view_projection: camera.view_projection(aspect).inverse().to_cols_array(),
            eye: camera.eye.extend(1.0).into(),
            t_min: camera.near,
            t_max: camera.far,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::shader_block::{assert_matches_spirv, rust_block};

    #[test]
    fn primary_rays_match_the_glsl_block() {
        let spirv = include_bytes!("../../../shaders/primary.rgen.spv");
        let rust = rust_block!(PrimaryRays { inverse_view_projection, eye, t_min, t_max });
        assert_matches_spirv(spirv, "PrimaryRays", rust);
    }
}
