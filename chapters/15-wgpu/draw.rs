//! Chapter 15, step 5: wgpu's frame. A render pass draws the triangle into the two shared images;
//! around it, in command buffers of their own, the queue-family transfers wgpu does not make.

use crate::shared::SharedImage;
use anyhow::{Context as _, Result};
use ash::vk;
use common::instruments::fail;
use wgpu::hal::api::Vulkan;

const SHADER: &str = include_str!("../../shaders/wgsl/triangle.wgsl");
/// What the picture is cleared to (chapter 02's background) and its depth image (the far plane).
pub const CLEAR: [f64; 4] = [0.1, 0.1, 0.12, 1.0];
pub const FAR: f64 = 1.0;
/// The two shared images' formats: wgpu's, Vulkan's and GL's names for each.
pub const PICTURE: (wgpu::TextureFormat, vk::Format, u32) =
    (wgpu::TextureFormat::Rgba8Unorm, vk::Format::R8G8B8A8_UNORM, glow::RGBA8);
pub const DEPTH: (wgpu::TextureFormat, vk::Format, u32) =
    (wgpu::TextureFormat::R32Float, vk::Format::R32_SFLOAT, glow::R32F);

// ANCHOR: pipeline
pub fn pipeline(device: &wgpu::Device) -> Result<wgpu::RenderPipeline> {
    fail::step("wgpu: create_shader_module (WGSL) + create_render_pipeline")?;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("triangle.wgsl"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let targets = [Some(PICTURE.0.into()), Some(DEPTH.0.into())];
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

/// One image's transfer between wgpu's queue family and `VK_QUEUE_FAMILY_EXTERNAL` (GL), in the
/// layout wgpu's tracker believes the image is in: a transfer changes no layout behind its back.
fn transfer(image: vk::Image, from: u32, to: u32) -> vk::ImageMemoryBarrier<'static> {
    let layout = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL; // wgpu's TextureUses::RESOURCE
    vk::ImageMemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
        .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)
        .old_layout(layout)
        .new_layout(layout)
        .src_queue_family_index(from)
        .dst_queue_family_index(to)
        .image(image)
        .subresource_range(common::base::commands::COLOR_RANGE)
}

/// A command buffer of raw Vulkan barriers (wgpu forbids mixing raw and wgpu commands in one).
fn barriers(device: &wgpu::Device, barriers: &[vk::ImageMemoryBarrier]) -> wgpu::CommandBuffer {
    let mut encoder = device.create_command_encoder(&Default::default());
    // SAFETY: the callback records one barrier into the encoder wgpu opened, and ends nothing.
    unsafe {
        encoder.as_hal_mut::<Vulkan, _, _>(|hal| {
            let hal = hal.expect("a Vulkan encoder");
            let stage = vk::PipelineStageFlags::ALL_COMMANDS;
            let raw = hal.raw_handle();
            let hal_device = device.as_hal::<Vulkan>().expect("a Vulkan device");
            hal_device.raw_device().cmd_pipeline_barrier(
                raw,
                stage,
                stage,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                barriers,
            );
        })
    };
    encoder.finish()
}

/// A readback of one image: rows padded to wgpu's 256-byte copy alignment.
pub struct Readback {
    pub buffer: wgpu::Buffer,
    pub row_bytes: u32,
    pub padded: u32,
}

/// What one frame of wgpu's needs: the images, whether GL had them (an acquire first), whether
/// to read them back, and the semaphores ([wgpu done, GL done]) where both sides share them,
/// with whether GL has signalled its one (once it has, every submission waits for it: after a
/// resize too, when the new images were never GL's, or the signal would be left pending).
pub struct Frame<'a> {
    pub images: [&'a SharedImage; 2],
    pub gl_had_them: bool,
    pub read_back: bool,
    pub semaphores: Option<[vk::Semaphore; 2]>,
    pub gl_signalled: bool,
}

// ANCHOR: frame
/// Records and submits wgpu's frame; returns the readbacks asked for.
pub fn frame(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipeline: &wgpu::RenderPipeline,
    frame: Frame,
) -> Result<Vec<Readback>> {
    // SAFETY: read only (the queue family's index); the guard is dropped at once.
    let family = unsafe { device.as_hal::<Vulkan>() }.context("a Vulkan device")?.queue_family_index();
    let raw = frame.images.map(|image| *image.image);
    let mut buffers = Vec::new();
    // 1. Acquire from GL: the other half of GL's release (its semaphore signal, or glFinish).
    if frame.gl_had_them {
        buffers.push(barriers(device, &raw.map(|image| transfer(image, vk::QUEUE_FAMILY_EXTERNAL, family))));
    }
    // 2. The render pass, in plain wgpu: wgpu makes every barrier inside its own queue family.
    let mut encoder = device.create_command_encoder(&Default::default());
    let views = frame.images.map(|image| image.wgpu.create_view(&Default::default()));
    let clears = [
        wgpu::Color { r: CLEAR[0], g: CLEAR[1], b: CLEAR[2], a: CLEAR[3] },
        wgpu::Color { r: FAR, g: 0.0, b: 0.0, a: 0.0 },
    ];
    let attachments: Vec<_> = views
        .iter()
        .zip(clears)
        .map(|(view, clear)| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(clear), store: wgpu::StoreOp::Store },
            })
        })
        .collect();
    {
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            color_attachments: &attachments,
            ..Default::default()
        });
        pass.set_pipeline(pipeline);
        pass.draw(0..3, 0..1);
    }
    let readbacks = if frame.read_back {
        Vec::from(frame.images.map(|image| read_back(device, &mut encoder, image)))
    } else {
        vec![]
    };
    // The layout GL's semaphore calls name (GL_LAYOUT_SHADER_READ_ONLY_EXT): wgpu's own barrier.
    let transitions = frame.images.map(|image| wgpu::TextureTransition {
        texture: &image.wgpu,
        selector: None,
        state: wgpu::TextureUses::RESOURCE,
    });
    encoder.transition_resources(std::iter::empty(), transitions.into_iter());
    buffers.push(encoder.finish());
    // 3. Release to GL, in the layout wgpu left.
    buffers.push(barriers(device, &raw.map(|image| transfer(image, family, vk::QUEUE_FAMILY_EXTERNAL))));

    // 4. Submit, with the semaphores in wgpu's own vkQueueSubmit where both sides have them.
    fail::step("wgpu: Queue::submit")?;
    if let Some([wgpu_done, gl_done]) = frame.semaphores {
        // SAFETY: the semaphores live until the queue is idle (their owner is dropped after).
        let hal = unsafe { queue.as_hal::<Vulkan>() }.context("a Vulkan queue")?;
        if frame.gl_signalled {
            hal.add_wait_semaphore(gl_done, None, vk::PipelineStageFlags::ALL_COMMANDS);
        }
        hal.add_signal_semaphore(wgpu_done, None);
    }
    queue.submit(buffers);
    Ok(readbacks)
}
// ANCHOR_END: frame

fn read_back(device: &wgpu::Device, encoder: &mut wgpu::CommandEncoder, image: &SharedImage) -> Readback {
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
