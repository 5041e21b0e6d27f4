//! Chapter 15, steps 7 and 8: how wgpu and GL take turns with the shared images. wgpu's turn is
//! one submission: the acquire from GL, the caller's commands, the release to GL (the two
//! transfers wgpu does not make), with the semaphores in wgpu's own `vkQueueSubmit`. GL's turn
//! begins with a wait and ends with a signal. Where the drivers share no semaphores, the CPU
//! waits for each side in turn instead.

use crate::device::WgpuDevice;
use crate::shared::SharedImage;
use anyhow::{Context as _, Result};
use ash::vk;
use common::base::gl::{self, GlContext};
use common::clocks::timing::PassTimes;
use common::instruments::fail;
use common::interop::handoff::SharedSemaphore;
use glow::HasContext;
use std::time::Instant;
use wgpu::hal::api::Vulkan;

/// The layout every shared image is in when it changes hands, both ways (GL's name for it).
const GL_LAYOUT: u32 = gl::layout::SHADER_READ_ONLY;
const LAYOUT: vk::ImageLayout = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL; // wgpu's TextureUses::RESOURCE

/// Who holds the images, and how the two sides take turns.
pub struct Turns {
    /// [wgpu done, GL done], where both drivers share semaphores; the host path where not.
    pub semaphores: Option<[SharedSemaphore; 2]>,
    /// Has GL had these images (then wgpu's next turn begins with an acquire)? Not after a resize.
    pub gl_had_them: bool,
    /// Has GL signalled (then wgpu's every turn waits for it, after a resize too, or the signal
    /// would be left pending)?
    gl_signalled: bool,
    /// The CPU's time in each round trip (GL's release, wgpu's submission, GL's acquire): in
    /// all, and in wgpu's calls and GL's.
    pub times: PassTimes,
    wgpu_ms: f64,
    gl_ms: f64,
}

impl Turns {
    pub fn new(semaphores: Option<[SharedSemaphore; 2]>) -> Self {
        Turns {
            semaphores,
            gl_had_them: false,
            gl_signalled: false,
            times: PassTimes::new(),
            wgpu_ms: 0.0,
            gl_ms: 0.0,
        }
    }

    // ANCHOR: wgpu_turn
    /// wgpu's turn: acquire every image from GL, run `commands` (wgpu's own), move every image
    /// into the layout GL's semaphore calls name, release them all to GL, and submit.
    pub fn wgpu(
        &mut self,
        wgpu: &WgpuDevice,
        images: &[SharedImage],
        mut commands: wgpu::CommandEncoder,
    ) -> Result<()> {
        // wgpu's own barrier into the layout GL's calls name, from wherever the commands left them.
        let transitions = images.iter().map(|image| wgpu::TextureTransition {
            texture: &image.wgpu,
            selector: None,
            state: wgpu::TextureUses::RESOURCE,
        });
        commands.transition_resources(std::iter::empty(), transitions);
        let commands = commands.finish();

        let started = Instant::now();
        // SAFETY: read only (the queue family's index); the guard is dropped at once.
        let family =
            unsafe { wgpu.device.as_hal::<Vulkan>() }.context("a Vulkan device")?.queue_family_index();
        let raw: Vec<vk::Image> = images.iter().map(|image| *image.image).collect();
        let mut buffers = Vec::new();
        // The other half of GL's release (its semaphore signal, or glFinish).
        if self.gl_had_them {
            buffers.push(barriers(&wgpu.device, &raw, vk::QUEUE_FAMILY_EXTERNAL, family));
        }
        buffers.push(commands);
        buffers.push(barriers(&wgpu.device, &raw, family, vk::QUEUE_FAMILY_EXTERNAL));

        fail::step("wgpu: Queue::submit")?;
        if let Some([wgpu_done, gl_done]) = &self.semaphores {
            // SAFETY: the semaphores live until the queue is idle (their owner is dropped after).
            let hal = unsafe { wgpu.queue.as_hal::<Vulkan>() }.context("a Vulkan queue")?;
            if self.gl_signalled {
                hal.add_wait_semaphore(*gl_done.vk, None, vk::PipelineStageFlags::ALL_COMMANDS);
            }
            hal.add_signal_semaphore(*wgpu_done.vk, None);
        }
        wgpu.queue.submit(buffers);
        self.wgpu_ms += started.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }
    // ANCHOR_END: wgpu_turn

    // ANCHOR: gl_turn
    /// GL's turn begins: its queue waits for wgpu's signal, or the CPU for wgpu's submission.
    pub fn gl_acquire(&mut self, wgpu: &WgpuDevice, gl: &GlContext, images: &[SharedImage]) -> Result<()> {
        let started = Instant::now();
        match &self.semaphores {
            Some([wgpu_done, _]) => gl_semaphore(gl, wgpu_done, images, false)?,
            None => {
                wgpu.device.poll(wgpu::PollType::wait_indefinitely()).context("wgpu: Device::poll")?;
            }
        }
        self.gl_ms += started.elapsed().as_secs_f64() * 1e3;
        let (wgpu_ms, gl_ms) = (std::mem::take(&mut self.wgpu_ms), std::mem::take(&mut self.gl_ms));
        self.times.add("handshake_cpu", wgpu_ms + gl_ms);
        self.times.add("handshake_wgpu_cpu", wgpu_ms);
        self.times.add("handshake_gl_cpu", gl_ms);
        Ok(())
    }

    /// GL's turn ends: it signals once its commands are done, or the CPU waits for them.
    pub fn gl_release(&mut self, gl: &GlContext, images: &[SharedImage]) -> Result<()> {
        let started = Instant::now();
        match &self.semaphores {
            Some([_, gl_done]) => gl_semaphore(gl, gl_done, images, true)?,
            None => unsafe { gl.gl.finish() },
        }
        (self.gl_had_them, self.gl_signalled) = (true, true);
        self.gl_ms += started.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }
    // ANCHOR_END: gl_turn
}

// ANCHOR: transfer
/// A command buffer of raw Vulkan barriers that move `images` from queue family `from` to `to`,
/// in the layout wgpu's tracker believes they are in: a transfer changes no layout behind its
/// back. (wgpu forbids mixing raw and wgpu commands in one command buffer.)
fn barriers(device: &wgpu::Device, images: &[vk::Image], from: u32, to: u32) -> wgpu::CommandBuffer {
    let transfer = |image| {
        vk::ImageMemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
            .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)
            .old_layout(LAYOUT)
            .new_layout(LAYOUT)
            .src_queue_family_index(from)
            .dst_queue_family_index(to)
            .image(image)
            .subresource_range(common::base::commands::COLOR_RANGE)
    };
    let barriers: Vec<_> = images.iter().map(|&image| transfer(image)).collect();
    let mut encoder = device.create_command_encoder(&Default::default());
    // SAFETY: the callback records barriers into the encoder wgpu opened, and ends nothing.
    unsafe {
        encoder.as_hal_mut::<Vulkan, _, _>(|hal| {
            let hal = hal.expect("a Vulkan encoder");
            let stage = vk::PipelineStageFlags::ALL_COMMANDS;
            let hal_device = device.as_hal::<Vulkan>().expect("a Vulkan device");
            let flags = vk::DependencyFlags::empty();
            hal_device.raw_device().cmd_pipeline_barrier(
                hal.raw_handle(),
                stage,
                stage,
                flags,
                &[],
                &[],
                &barriers,
            );
        })
    };
    encoder.finish()
}
// ANCHOR_END: transfer

// ANCHOR: gl_semaphores
/// GL waits for wgpu (`signal` false) or signals that it is done, on `semaphore`, for every
/// image, each named with the layout it is in: GL_EXT_semaphore's two calls.
fn gl_semaphore(
    gl: &GlContext,
    semaphore: &SharedSemaphore,
    images: &[SharedImage],
    signal: bool,
) -> Result<()> {
    let ext = gl.semaphores.as_ref().context("GL has no GL_EXT_semaphore_fd")?;
    let call = if signal { ext.SignalSemaphoreEXT } else { ext.WaitSemaphoreEXT };
    let names: Vec<u32> = images.iter().map(|image| image.gl.texture.0.get()).collect();
    let layouts = vec![GL_LAYOUT; names.len()];
    // No buffers; one layout per texture.
    unsafe {
        call(semaphore.gl.0, 0, std::ptr::null(), names.len() as u32, names.as_ptr(), layouts.as_ptr())
    };
    if signal {
        // The signal sits in GL's queue until flushed: without this wgpu could wait forever.
        unsafe { gl.gl.flush() };
    }
    Ok(())
}
// ANCHOR_END: gl_semaphores
