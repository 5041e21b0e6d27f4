//! Chapter 08's GL side: the composite pass, the overlay lines, and the CPU references its
//! checks compare them with.

use crate::check::Pixels;
use anyhow::Result;
use common::ao::AoTracer;
use common::gbuffer::GBuffers;
use common::scene::Scene;
use glam::{Mat4, Vec3, Vec4};
use glow::HasContext;

const FULLSCREEN: &str = include_str!("../../shaders/gl/fullscreen.vert");
const COMPOSITE: &str = include_str!("../../shaders/gl/composite.frag");
const LINES_VERTEX: &str = include_str!("../../shaders/gl/lines.vert");
const LINES_FRAGMENT: &str = include_str!("../../shaders/gl/lines.frag");

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

/// The composite shader's uniforms.
#[derive(Clone, Copy)]
pub struct Uniforms {
    pub blur_radius: i32,
    /// Relative: a neighbour is on the same surface if its view depth is within this fraction.
    pub depth_tolerance: f32,
    /// A neighbour is on the same surface if the dot product of the normals is at least this.
    pub normal_tolerance: f32,
    pub power: f32,
    pub view: View,
    pub bounds: (Vec3, Vec3),
    pub far_depth: f32,
}

/// The composite pass: a full-screen triangle into an offscreen colour buffer whose depth
/// buffer is the G-buffer pass's, so that overlays drawn next are tested against the scene.
/// Deleted when dropped too, so that an early return from `run` leaves nothing behind.
pub struct Composite {
    program: glow::Program,
    empty: glow::VertexArray,
    framebuffer: glow::Framebuffer,
    colour: glow::Renderbuffer,
    width: u32,
    height: u32,
    gl: std::rc::Rc<glow::Context>,
}

impl Composite {
    pub fn new(gl: &std::rc::Rc<glow::Context>, gbuffers: &GBuffers) -> Result<Self> {
        let program = common::gl::program(gl, FULLSCREEN, COMPOSITE)?;
        // Core profile draws need a vertex array bound, even one that feeds nothing.
        let empty = unsafe { gl.create_named_vertex_array() }.map_err(anyhow::Error::msg)?;
        let (framebuffer, colour) = unsafe { target(gl, gbuffers)? };
        let (width, height) = (gbuffers.extent.width, gbuffers.extent.height);
        Ok(Composite { program, empty, framebuffer, colour, width, height, gl: gl.clone() })
    }

    /// After the G-buffers were made anew: a colour buffer of their size, their depth buffer.
    pub fn resize(&mut self, gl: &glow::Context, gbuffers: &GBuffers) -> Result<()> {
        let (framebuffer, colour) = unsafe { target(gl, gbuffers)? };
        unsafe {
            gl.delete_framebuffer(std::mem::replace(&mut self.framebuffer, framebuffer));
            gl.delete_renderbuffer(std::mem::replace(&mut self.colour, colour));
            common::resources::destroyed("gl_renderbuffer: RGBA8");
        }
        (self.width, self.height) = (gbuffers.extent.width, gbuffers.extent.height);
        Ok(())
    }

    // ANCHOR: composite
    /// Albedo x occlusion (or a debug view) into the offscreen target.
    pub fn draw(&self, gl: &glow::Context, gbuffers: &GBuffers, tracer: &AoTracer, u: &Uniforms) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(self.framebuffer));
            gl.viewport(0, 0, self.width as i32, self.height as i32);
            // A full-screen pass: it must neither be hidden by the scene's depth nor change it.
            gl.disable(glow::DEPTH_TEST);
            gl.depth_mask(false);
            gl.use_program(Some(self.program));
            for (unit, texture) in
                gbuffers.textures().into_iter().chain([tracer.image.texture.texture]).enumerate()
            {
                gl.bind_texture_unit(unit as u32, Some(texture));
            }
            let at = |name| gl.get_uniform_location(self.program, name);
            gl.uniform_1_i32(at("blur_radius").as_ref(), u.blur_radius);
            gl.uniform_1_f32(at("depth_tolerance").as_ref(), u.depth_tolerance);
            gl.uniform_1_f32(at("normal_tolerance").as_ref(), u.normal_tolerance);
            gl.uniform_1_f32(at("power").as_ref(), u.power);
            gl.uniform_1_i32(at("view").as_ref(), u.view as i32);
            let (low, high) = u.bounds;
            gl.uniform_3_f32(at("bounds_low").as_ref(), low.x, low.y, low.z);
            gl.uniform_3_f32(at("bounds_high").as_ref(), high.x, high.y, high.z);
            gl.uniform_1_f32(at("far_depth").as_ref(), u.far_depth);
            gl.bind_vertex_array(Some(self.empty));
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
            gl.bind_vertex_array(None);
            gl.depth_mask(true);
        }
    }
    // ANCHOR_END: composite

    /// The target's RGBA8 pixels, bottom row first (memory order).
    pub fn read(&self, gl: &glow::Context) -> Vec<u8> {
        let mut pixels = vec![0u8; (self.width * self.height * 4) as usize];
        unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(self.framebuffer));
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
                Some(self.framebuffer),
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

    pub fn destroy(self, _gl: &glow::Context) {
        drop(self); // Drop below
    }
}

impl Drop for Composite {
    fn drop(&mut self) {
        let gl = &self.gl;
        unsafe {
            gl.delete_framebuffer(self.framebuffer);
            gl.delete_renderbuffer(self.colour);
            common::resources::destroyed("gl_renderbuffer: RGBA8");
            gl.delete_vertex_array(self.empty);
            gl.delete_program(self.program);
        }
    }
}

// ANCHOR: target
/// An RGBA8 colour buffer, with the G-buffer pass's depth buffer attached as this target's
/// depth: the scene's depth, exactly as GL rasterised it.
unsafe fn target(gl: &glow::Context, gbuffers: &GBuffers) -> Result<(glow::Framebuffer, glow::Renderbuffer)> {
    unsafe {
        let colour = gl.create_renderbuffer().map_err(anyhow::Error::msg)?;
        gl.bind_renderbuffer(glow::RENDERBUFFER, Some(colour));
        let (w, h) = (gbuffers.extent.width as i32, gbuffers.extent.height as i32);
        gl.renderbuffer_storage(glow::RENDERBUFFER, glow::RGBA8, w, h);
        gl.bind_renderbuffer(glow::RENDERBUFFER, None);
        common::resources::created("gl_renderbuffer: RGBA8", 4 * w as u64 * h as u64);
        let fb = gl.create_named_framebuffer().map_err(anyhow::Error::msg)?;
        gl.named_framebuffer_renderbuffer(
            Some(fb),
            glow::COLOR_ATTACHMENT0,
            glow::RENDERBUFFER,
            Some(colour),
        );
        gl.named_framebuffer_renderbuffer(
            Some(fb),
            glow::DEPTH_ATTACHMENT,
            glow::RENDERBUFFER,
            Some(gbuffers.depth),
        );
        let status = gl.check_named_framebuffer_status(Some(fb), glow::FRAMEBUFFER);
        if status != glow::FRAMEBUFFER_COMPLETE {
            gl.delete_framebuffer(fb);
            gl.delete_renderbuffer(colour);
            common::resources::destroyed("gl_renderbuffer: RGBA8");
            anyhow::bail!("composite framebuffer incomplete: {status:#x}");
        }
        Ok((fb, colour))
    }
}
// ANCHOR_END: target

/// One vertex of an overlay line: world position and colour (24 bytes).
#[repr(C)]
#[derive(Clone, Copy)]
struct LineVertex {
    position: [f32; 3],
    colour: [f32; 3],
}

/// The overlay lines: an axis gizmo through the scene's centre, and the selected instance's
/// oriented bounding box. GL's own buffer: Vulkan never sees these.
pub struct Overlays {
    program: glow::Program,
    vertex_array: glow::VertexArray,
    buffer: glow::Buffer,
    count: i32,
    /// The gizmo's half-axes (start, end, colour), for the checks.
    axes: Vec<(Vec3, Vec3, [u8; 3])>,
}

/// Pixels (x, y in memory order) the checks look at.
pub struct Probes {
    pub hidden: Option<(usize, usize, [u8; 3])>,
    pub visible: Option<(usize, usize, [u8; 3])>,
}

impl Overlays {
    pub fn new(gl: &glow::Context, scene: &Scene, select: usize) -> Result<Self> {
        // ANCHOR: lines
        let centre = (scene.bounds.0 + scene.bounds.1) / 2.0;
        let length = 0.3 * scene.size();
        let mut axes = Vec::new();
        for (axis, colour) in [(Vec3::X, [255, 0, 0]), (Vec3::Y, [0, 255, 0]), (Vec3::Z, [0, 0, 255])] {
            axes.push((centre, centre + axis * length, colour));
            // The negative half, darker: below the ground or behind the bunny, often hidden.
            axes.push((centre, centre - axis * length, colour.map(|c| c / 2)));
        }
        let mut vertices: Vec<LineVertex> = Vec::new();
        let mut line = |a: Vec3, b: Vec3, colour: [u8; 3]| {
            let colour = colour.map(|c| c as f32 / 255.0);
            vertices.push(LineVertex { position: a.into(), colour });
            vertices.push(LineVertex { position: b.into(), colour });
        };
        for &(a, b, colour) in &axes {
            line(a, b, colour);
        }
        // The selected instance's box: its mesh's bounds, carried by its transform.
        let mesh = scene.mesh_instances.iter().position(|r| r.contains(&(select as u32))).unwrap_or(0);
        let (low, high) = scene.meshes[mesh].vertices.iter().fold((Vec3::MAX, Vec3::MIN), |(l, h), v| {
            (l.min(Vec3::from(v.position)), h.max(Vec3::from(v.position)))
        });
        let to_world = scene.instances[select].object_to_world();
        let corner = |i: u32| {
            to_world.transform_point3(Vec3::new(
                if i & 1 == 0 { low.x } else { high.x },
                if i & 2 == 0 { low.y } else { high.y },
                if i & 4 == 0 { low.z } else { high.z },
            ))
        };
        for i in 0..8u32 {
            for bit in [1, 2, 4] {
                if i & bit == 0 {
                    line(corner(i), corner(i | bit), [255, 0, 255]);
                }
            }
        }
        // ANCHOR_END: lines
        let program = common::gl::program(gl, LINES_VERTEX, LINES_FRAGMENT)?;
        let bytes = common::gbuffer::as_bytes(&vertices);
        let (vertex_array, buffer) = unsafe {
            let buffer = gl.create_named_buffer().map_err(anyhow::Error::msg)?;
            gl.named_buffer_data_u8_slice(buffer, bytes, glow::STATIC_DRAW);
            common::resources::created("gl_buffer", bytes.len() as u64);
            let vao = gl.create_named_vertex_array().map_err(anyhow::Error::msg)?;
            gl.vertex_array_vertex_buffer(vao, 0, Some(buffer), 0, size_of::<LineVertex>() as i32);
            for (location, offset) in [(0, 0), (1, 12)] {
                gl.enable_vertex_array_attrib(vao, location);
                gl.vertex_array_attrib_format_f32(vao, location, 3, glow::FLOAT, false, offset);
                gl.vertex_array_attrib_binding_f32(vao, location, 0);
            }
            (vao, buffer)
        };
        Ok(Overlays { program, vertex_array, buffer, count: vertices.len() as i32, axes })
    }

    // ANCHOR: draw_lines
    /// Lines over the composite, depth-tested against the scene's depth but not writing it.
    pub fn draw(&self, gl: &glow::Context, composite: &Composite, view_projection: Mat4) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(composite.framebuffer));
            gl.viewport(0, 0, composite.width as i32, composite.height as i32);
            gl.enable(glow::DEPTH_TEST);
            // LEQUAL: a line lying on a surface (an edge of the selected box) stays visible.
            gl.depth_func(glow::LEQUAL);
            gl.depth_mask(false);
            gl.use_program(Some(self.program));
            let at = gl.get_uniform_location(self.program, "view_projection");
            gl.uniform_matrix_4_f32_slice(at.as_ref(), false, &view_projection.to_cols_array());
            gl.bind_vertex_array(Some(self.vertex_array));
            gl.draw_arrays(glow::LINES, 0, self.count);
            gl.bind_vertex_array(None);
            gl.depth_mask(true);
            gl.depth_func(glow::LESS);
        }
    }
    // ANCHOR_END: draw_lines

    /// Points along the gizmo that are certainly hidden (a surface clearly in front, all around)
    /// or certainly visible (nothing at all in front, all around), by the G-buffers' view depth.
    pub fn probe(&self, g: &Pixels, view_projection: Mat4, eye: Vec3, forward: Vec3) -> Probes {
        let mut probes = Probes { hidden: None, visible: None };
        for &(start, end, colour) in &self.axes {
            for step in 4..=18 {
                let point = start.lerp(end, step as f32 / 20.0);
                let clip = view_projection * Vec4::from((point, 1.0));
                let ndc = clip.truncate() / clip.w;
                if clip.w <= 0.0 || ndc.x.abs() > 0.9 || ndc.y.abs() > 0.9 {
                    continue;
                }
                let x = ((ndc.x + 1.0) / 2.0 * g.width as f32) as usize;
                let y = ((ndc.y + 1.0) / 2.0 * g.height as f32) as usize;
                if x < 2 || y < 2 || x + 2 >= g.width || y + 2 >= g.height {
                    continue;
                }
                let depth = forward.dot(point - eye);
                let around = |test: &dyn Fn(f32) -> bool| {
                    (y - 2..=y + 2)
                        .all(|v| (x - 2..=x + 2).all(|u| test(g.positions[(v * g.width + u) * 4 + 3])))
                };
                if probes.hidden.is_none() && around(&|w| w > 0.0 && w < 0.9 * depth) {
                    probes.hidden = Some((x, y, colour));
                }
                if probes.visible.is_none() && around(&|w| w <= 0.0 || w > 1.1 * depth) {
                    probes.visible = Some((x, y, colour));
                }
            }
        }
        probes
    }

    pub fn destroy(self, gl: &glow::Context) {
        unsafe {
            gl.delete_vertex_array(self.vertex_array);
            gl.delete_buffer(self.buffer);
            gl.delete_program(self.program);
        }
    }
}
