//! Chapter 16's rays through the cut-outs: chapter 07's tracer with one hit group, an any-hit
//! shader that reads the alpha of the same shared images GL samples, and only the instances
//! whose material has a cut-out marked as not opaque.

use crate::scene::{CUTOFF, TexturedScene};
use crate::textures::Texture;
use anyhow::Result;
use ash::vk;
use common::VulkanContext;
use common::base::gl::GlContext;
use common::base::owned::{Owned, create};
use common::interop::BufferPair;
use common::interop::handoff::Handoff;
use common::rt::RayTracedScene;
use common::rt::accel::{BufferDesc, DeviceBuffer};
use common::rt::ao::{AO_SHADERS, AoRays, AoTracer, sampled_layouts};
use common::rt::raytrace::RayPipeline;
use common::scene::Scene;
use common::scene::gbuffer::GBuffers;
use gpu_allocator::MemoryLocation;

const ANY_HIT: &[u8] = include_bytes!("../../shaders/cut_out.rahit.spv");

// ANCHOR: cut_out
/// `CutOut` of `shaders/cut_out.rahit`, byte for byte (std430: 24 bytes): where the any-hit
/// shader finds an instance's triangles, texture coordinates and alpha.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CutOut {
    /// Device addresses of the mesh's index buffer and of its texture coordinates.
    pub indices: [u32; 2],
    pub uvs: [u32; 2],
    /// Which texture of the descriptor array holds the alpha.
    pub texture: u32,
    pub cutoff: f32,
}
// ANCHOR_END: cut_out

// ANCHOR: mark
/// Marks every instance of a mesh with a cut-out as not opaque (`FORCE_NO_OPAQUE`, in the
/// instance's flags byte), before the scene is shared: only their hits call the any-hit shader.
/// Every other instance keeps its geometry's OPAQUE flag, and pays nothing for the cut-outs.
pub fn mark_cut_outs(textured: &mut TexturedScene) {
    let force_no_opaque = vk::GeometryInstanceFlagsKHR::FORCE_NO_OPAQUE.as_raw() << 24;
    let Scene { instances, mesh_instances, .. } = &mut textured.scene;
    for (range, surface) in mesh_instances.iter().zip(&textured.surfaces) {
        if surface.is_some_and(|s| s.cut_out) {
            for instance in &mut instances[range.start as usize..range.end as usize] {
                instance.sbt_offset_and_flags |= force_no_opaque;
            }
        }
    }
}
// ANCHOR_END: mark

/// What the any-hit shader reads besides the images: the table of cut-outs and the sampler.
/// Dropped after the tracer, whose descriptors name both.
pub struct CutOutObjects {
    _table: DeviceBuffer,
    _sampler: Owned<vk::Sampler>,
}

// ANCHOR: pipeline
/// Chapter 07's tracer on a pipeline with the any-hit shader, and what that shader reads.
pub fn tracer(
    vk: &VulkanContext,
    (gl, handoff): (&GlContext, &Handoff),
    shared: &RayTracedScene,
    (scene, textures, uvs): (&TexturedScene, &[Texture], &[Option<BufferPair>]),
    gbuffers: &GBuffers,
) -> Result<(AoTracer, CutOutObjects)> {
    check_descriptor_limits(vk, textures.len() as u32)?;
    // Chapter 07's bindings 0-3, then what only the any-hit shader reads: the table of
    // cut-outs (4), and every texture (5), an array the shader indexes per hit.
    let any_hit = vk::ShaderStageFlags::ANY_HIT_KHR;
    let mut bindings = AoTracer::bindings();
    bindings.push(binding(4, vk::DescriptorType::STORAGE_BUFFER, 1, any_hit));
    bindings.push(binding(5, vk::DescriptorType::COMBINED_IMAGE_SAMPLER, textures.len() as u32, any_hit));
    let push = size_of::<AoRays>() as u32;
    let pipeline = RayPipeline::with_any_hit(vk, &shared.allocator, AO_SHADERS, ANY_HIT, &bindings, push)?;
    pipeline.write_tlas(vk, 0, *shared.structures.tlas.handle);
    // ANCHOR_END: pipeline
    // ANCHOR: table
    // One entry per instance, in the TLAS's order (gl_InstanceID); an opaque instance's
    // entry is never read.
    let address = |pair: &BufferPair| bytemuck::cast::<u64, [u32; 2]>(pair.vk.device_address(vk));
    let mut table = Vec::new();
    for (m, range) in scene.scene.mesh_instances.iter().enumerate() {
        let entry = match (scene.surfaces[m], &uvs[m]) {
            (Some(s), Some(uv)) if s.cut_out => CutOut {
                indices: address(&shared.buffers.meshes[m][1]),
                uvs: address(uv),
                texture: s.picture as u32,
                cutoff: CUTOFF,
            },
            _ => CutOut::default(),
        };
        table.extend(std::iter::repeat_n(entry, range.len()));
    }
    let bytes: &[u8] = bytemuck::cast_slice(&table);
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let desc = BufferDesc {
        name: "cut-out table",
        size: bytes.len() as u64,
        usage,
        location: MemoryLocation::CpuToGpu,
    };
    let mut table = DeviceBuffer::new(vk, &shared.allocator, desc)?;
    let mapped = table
        .allocation
        .mapped_slice_mut()
        .ok_or_else(|| anyhow::anyhow!("the cut-out table is not mapped"))?;
    mapped[..bytes.len()].copy_from_slice(bytes);
    // ANCHOR_END: table
    // ANCHOR: sampler
    // Level 0 only (the shader asks for it), repeated past the edges as GL's sampling is.
    let info = vk::SamplerCreateInfo::default()
        .mag_filter(vk::Filter::LINEAR)
        .min_filter(vk::Filter::LINEAR)
        .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
        .address_mode_u(vk::SamplerAddressMode::REPEAT)
        .address_mode_v(vk::SamplerAddressMode::REPEAT)
        .max_lod(vk::LOD_CLAMP_NONE);
    let sampler = create(&vk.device, "vkCreateSampler (the cut-outs)", || unsafe {
        vk.device.create_sampler(&info, None)
    })?;
    let set = pipeline.interface.set;
    let buffers = [vk::DescriptorBufferInfo::default().buffer(*table.buffer).range(vk::WHOLE_SIZE)];
    // The layout the images are in while Vulkan has them (a frame's hand-over leaves them there).
    let layout = sampled_layouts(handoff).to_vulkan;
    let images: Vec<_> = textures
        .iter()
        .map(|t| {
            vk::DescriptorImageInfo::default().sampler(*sampler).image_view(*t.view).image_layout(layout)
        })
        .collect();
    let writes = [
        vk::WriteDescriptorSet::default()
            .dst_set(set)
            .dst_binding(4)
            .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
            .buffer_info(&buffers),
        vk::WriteDescriptorSet::default()
            .dst_set(set)
            .dst_binding(5)
            .descriptor_type(vk::DescriptorType::COMBINED_IMAGE_SAMPLER)
            .image_info(&images),
    ];
    unsafe { vk.device.update_descriptor_sets(&writes, &[]) };
    // ANCHOR_END: sampler
    let mut tracer = AoTracer::with_pipeline(vk, gl, pipeline, gbuffers)?;
    // Every frame's hand-over now carries the textures too: the rays read them.
    tracer.sampled = textures.iter().map(Texture::sampled).collect();
    Ok((tracer, CutOutObjects { _table: table, _sampler: sampler }))
}

fn binding(
    binding: u32,
    ty: vk::DescriptorType,
    count: u32,
    stages: vk::ShaderStageFlags,
) -> vk::DescriptorSetLayoutBinding<'static> {
    vk::DescriptorSetLayoutBinding::default()
        .binding(binding)
        .descriptor_type(ty)
        .descriptor_count(count)
        .stage_flags(stages)
}

// ANCHOR: limits
/// Refuses a scene with more textures than one stage may sample, naming the limit: the array is
/// one binding, and a device caps how many sampled images a stage and a set may see.
fn check_descriptor_limits(vk: &VulkanContext, textures: u32) -> Result<()> {
    let limits = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }.limits;
    let most = limits.max_per_stage_descriptor_sampled_images.min(limits.max_descriptor_set_sampled_images);
    let most = most.min(limits.max_per_stage_descriptor_samplers).min(limits.max_descriptor_set_samplers);
    anyhow::ensure!(
        textures <= most,
        "the scene has {textures} textures, but a shader stage of {} samples at most {most} \
         (maxPerStageDescriptorSampledImages and the set's limit): fewer materials with pictures",
        vk.info.name
    );
    Ok(())
}
// ANCHOR_END: limits
