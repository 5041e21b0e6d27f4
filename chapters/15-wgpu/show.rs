//! Chapter 15, step 6: GL shows wgpu's picture, then draws a line over it that wgpu's depth
//! hides where the triangle is nearer (chapter 08's overlays, with depth that crossed from wgpu).

use anyhow::{Result, bail};
use common::base::gl::{Owned, RenderTarget, create, program, renderbuffer};
use common::frame::{LineBuffer, LineVertex};
use glow::HasContext;
use std::rc::Rc;

const FULLSCREEN: &str = include_str!("../../shaders/gl/fullscreen.vert");
const PICTURE: &str = include_str!("../../shaders/gl/wgpu_picture.frag");
const LINES_VERTEX: &str = include_str!("../../shaders/gl/lines.vert");
const LINES_FRAGMENT: &str = include_str!("../../shaders/gl/lines.frag");

// ANCHOR: line
/// The line GL draws: across the triangle's lower half at depth 0.5, where wgpu's triangle runs
/// from 0.2 (left) to 0.8 (right), so its left half is behind the triangle and its right in front.
pub const LINE_Y: f32 = -0.5;
pub const LINE_DEPTH: f32 = 0.5;
pub const LINE_COLOUR: [u8; 3] = [255, 0, 255]; // a colour the triangle never shows
/// wgpu's depth runs from 0 to 1 in clip space, GL's from -1 to 1: this matrix takes the line's
/// (x, y, depth) in wgpu's terms to GL's clip space, so that both write the same window depth.
const WGPU_TO_GL_DEPTH: [f32; 16] =
    [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, -1.0, 1.0];
// ANCHOR_END: line

/// GL's programs, the line, and a colour + depth target of the images' size.
pub struct Show {
    pub target: RenderTarget,
    depth: Owned<glow::Renderbuffer>,
    picture: Owned<glow::Program>,
    lines_program: Owned<glow::Program>,
    line: LineBuffer,
    empty: Owned<glow::VertexArray>,
}

impl Show {
    pub fn new(gl: &Rc<glow::Context>, (width, height): (u32, u32)) -> Result<Self> {
        let picture = program(gl, FULLSCREEN, PICTURE)?;
        let lines_program = program(gl, LINES_VERTEX, LINES_FRAGMENT)?;
        let colour = LINE_COLOUR.map(|c| c as f32 / 255.0);
        let vertex = |x: f32| LineVertex { position: [x, LINE_Y, LINE_DEPTH], colour };
        let line = LineBuffer::new(gl, &[vertex(-0.95), vertex(0.95)])?;
        let empty =
            create(gl, "glCreateVertexArrays (none)", |gl| unsafe { gl.create_named_vertex_array() })?;
        let (target, depth) = Self::target(gl, (width, height))?;
        Ok(Show { target, depth, picture, lines_program, line, empty })
    }

    /// A framebuffer of the images' size, with a depth buffer that wgpu's depth is written into.
    pub fn target(
        gl: &Rc<glow::Context>,
        (w, h): (u32, u32),
    ) -> Result<(RenderTarget, Owned<glow::Renderbuffer>)> {
        let target = RenderTarget::new(gl, w, h)?;
        let what = "glCreateRenderbuffers for GL's depth";
        let depth = renderbuffer(gl, what, (glow::DEPTH_COMPONENT32F, "DEPTH_COMPONENT32F", 4), (w, h))?;
        unsafe {
            let framebuffer = Some(*target.framebuffer);
            gl.named_framebuffer_renderbuffer(
                framebuffer,
                glow::DEPTH_ATTACHMENT,
                glow::RENDERBUFFER,
                Some(*depth),
            );
            let status = gl.check_named_framebuffer_status(framebuffer, glow::FRAMEBUFFER);
            if status != glow::FRAMEBUFFER_COMPLETE {
                bail!("GL's colour + depth framebuffer is incomplete: {status:#x}");
            }
        }
        Ok((target, depth))
    }

    /// After a resize: a target of the new size (the old one deleted).
    pub fn resize(&mut self, gl: &Rc<glow::Context>, size: (u32, u32)) -> Result<()> {
        let (target, depth) = Self::target(gl, size)?;
        (self.target, self.depth) = (target, depth);
        Ok(())
    }

    // ANCHOR: draw
    /// wgpu's picture and depth into GL's target, then (with `lines`) the line, depth-tested.
    pub fn draw(&self, gl: &glow::Context, [picture, depth]: [glow::Texture; 2], lines: bool) {
        unsafe {
            self.target.bind(gl);
            gl.enable(glow::DEPTH_TEST);
            // Every pixel written, colour and depth: the picture covers the target.
            gl.depth_func(glow::ALWAYS);
            gl.use_program(Some(*self.picture));
            gl.bind_texture_unit(0, Some(picture));
            gl.bind_texture_unit(1, Some(depth));
            gl.bind_vertex_array(Some(*self.empty));
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
            if lines {
                // Now the depth test of chapter 08: hidden where wgpu's triangle is nearer.
                gl.depth_func(glow::LESS);
                gl.use_program(Some(*self.lines_program));
                let location = gl.get_uniform_location(*self.lines_program, "view_projection");
                gl.uniform_matrix_4_f32_slice(location.as_ref(), false, &WGPU_TO_GL_DEPTH);
                gl.bind_vertex_array(Some(*self.line.vertex_array));
                gl.draw_arrays(glow::LINES, 0, 2);
            }
            gl.disable(glow::DEPTH_TEST);
            gl.bind_vertex_array(None);
            gl.bind_texture_unit(0, None);
            gl.bind_texture_unit(1, None);
        }
    }
    // ANCHOR_END: draw

    /// Into a window: GL's target, scaled to the window's back buffer.
    pub fn blit(&self, gl: &glow::Context, (w, h): (u32, u32)) {
        let (tw, th) = (self.target.width as i32, self.target.height as i32);
        unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*self.target.framebuffer));
            gl.bind_framebuffer(glow::DRAW_FRAMEBUFFER, None);
            let (to, colour) = ([0, 0, w as i32, h as i32], glow::COLOR_BUFFER_BIT);
            gl.blit_framebuffer(0, 0, tw, th, to[0], to[1], to[2], to[3], colour, glow::NEAREST);
        }
    }
}
