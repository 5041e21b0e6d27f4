//! The composite pass: albedo x occlusion (or a debug view), blurred without crossing edges, into
//! an offscreen colour buffer whose depth buffer is the G-buffer pass's.

use super::overlay::Target;
use crate::base::gl::{Owned, create, renderbuffer};
use crate::rt::ao::AoTracer;
use crate::scene::gbuffer::GBuffers;
use anyhow::Result;
use glam::Vec3;
use glow::HasContext;
use std::rc::Rc;

const FULLSCREEN: &str = include_str!("../../../shaders/gl/fullscreen.vert");
const COMPOSITE: &str = include_str!("../../../shaders/gl/composite.frag");

/// The pictures the composite shader can show (its `view` uniform, in this order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum View {
    Final,
    Position,
    Normal,
    Depth,
    Albedo,
    Ao,
}

impl View {
    pub const ALL: [View; 6] =
        [View::Final, View::Position, View::Normal, View::Depth, View::Albedo, View::Ao];

    pub fn from_index(i: u32) -> View {
        View::ALL[i as usize % 6]
    }

    pub fn name(self) -> &'static str {
        ["final", "position", "normal", "depth", "albedo", "ao"][self as usize]
    }
}

/// The composite shaders' uniforms: chapter 08's fragment shader's (`V` = [`View`]) and chapter
/// 12's compute shader's (`V` = chapter 12's `fast_frame::composite::View`, which shows no positions).
#[derive(Clone, Copy)]
pub struct Uniforms<V = View> {
    pub blur_radius: i32,
    /// Relative: a neighbour is on the same surface if its view depth is within this fraction.
    pub depth_tolerance: f32,
    /// A neighbour is on the same surface if the dot product of the normals is at least this.
    pub normal_tolerance: f32,
    pub power: f32,
    pub view: V,
    pub far_depth: f32,
}

impl<V> Uniforms<V> {
    /// Chapter 08's blur as its flags start it (a neighbour within 2% of the depth and facing
    /// within about 25 degrees), with a blur radius, a power and a view.
    pub fn new(blur_radius: u32, power: f32, view: V, far_depth: f32) -> Uniforms<V> {
        Uniforms {
            blur_radius: blur_radius as i32,
            depth_tolerance: 0.02,
            normal_tolerance: 0.9,
            power,
            view,
            far_depth,
        }
    }

    /// Sets what both composite shaders declare alike (all but `view`, whose numbering is each
    /// shader's own) on `program`, which is in use: the blur, its edge tests and the power.
    pub fn set_blur(&self, gl: &glow::Context, program: glow::Program) {
        let at = |name| unsafe { gl.get_uniform_location(program, name) };
        unsafe {
            gl.uniform_1_i32(at("blur_radius").as_ref(), self.blur_radius);
            gl.uniform_1_f32(at("depth_tolerance").as_ref(), self.depth_tolerance);
            gl.uniform_1_f32(at("normal_tolerance").as_ref(), self.normal_tolerance);
            gl.uniform_1_f32(at("power").as_ref(), self.power);
            gl.uniform_1_f32(at("far_depth").as_ref(), self.far_depth);
        }
    }
}

impl Uniforms {
    /// Chapter 08's final picture as its flags start it (a blur of radius 2), for the chapters
    /// that show only that.
    pub fn final_picture(power: f32, far_depth: f32) -> Uniforms {
        Uniforms::new(2, power, View::Final, far_depth)
    }
}

/// The composite pass: a full-screen triangle into an offscreen colour buffer whose depth
/// buffer is the G-buffer pass's, so that overlays drawn next are tested against the scene.
/// Deleted when dropped too, so that an early return from `run` leaves nothing behind.
pub struct Composite {
    /// The scene's box, which the position view maps to colours.
    bounds: (Vec3, Vec3),
    framebuffer: Owned<glow::Framebuffer>,
    colour: Owned<glow::Renderbuffer>,
    empty: Owned<glow::VertexArray>,
    program: Owned<glow::Program>,
    width: u32,
    height: u32,
}

impl Composite {
    pub fn new(gl: &Rc<glow::Context>, gbuffers: &GBuffers, bounds: (Vec3, Vec3)) -> Result<Self> {
        let program = crate::base::gl::program(gl, FULLSCREEN, COMPOSITE)?;
        // Core profile draws need a vertex array bound, even one that feeds nothing.
        let empty = create(gl, "glCreateVertexArrays for the composite", |gl| unsafe {
            gl.create_named_vertex_array()
        })?;
        let (framebuffer, colour) = new_target(gl, gbuffers)?;
        let (width, height) = (gbuffers.extent.width, gbuffers.extent.height);
        Ok(Composite { bounds, framebuffer, colour, empty, program, width, height })
    }

    /// After the G-buffers were made anew: a colour buffer of their size, their depth buffer.
    pub fn resize(&mut self, gl: &Rc<glow::Context>, gbuffers: &GBuffers) -> Result<()> {
        // The old target is deleted as the new one takes its place.
        (self.framebuffer, self.colour) = new_target(gl, gbuffers)?;
        (self.width, self.height) = (gbuffers.extent.width, gbuffers.extent.height);
        Ok(())
    }

    // ANCHOR: composite
    /// Albedo x occlusion (or a debug view) into the offscreen target.
    pub fn draw(&self, gl: &glow::Context, gbuffers: &GBuffers, tracer: &AoTracer, u: &Uniforms) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.viewport(0, 0, self.width as i32, self.height as i32);
            // A full-screen pass: it must neither be hidden by the scene's depth nor change it.
            gl.disable(glow::DEPTH_TEST);
            gl.depth_mask(false);
            gl.use_program(Some(*self.program));
            for (unit, texture) in
                gbuffers.textures().into_iter().chain([*tracer.image.texture.texture]).enumerate()
            {
                gl.bind_texture_unit(unit as u32, Some(texture));
            }
            u.set_blur(gl, *self.program);
            let at = |name| gl.get_uniform_location(*self.program, name);
            gl.uniform_1_i32(at("view").as_ref(), u.view as i32);
            let (low, high) = self.bounds;
            gl.uniform_3_f32(at("bounds_low").as_ref(), low.x, low.y, low.z);
            gl.uniform_3_f32(at("bounds_high").as_ref(), high.x, high.y, high.z);
            gl.bind_vertex_array(Some(*self.empty));
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
            gl.bind_vertex_array(None);
            gl.depth_mask(true);
        }
    }
    // ANCHOR_END: composite

    /// Where overlays draw over the picture: this target, whose depth is the scene's.
    pub fn target(&self) -> Target {
        Target { framebuffer: *self.framebuffer, width: self.width, height: self.height }
    }

    /// The target's RGBA8 pixels, bottom row first (memory order).
    pub fn read(&self, gl: &glow::Context) -> Vec<u8> {
        let mut pixels = vec![0u8; (self.width * self.height * 4) as usize];
        unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*self.framebuffer));
            gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
            let data = glow::PixelPackData::Slice(Some(&mut pixels));
            gl.read_pixels(
                0,
                0,
                self.width as i32,
                self.height as i32,
                glow::RGBA,
                glow::UNSIGNED_BYTE,
                data,
            );
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None);
        }
        pixels
    }

    /// Copies the picture into the window's back buffer, scaled to fit.
    pub fn show(&self, gl: &glow::Context, (width, height): (u32, u32)) {
        unsafe {
            gl.blit_named_framebuffer(
                Some(*self.framebuffer),
                None,
                0,
                0,
                self.width as i32,
                self.height as i32,
                0,
                0,
                width as i32,
                height as i32,
                glow::COLOR_BUFFER_BIT,
                glow::LINEAR,
            );
        }
    }
}

// ANCHOR: target
/// An RGBA8 colour buffer, with the G-buffer pass's depth buffer attached as this target's
/// depth: the scene's depth, exactly as GL rasterised it.
fn new_target(
    gl: &Rc<glow::Context>,
    gbuffers: &GBuffers,
) -> Result<(Owned<glow::Framebuffer>, Owned<glow::Renderbuffer>)> {
    let size = (gbuffers.extent.width, gbuffers.extent.height);
    let what = "glCreateRenderbuffers for the composite";
    let colour = renderbuffer(gl, what, (glow::RGBA8, "RGBA8", 4), size)?;
    let fb =
        create(gl, "glCreateFramebuffers for the composite", |gl| unsafe { gl.create_named_framebuffer() })?;
    unsafe {
        gl.named_framebuffer_renderbuffer(
            Some(*fb),
            glow::COLOR_ATTACHMENT0,
            glow::RENDERBUFFER,
            Some(*colour),
        );
        gl.named_framebuffer_renderbuffer(
            Some(*fb),
            glow::DEPTH_ATTACHMENT,
            glow::RENDERBUFFER,
            Some(*gbuffers.depth),
        );
        let status = gl.check_named_framebuffer_status(Some(*fb), glow::FRAMEBUFFER);
        // Incomplete: `fb` and `colour` are dropped on the way out, which deletes them.
        anyhow::ensure!(
            status == glow::FRAMEBUFFER_COMPLETE,
            "composite framebuffer incomplete: {status:#x}"
        );
    }
    Ok((fb, colour))
}
// ANCHOR_END: target
