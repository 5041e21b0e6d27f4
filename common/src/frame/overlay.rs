//! Overlay lines: world-space segments drawn over a picture with the depth test against the
//! scene's depth, so that the scene's surfaces hide them where they should. GL's own buffer:
//! Vulkan never sees these.

use crate::base::gl::{Owned, create};
use crate::scene::{Camera, Scene};
use anyhow::Result;
use glam::{Mat4, Vec3, Vec4};
use glow::HasContext;
use std::rc::Rc;

const LINES_VERTEX: &str = include_str!("../../../shaders/gl/lines.vert");
const LINES_FRAGMENT: &str = include_str!("../../../shaders/gl/lines.frag");

/// Where overlays draw: a framebuffer whose depth attachment holds the scene's depth (the
/// composite's target, or any other drawn over the same depth), and its size.
#[derive(Clone, Copy, Debug)]
pub struct Target {
    pub framebuffer: glow::Framebuffer,
    pub width: u32,
    pub height: u32,
}

/// One vertex of an overlay line: world position and colour (24 bytes, as `lines.vert` reads it).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LineVertex {
    pub position: [f32; 3],
    pub colour: [f32; 3],
}

/// One half of a gizmo's axis: start, end, colour.
pub type HalfAxis = (Vec3, Vec3, [u8; 3]);

/// An axis gizmo through `centre`: x red, y green, z blue, each half `length` long. The
/// negative half is darker, so that an axis's direction shows even where half of it is hidden.
pub fn gizmo(centre: Vec3, length: f32) -> Vec<HalfAxis> {
    let mut axes = Vec::new();
    for (axis, colour) in [(Vec3::X, [255, 0, 0]), (Vec3::Y, [0, 255, 0]), (Vec3::Z, [0, 0, 255])] {
        axes.push((centre, centre + axis * length, colour));
        axes.push((centre, centre - axis * length, colour.map(|c| c / 2)));
    }
    axes
}

/// Line vertices, two a line, in the order they are added.
#[derive(Default)]
pub struct Lines {
    pub vertices: Vec<LineVertex>,
}

impl Lines {
    pub fn line(&mut self, a: Vec3, b: Vec3, colour: [u8; 3]) {
        let colour = colour.map(|c| c as f32 / 255.0);
        self.vertices.push(LineVertex { position: a.into(), colour });
        self.vertices.push(LineVertex { position: b.into(), colour });
    }

    /// The twelve edges of a box, from its eight corners: `corner(i)` is the corner whose bits
    /// 0, 1, 2 of `i` choose the high x, y, z side.
    pub fn box_edges(&mut self, corner: impl Fn(u32) -> Vec3, colour: [u8; 3]) {
        for i in 0..8u32 {
            for bit in [1, 2, 4] {
                if i & bit == 0 {
                    self.line(corner(i), corner(i | bit), colour);
                }
            }
        }
    }

    pub fn half_axes(&mut self, axes: &[HalfAxis]) {
        for &(a, b, colour) in axes {
            self.line(a, b, colour);
        }
    }
}

/// Line vertices in a GL buffer, with the vertex array `lines.vert` reads them through
/// (location 0 the position, 1 the colour).
pub struct LineBuffer {
    pub vertex_array: Owned<glow::VertexArray>,
    pub buffer: Owned<glow::Buffer>,
}

impl LineBuffer {
    pub fn new(gl: &Rc<glow::Context>, vertices: &[LineVertex]) -> Result<Self> {
        let bytes = bytemuck::cast_slice(vertices);
        let buffer =
            create(gl, "glCreateBuffers for the overlay lines", |gl| unsafe { gl.create_named_buffer() })?;
        let vertex_array = create(gl, "glCreateVertexArrays for the overlay lines", |gl| unsafe {
            gl.create_named_vertex_array()
        })?;
        let lines = LineBuffer { vertex_array, buffer };
        let (vertex_array, buffer) = (*lines.vertex_array, *lines.buffer);
        unsafe {
            gl.named_buffer_data_u8_slice(buffer, bytes, glow::STATIC_DRAW);
            crate::instruments::resources::created("gl_buffer", bytes.len() as u64);
            let stride = size_of::<LineVertex>() as i32;
            gl.vertex_array_vertex_buffer(vertex_array, 0, Some(buffer), 0, stride);
            for (location, offset) in [(0, 0), (1, 12)] {
                gl.enable_vertex_array_attrib(vertex_array, location);
                gl.vertex_array_attrib_format_f32(vertex_array, location, 3, glow::FLOAT, false, offset);
                gl.vertex_array_attrib_binding_f32(vertex_array, location, 0);
            }
        }
        Ok(lines)
    }
}

/// The overlay lines: an axis gizmo through the scene's centre, and the selected instance's
/// oriented bounding box.
pub struct Overlays {
    lines: LineBuffer,
    program: Owned<glow::Program>,
    count: i32,
    /// The gizmo's half-axes, for the checks.
    axes: Vec<HalfAxis>,
}

/// Pixels (x, y in memory order) the checks look at, with the colour a line shows there.
pub struct Probes {
    pub hidden: Option<(usize, usize, [u8; 3])>,
    pub visible: Option<(usize, usize, [u8; 3])>,
}

impl Overlays {
    pub fn new(gl: &Rc<glow::Context>, scene: &Scene, select: usize) -> Result<Self> {
        // ANCHOR: lines
        let centre = (scene.bounds.0 + scene.bounds.1) / 2.0;
        // The negative halves go below the ground or behind the bunny: often hidden.
        let axes = gizmo(centre, 0.3 * scene.size());
        let mut lines = Lines::default();
        lines.half_axes(&axes);
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
        lines.box_edges(corner, [255, 0, 255]);
        // ANCHOR_END: lines
        let program = crate::base::gl::program(gl, LINES_VERTEX, LINES_FRAGMENT)?;
        let count = lines.vertices.len() as i32;
        let lines = LineBuffer::new(gl, &lines.vertices)?;
        Ok(Overlays { lines, program, count, axes })
    }

    // ANCHOR: draw_lines
    /// Lines over the target's picture, depth-tested against the scene's depth but not writing it.
    pub fn draw(&self, gl: &glow::Context, target: &Target, view_projection: Mat4) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(target.framebuffer));
            gl.viewport(0, 0, target.width as i32, target.height as i32);
            gl.enable(glow::DEPTH_TEST);
            // LEQUAL: a line lying on a surface (an edge of the selected box) stays visible.
            gl.depth_func(glow::LEQUAL);
            gl.depth_mask(false);
            gl.use_program(Some(*self.program));
            let at = gl.get_uniform_location(*self.program, "view_projection");
            gl.uniform_matrix_4_f32_slice(at.as_ref(), false, &view_projection.to_cols_array());
            gl.bind_vertex_array(Some(*self.lines.vertex_array));
            gl.draw_arrays(glow::LINES, 0, self.count);
            gl.bind_vertex_array(None);
            gl.depth_mask(true);
            gl.depth_func(glow::LESS);
        }
    }
    // ANCHOR_END: draw_lines

    /// Points along the gizmo that are certainly hidden (a surface clearly in front, all around)
    /// or certainly visible (nothing at all in front, all around), by the scene's view depth:
    /// one value a pixel, `width * height` of them in memory order (bottom row first), 0 where
    /// nothing was drawn. `camera` is the one the picture was drawn with.
    pub fn probe(&self, depth: &[f32], width: usize, height: usize, camera: &Camera) -> Probes {
        let view_projection = camera.view_projection(width as f32 / height as f32);
        let (eye, forward) = (camera.eye, (camera.target - camera.eye).normalize());
        let mut probes = Probes { hidden: None, visible: None };
        for &(start, end, colour) in &self.axes {
            for step in 4..=18 {
                let point = start.lerp(end, step as f32 / 20.0);
                let clip = view_projection * Vec4::from((point, 1.0));
                let ndc = clip.truncate() / clip.w;
                if clip.w <= 0.0 || ndc.x.abs() > 0.9 || ndc.y.abs() > 0.9 {
                    continue;
                }
                let x = ((ndc.x + 1.0) / 2.0 * width as f32) as usize;
                let y = ((ndc.y + 1.0) / 2.0 * height as f32) as usize;
                if x < 2 || y < 2 || x + 2 >= width || y + 2 >= height {
                    continue;
                }
                let point_depth = forward.dot(point - eye);
                let around = |test: &dyn Fn(f32) -> bool| {
                    (y - 2..=y + 2).all(|v| (x - 2..=x + 2).all(|u| test(depth[v * width + u])))
                };
                if probes.hidden.is_none() && around(&|w| w > 0.0 && w < 0.9 * point_depth) {
                    probes.hidden = Some((x, y, colour));
                }
                if probes.visible.is_none() && around(&|w| w <= 0.0 || w > 1.1 * point_depth) {
                    probes.visible = Some((x, y, colour));
                }
            }
        }
        probes
    }
}
