//! Which lean buffer? `bench --probe layouts --rounds N`, after the frames, draws the scene N
//! times into each of two layouts, each with the same 32-bit depth buffer, timed by GL:
//!
//! - the ids this chapter draws (R32UI, 4 bytes a pixel): the ray generation shader rebuilds the
//!   hit, its normal and its albedo from the triangle the id names;
//! - a packed normal and the view depth (RG32UI, 8 bytes, `normal_depth.frag`): the hit would
//!   come back from the depth alone, and the albedo would need 4 bytes more.
//!
//! Both come from the same vertex stage, so they must cover the same pixels: that is checked.

use super::Frame;
use anyhow::{Context as _, Result, ensure};
use ash::vk;
use common::GlContext;
use common::base::gl::{Owned, create};
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::scene::gbuffer::SceneBuffers;
use fast_frame::visibility::VisibilityPass;
use glow::HasContext;
use std::rc::Rc;

const NORMAL_DEPTH: &str = include_str!("../../../shaders/gl/normal_depth.frag");

/// An unsigned integer colour texture of `format` and a depth buffer, as one framebuffer.
/// Deleted when dropped (the framebuffer first).
struct Layout {
    framebuffer: Owned<glow::Framebuffer>,
    _depth: Owned<glow::Renderbuffer>, // held to be deleted after the framebuffer
    colour: Owned<glow::Texture>,
    gl: Rc<glow::Context>,
}

impl Layout {
    fn new(gl: &Rc<glow::Context>, format: u32, extent: vk::Extent2D) -> Result<Self> {
        let (w, h) = (extent.width as i32, extent.height as i32);
        let colour = create(gl, "glCreateTextures for a layout", |gl| unsafe {
            gl.create_named_texture(glow::TEXTURE_2D)
        })?;
        let depth =
            create(gl, "glCreateRenderbuffers for a layout", |gl| unsafe { gl.create_renderbuffer() })?;
        let framebuffer =
            create(gl, "glCreateFramebuffers for a layout", |gl| unsafe { gl.create_named_framebuffer() })?;
        let (c, d, f) = (*colour, *depth, *framebuffer);
        // Each is owned from creation: a failure below drops `layout`, which deletes all three.
        let layout = Layout { framebuffer, _depth: depth, colour, gl: gl.clone() };
        unsafe {
            gl.texture_storage_2d(c, 1, format, w, h);
            gl.bind_renderbuffer(glow::RENDERBUFFER, Some(d));
            gl.renderbuffer_storage(glow::RENDERBUFFER, glow::DEPTH_COMPONENT32F, w, h);
            gl.bind_renderbuffer(glow::RENDERBUFFER, None);
            gl.named_framebuffer_texture(Some(f), glow::COLOR_ATTACHMENT0, Some(c), 0);
            gl.named_framebuffer_renderbuffer(Some(f), glow::DEPTH_ATTACHMENT, glow::RENDERBUFFER, Some(d));
            let status = gl.check_named_framebuffer_status(Some(f), glow::FRAMEBUFFER);
            ensure!(
                status == glow::FRAMEBUFFER_COMPLETE,
                "a layout's framebuffer is incomplete: {status:#x}"
            );
        }
        Ok(layout)
    }

    /// The last of `channels` channels of every pixel (the id; the depth), in memory order.
    fn last_channel(&self, channels: usize, extent: vk::Extent2D) -> Vec<u32> {
        let pixels = extent.width as usize * extent.height as usize;
        let mut words = vec![0u32; pixels * channels];
        let format = if channels == 1 { glow::RED_INTEGER } else { glow::RG_INTEGER };
        unsafe {
            self.gl.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
            let bytes = std::slice::from_raw_parts_mut(words.as_mut_ptr().cast::<u8>(), words.len() * 4);
            self.gl.bind_texture(glow::TEXTURE_2D, Some(*self.colour));
            let data = glow::PixelPackData::Slice(Some(bytes));
            self.gl.get_tex_image(glow::TEXTURE_2D, 0, format, glow::UNSIGNED_INT, data);
            self.gl.bind_texture(glow::TEXTURE_2D, None);
        }
        words.chunks(channels).map(|c| c[channels - 1]).collect()
    }
}

/// The two layouts' passes over `rounds` rounds, for the frame `f` shows (drawn from `buffers`):
/// their median GPU milliseconds, and whether they cover the same pixels.
pub fn measure(gl: &GlContext, f: &Frame, buffers: &SceneBuffers, rounds: u32) -> Result<(f64, f64, bool)> {
    let (g, extent) = (&gl.gl, f.targets.extent);
    let source = common::base::gl::with_includes(NORMAL_DEPTH, &[common::scene::gbuffer::OCTAHEDRAL])?;
    let normal_depth = VisibilityPass::with_fragment_shader(gl, buffers, &source)?;
    let targets = [Layout::new(g, glow::R32UI, extent)?, Layout::new(g, glow::RG32UI, extent)?];
    let mut timer = GlPassTimer::new(g)?;
    let mut times = PassTimes::new();
    for _ in 0..rounds {
        let at = |t: &Layout| (*t.framebuffer, extent);
        timer.time(g, "ids", || f.visibility.draw_into(g, at(&targets[0]), f.scene, &f.ids, &f.camera))?;
        timer.time(g, "normal_depth", || {
            normal_depth.draw_into(g, at(&targets[1]), f.scene, &f.ids, &f.camera)
        })?;
        timer.end_frame(g, &mut times);
    }
    timer.finish(g, &mut times);
    gl.check_error("the layouts' passes").context("--probe layouts")?;
    let median = |pass| common::clocks::timestamps::median_p95(times.samples(pass)).0;
    // Drawn or not: 0 where the clear left it, an id from 1, a view depth above 0 (its bits too).
    let (ids, depths) = (targets[0].last_channel(1, extent), targets[1].last_channel(2, extent));
    let differing = ids.iter().zip(&depths).filter(|(id, z)| (**id == 0) != (**z == 0)).count();
    Ok((median("ids"), median("normal_depth"), differing == 0))
}
