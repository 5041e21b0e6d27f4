//! Which lean buffer? `bench --probe layouts --rounds N`, after the frames, draws the scene N
//! times into each of two layouts, each with the same 32-bit depth buffer, timed by GL:
//!
//! - the ids this chapter draws (R32UI, 4 bytes a pixel): the ray generation shader rebuilds the
//!   hit, its normal and its albedo from the triangle the id names;
//! - a packed normal and the view depth (RG32UI, 8 bytes, `normal_depth.frag`): the hit would
//!   come back from the depth alone, and the albedo would need 4 bytes more.
//!
//! The second layout's vertex stage (`normal_depth.vert`) transforms positions as the ids' does,
//! so the two must cover the same pixels: that is checked.

use super::Frame;
use anyhow::{Context as _, Result, ensure};
use ash::vk;
use common::GlContext;
use common::base::gl::{Owned, create};
use common::clocks::timing::{GlPassTimer, PassTimes};
use common::frame::Target;
use common::scene::gbuffer::SceneBuffers;
use common::scene::{Camera, Scene};
use glow::HasContext;
use std::rc::Rc;

const NORMAL_DEPTH_VERTEX: &str = include_str!("../../../shaders/gl/normal_depth.vert");
const NORMAL_DEPTH: &str = include_str!("../../../shaders/gl/normal_depth.frag");

/// The second layout's pass: its program over chapter 05's vertex arrays of the shared buffers,
/// one instanced draw per mesh, as chapter 12's ids are drawn. Deleted when dropped.
struct NormalDepthPass {
    vertex_arrays: Vec<Owned<glow::VertexArray>>,
    program: Owned<glow::Program>,
}

impl NormalDepthPass {
    fn new(gl: &GlContext, buffers: &SceneBuffers) -> Result<Self> {
        let g = &gl.gl;
        let fragment = common::base::gl::with_includes(NORMAL_DEPTH, &[common::scene::gbuffer::OCTAHEDRAL])?;
        let program = common::base::gl::program(g, NORMAL_DEPTH_VERTEX, &fragment)
            .context("the normal and depth program")?;
        let vertex_arrays = common::scene::gbuffer::vertex_arrays(g, buffers)?;
        Ok(NormalDepthPass { vertex_arrays, program })
    }

    /// Clears the layout to 0 and the depth to 1, then draws every mesh's instances.
    fn draw(&self, gl: &glow::Context, target: &Target, scene: &Scene, camera: &Camera) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(target.framebuffer));
            gl.viewport(0, 0, target.width as i32, target.height as i32);
            gl.enable(glow::DEPTH_TEST);
            gl.clear_buffer_u32_slice(glow::COLOR, 0, &[0; 4]);
            gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
            gl.use_program(Some(*self.program));
            let uniform = |name| gl.get_uniform_location(*self.program, name);
            let projection = camera.projection(target.width as f32 / target.height as f32);
            gl.uniform_matrix_4_f32_slice(uniform("view").as_ref(), false, &camera.view().to_cols_array());
            gl.uniform_matrix_4_f32_slice(uniform("projection").as_ref(), false, &projection.to_cols_array());
            common::scene::gbuffer::draw_meshes(gl, scene, &self.vertex_arrays);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
    }
}

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
    let normal_depth = NormalDepthPass::new(gl, buffers)?;
    let targets = [Layout::new(g, glow::R32UI, extent)?, Layout::new(g, glow::RG32UI, extent)?];
    let mut timer = GlPassTimer::new(g)?;
    let mut times = PassTimes::new();
    for _ in 0..rounds {
        let at =
            |t: &Layout| Target { framebuffer: *t.framebuffer, width: extent.width, height: extent.height };
        timer.time(g, "ids", || f.visibility.draw(g, &at(&targets[0]), f.scene, &f.ids, &f.camera))?;
        timer.time(g, "normal_depth", || normal_depth.draw(g, &at(&targets[1]), f.scene, &f.camera))?;
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
