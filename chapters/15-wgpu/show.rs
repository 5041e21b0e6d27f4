//! Chapter 15, step 8: GL draws wgpu's picture, then a line over it that wgpu's depth hides where
//! the triangle is nearer (chapter 08's overlays, with depth that crossed from wgpu), into the
//! shared image that wgpu reads next; and copies wgpu's outline of it into a window.

use crate::shared::SharedImage;
use anyhow::Result;
use common::base::gl::{Owned, create, framebuffer_over, program, renderbuffer};
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

/// GL's framebuffers over the shared images: the one GL draws into, with a depth buffer of GL's
/// own that wgpu's depth is written into, and wgpu's outline alone (to copy into a window).
pub struct Framebuffers {
    pub drawn: Owned<glow::Framebuffer>,
    #[allow(dead_code)] // never read: held as long as the framebuffer it is attached to
    depth: Owned<glow::Renderbuffer>,
    outline: Owned<glow::Framebuffer>,
}

/// GL's programs and line, and its framebuffers over the shared images.
pub struct Show {
    pub framebuffers: Framebuffers,
    size: (u32, u32),
    picture: Owned<glow::Program>,
    lines_program: Owned<glow::Program>,
    line: LineBuffer,
    empty: Owned<glow::VertexArray>,
}

impl Show {
    /// `into` is the shared image GL draws into, `outline` the one wgpu writes its outline to.
    pub fn new(gl: &Rc<glow::Context>, [into, outline]: [&SharedImage; 2], size: (u32, u32)) -> Result<Self> {
        let picture = program(gl, FULLSCREEN, PICTURE)?;
        let lines_program = program(gl, LINES_VERTEX, LINES_FRAGMENT)?;
        let colour = LINE_COLOUR.map(|c| c as f32 / 255.0);
        let vertex = |x: f32| LineVertex { position: [x, LINE_Y, LINE_DEPTH], colour };
        let line = LineBuffer::new(gl, &[vertex(-0.95), vertex(0.95)])?;
        let empty =
            create(gl, "glCreateVertexArrays (none)", |gl| unsafe { gl.create_named_vertex_array() })?;
        let framebuffers = Self::framebuffers(gl, [into, outline], size)?;
        Ok(Show { framebuffers, size, picture, lines_program, line, empty })
    }

    fn framebuffers(
        gl: &Rc<glow::Context>,
        [into, outline]: [&SharedImage; 2],
        (w, h): (u32, u32),
    ) -> Result<Framebuffers> {
        let what = "glCreateRenderbuffers for GL's depth";
        let depth = renderbuffer(gl, what, (glow::DEPTH_COMPONENT32F, "DEPTH_COMPONENT32F", 4), (w, h))?;
        let drawn = framebuffer_over(gl, "glCreateFramebuffers (GL's picture)", *into.gl.texture)?;
        let outlined = framebuffer_over(gl, "glCreateFramebuffers (the outline)", *outline.gl.texture)?;
        // GL's picture is depth-tested: its framebuffer has the depth renderbuffer too.
        let (attachment, target) = (glow::DEPTH_ATTACHMENT, glow::RENDERBUFFER);
        unsafe { gl.named_framebuffer_renderbuffer(Some(*drawn), attachment, target, Some(*depth)) };
        Ok(Framebuffers { drawn, depth, outline: outlined })
    }

    /// New shared images: framebuffers over them. The old ones go first, before their images
    /// are dropped: a framebuffer would keep a deleted texture, and so its memory, alive.
    pub fn resize(
        &mut self,
        gl: &Rc<glow::Context>,
        images: [&SharedImage; 2],
        size: (u32, u32),
    ) -> Result<()> {
        self.framebuffers = Self::framebuffers(gl, images, size)?;
        self.size = size;
        Ok(())
    }

    // ANCHOR: draw
    /// wgpu's picture and depth into GL's framebuffer, then (with `lines`) the line, depth-tested.
    pub fn draw(&self, gl: &glow::Context, [picture, depth]: [&SharedImage; 2], lines: bool) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffers.drawn));
            gl.viewport(0, 0, self.size.0 as i32, self.size.1 as i32);
            gl.enable(glow::DEPTH_TEST);
            // Every pixel written, colour and depth: the picture covers the target.
            gl.depth_func(glow::ALWAYS);
            gl.use_program(Some(*self.picture));
            gl.bind_texture_unit(0, Some(*picture.gl.texture));
            gl.bind_texture_unit(1, Some(*depth.gl.texture));
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

    /// Into a window: wgpu's outline, scaled to the window's back buffer. GL drew the picture it
    /// outlines with its first row at the bottom, as a window counts them: no flip.
    pub fn blit(&self, gl: &glow::Context, (w, h): (u32, u32)) {
        let (tw, th) = (self.size.0 as i32, self.size.1 as i32);
        unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*self.framebuffers.outline));
            gl.bind_framebuffer(glow::DRAW_FRAMEBUFFER, None);
            let (to, colour) = ([0, 0, w as i32, h as i32], glow::COLOR_BUFFER_BIT);
            gl.blit_framebuffer(0, 0, tw, th, to[0], to[1], to[2], to[3], colour, glow::NEAREST);
        }
    }
}
