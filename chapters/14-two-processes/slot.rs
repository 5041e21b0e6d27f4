//! Chapter 14's reading of a slot, by the viewer and by `--one-process` alike: GL's wait for
//! Vulkan's frame, the read, and the checks that what was read is the frame announced.

use super::picture;
use anyhow::{Result, bail};
use common::base::gl::{GlContext, Owned, Semaphore, layout};
use common::instruments::{fail, output};
use common::interop::SharedTexture;
use glow::HasContext;
use std::time::{Duration, Instant};

// ANCHOR: read_slot
/// GL's queue waits for Vulkan's signal on `frame_written`, and takes `texture`'s image in the
/// layout Vulkan's release left it in: GENERAL. (The renderer announces a frame only once its
/// fence has signalled: this wait is already satisfied, and cannot be left hanging.)
pub fn wait_until_written(gl_context: &GlContext, texture: &SharedTexture, frame_written: &Owned<Semaphore>) {
    let ext = gl_context.semaphores.as_ref().expect("semaphores were negotiated with GL's");
    let (textures, layouts) = ([texture.texture.0.get()], [layout::GENERAL]);
    unsafe {
        (ext.WaitSemaphoreEXT)(
            frame_written.name.0,
            0,
            std::ptr::null(),
            1,
            textures.as_ptr(),
            layouts.as_ptr(),
        )
    };
}

/// The slot's pixels, row 0 first as Vulkan wrote it, once everything GL was asked so far is
/// done (or the renderer lied): waited on the CPU, with `timeout`, so that a wait that never
/// ends is an error rather than a hang.
pub fn read_slot(
    gl_context: &GlContext,
    texture: &SharedTexture,
    (width, height): (u32, u32),
    timeout: Duration,
) -> Result<Vec<u8>> {
    gl_finished(gl_context, timeout)?;
    // glGetTexImage returns when the pixels are in our memory: GL is done with the slot. (Not
    // glReadPixels through a framebuffer: on NVIDIA's driver that takes about 27 ms from an
    // imported texture, glGetTexImage a fraction of one.)
    let read = output::read_texture_rgba8(&gl_context.gl, *texture.texture, width, height);
    gl_context.check_error("reading a slot")?;
    Ok(output::flip_rows(&read, width, height))
}
// ANCHOR_END: read_slot

/// Waits, on the CPU, for every GL command issued so far (a fence, `glClientWaitSync`), for up
/// to `timeout`. GL takes a wait of at most about two seconds at a time: it is asked again.
pub fn gl_finished(gl_context: &GlContext, timeout: Duration) -> Result<()> {
    let gl = &gl_context.gl;
    let fence = common::base::gl::create(gl, "glFenceSync", |gl| unsafe {
        gl.fence_sync(glow::SYNC_GPU_COMMANDS_COMPLETE, 0)
    })?;
    fail::step("glClientWaitSync")?;
    let started = Instant::now();
    loop {
        // FLUSH: the fence is sent to the GPU, or the wait could outlast every timeout.
        match unsafe { gl.client_wait_sync(*fence, glow::SYNC_FLUSH_COMMANDS_BIT, 100_000_000) } {
            glow::ALREADY_SIGNALED | glow::CONDITION_SATISFIED => return Ok(()),
            glow::TIMEOUT_EXPIRED if started.elapsed() < timeout => {}
            glow::TIMEOUT_EXPIRED => bail!("GL's work on a slot did not finish within {timeout:?}"),
            _ => bail!("glClientWaitSync failed (GL_WAIT_FAILED)"),
        }
    }
}

/// Is `pixels` (row 0 first, as Vulkan wrote it) frame `frame`'s picture? Probes the corner
/// (background), the square's centre (white) and the pixel left of it (background, if any).
pub fn is_picture_of(pixels: &[u8], frame: u64, width: u32, height: u32) -> bool {
    let (background, (x, y, side)) = picture(frame, width, height);
    let at = |px: u32, py: u32| &pixels[(py * width + px) as usize * 4..][..4];
    let close = |p: &[u8], q: [u8; 4]| p.iter().zip(q).all(|(&a, b)| a.abs_diff(b) <= 1);
    let left_ok = x == 0 || close(at(x - 1, y + side / 2), background);
    close(at(0, 0), background) && close(at(x + side / 2, y + side / 2), [255; 4]) && left_ok
}

/// Does the window's back buffer show frame `frame`? Its top-left pixel, the background, is
/// read (a window may be any size: the square lands elsewhere, the corner stays background).
pub fn window_shows(
    gl: &glow::Context,
    frame: u64,
    (width, height): (u32, u32),
    (ww, wh): (u32, u32),
) -> bool {
    if ww == 0 || wh == 0 {
        return true; // minimised: nothing to show
    }
    let mut pixel = [0u8; 4];
    unsafe {
        gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None);
        let data = glow::PixelPackData::Slice(Some(&mut pixel));
        gl.read_pixels(0, wh as i32 - 1, 1, 1, glow::RGBA, glow::UNSIGNED_BYTE, data);
    }
    let (background, _) = picture(frame, width, height);
    pixel[..3].iter().zip(&background[..3]).all(|(a, b)| a.abs_diff(*b) <= 1)
}
