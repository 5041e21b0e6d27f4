//! Chapter 15, step 9: GL draws, wgpu reads. A compute pass, in plain wgpu and WGSL, reads the
//! picture GL drew into a shared image and writes its outline into another, which GL shows.

use crate::draw::{Readback, copy_out};
use crate::shared::{Kind, SharedImage};
use anyhow::Result;
use ash::vk;
use common::instruments::fail;

const SHADER: &str = include_str!("../../shaders/wgsl/outline.wgsl");
/// The shader's edge: a colour difference, summed over red, green and blue in 0-255 steps.
pub const EDGE: u32 = 96;
/// Its workgroups are 8x8 pixels.
const GROUP: u32 = 8;

/// The image GL draws into and wgpu samples, and the one wgpu's compute pass writes.
pub const GL_PICTURE: Kind = Kind {
    format: wgpu::TextureFormat::Rgba8Unorm,
    vk_format: vk::Format::R8G8B8A8_UNORM,
    gl_format: glow::RGBA8,
    usage: wgpu::TextureUsages::TEXTURE_BINDING,
};
pub const OUTLINE: Kind = Kind { usage: wgpu::TextureUsages::STORAGE_BINDING, ..GL_PICTURE };

// ANCHOR: pipeline
pub fn pipeline(device: &wgpu::Device) -> Result<wgpu::ComputePipeline> {
    fail::step("wgpu: create_shader_module (WGSL) + create_compute_pipeline")?;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("outline.wgsl"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    Ok(device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("outline"),
        layout: None, // wgpu derives the bind group's layout from the shader
        module: &module,
        entry_point: None,
        // The shader's `override` constants, from here: one value on both sides.
        compilation_options: wgpu::PipelineCompilationOptions {
            constants: &[("EDGE", EDGE as f64), ("GROUP", GROUP as f64)],
            ..Default::default()
        },
        cache: None,
    }))
}
// ANCHOR_END: pipeline

// ANCHOR: bind
/// What the compute pass reads and writes: `picture` (GL's) and `outlined`. Made once for each
/// pair of images, at the start and after a resize, not every frame.
pub fn bind(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    [picture, outlined]: [&SharedImage; 2],
) -> wgpu::BindGroup {
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("outline"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&picture.view) },
            wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&outlined.view) },
        ],
    })
}
// ANCHOR_END: bind

// ANCHOR: outline
/// The compute pass over the images `bind_group` holds, with their readbacks when asked for.
pub fn record(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
    [picture, outlined]: [&SharedImage; 2],
    read_back: bool,
) -> (wgpu::CommandEncoder, Vec<Readback>) {
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        let size = picture.wgpu.size();
        pass.dispatch_workgroups(size.width.div_ceil(GROUP), size.height.div_ceil(GROUP), 1);
    }
    let readbacks = match read_back {
        true => vec![copy_out(device, &mut encoder, picture), copy_out(device, &mut encoder, outlined)],
        false => vec![],
    };
    (encoder, readbacks)
}
// ANCHOR_END: outline
