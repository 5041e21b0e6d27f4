//! Chapter 15, steps 5 and 7: wgpu's render pipeline, and the render pass that draws the triangle
//! and its depth into two shared images.

use crate::shared::{Kind, SharedImage};
use anyhow::{Context as _, Result};
use ash::vk;
use common::instruments::fail;

const SHADER: &str = include_str!("../../shaders/wgsl/triangle.wgsl");
/// What the picture is cleared to (chapter 02's background) and its depth image (the far plane).
pub const CLEAR: [f64; 4] = [0.1, 0.1, 0.12, 1.0];
pub const FAR: f64 = 1.0;
/// The two images wgpu draws into and GL reads: the picture, and its depths as a colour image.
pub const PICTURE: Kind = Kind {
    format: wgpu::TextureFormat::Rgba8Unorm,
    vk_format: vk::Format::R8G8B8A8_UNORM,
    gl_format: glow::RGBA8,
    usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
};
pub const DEPTH: Kind = Kind {
    format: wgpu::TextureFormat::R32Float,
    vk_format: vk::Format::R32_SFLOAT,
    gl_format: glow::R32F,
    usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
};

// ANCHOR: pipeline
pub fn pipeline(device: &wgpu::Device) -> Result<wgpu::RenderPipeline> {
    fail::step("wgpu: create_shader_module (WGSL) + create_render_pipeline")?;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("triangle.wgsl"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let targets = [Some(PICTURE.format.into()), Some(DEPTH.format.into())];
    Ok(device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("triangle"),
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: None,
            compilation_options: Default::default(),
            buffers: &[],
        },
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: None,
            compilation_options: Default::default(),
            targets: &targets,
        }),
        primitive: Default::default(),
        depth_stencil: None,
        multisample: Default::default(),
        multiview_mask: None,
        cache: None,
    }))
}
// ANCHOR_END: pipeline

/// A readback of one image: rows padded to wgpu's 256-byte copy alignment.
pub struct Readback {
    pub buffer: wgpu::Buffer,
    pub row_bytes: u32,
    pub padded: u32,
}

// ANCHOR: render
/// The render pass, in plain wgpu: the triangle into `picture` and its depth into `depth`, with
/// their readbacks when asked for. wgpu makes every barrier inside its own queue family.
pub fn render(
    device: &wgpu::Device,
    pipeline: &wgpu::RenderPipeline,
    [picture, depth]: [&SharedImage; 2],
    read_back: bool,
) -> (wgpu::CommandEncoder, Vec<Readback>) {
    let mut encoder = device.create_command_encoder(&Default::default());
    let clears = [
        wgpu::Color { r: CLEAR[0], g: CLEAR[1], b: CLEAR[2], a: CLEAR[3] },
        wgpu::Color { r: FAR, g: 0.0, b: 0.0, a: 0.0 },
    ];
    let attachments = [0, 1].map(|i| {
        Some(wgpu::RenderPassColorAttachment {
            view: &[picture, depth][i].view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load: wgpu::LoadOp::Clear(clears[i]), store: wgpu::StoreOp::Store },
        })
    });
    {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            color_attachments: &attachments,
            ..Default::default()
        });
        pass.set_pipeline(pipeline);
        pass.draw(0..3, 0..1);
    }
    let readbacks = match read_back {
        true => vec![copy_out(device, &mut encoder, picture), copy_out(device, &mut encoder, depth)],
        false => vec![],
    };
    (encoder, readbacks)
}
// ANCHOR_END: render

/// Records a copy of `image` into a buffer the CPU can map.
pub fn copy_out(device: &wgpu::Device, encoder: &mut wgpu::CommandEncoder, image: &SharedImage) -> Readback {
    let size = image.wgpu.size();
    let row_bytes = size.width * image.wgpu.format().block_copy_size(None).unwrap_or(4);
    let padded = row_bytes.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: padded as u64 * size.height as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    encoder.copy_texture_to_buffer(
        image.wgpu.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: None,
            },
        },
        size,
    );
    Readback { buffer, row_bytes, padded }
}

impl Readback {
    /// The image's bytes, its top row first, once wgpu's work is done (`wait` polls for it).
    pub fn bytes(&self, device: &wgpu::Device) -> Result<Vec<u8>> {
        self.buffer.slice(..).map_async(wgpu::MapMode::Read, |_| {});
        fail::step("wgpu: map the readback (Device::poll, wait)")?;
        device.poll(wgpu::PollType::wait_indefinitely()).context("wgpu: Device::poll")?;
        let mapped = self.buffer.slice(..).get_mapped_range().map_err(|e| anyhow::anyhow!("wgpu: {e}"))?;
        let rows = mapped.chunks(self.padded as usize).map(|row| &row[..self.row_bytes as usize]);
        let bytes = rows.flatten().copied().collect();
        drop(mapped);
        self.buffer.unmap();
        Ok(bytes)
    }
}
