//! The overlay lines chapters 08-12 draw over their pictures (taught in chapter 08): an axis
//! gizmo and a selected instance's box, depth-tested against the scene's depth, and the pixels
//! their checks look at.

use super::Target;
use crate::scene::{Camera, Scene};
use anyhow::{Context as _, Result};
use glam::{Mat4, Vec3, Vec4};
use glow::HasContext;
use std::rc::Rc;

const LINES_VERTEX: &str = include_str!("../../../shaders/gl/lines.vert");
const LINES_FRAGMENT: &str = include_str!("../../../shaders/gl/lines.frag");

/// One vertex of an overlay line: world position and colour (24 bytes; `lines.vert`'s inputs).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct LineVertex {
    pub position: [f32; 3],
    pub colour: [f32; 3],
}

/// The overlay lines: an axis gizmo through the scene's centre, and the selected instance's
/// oriented bounding box. GL's own buffer: Vulkan never sees these. Deleted when dropped.
pub struct Overlays {
    program: glow::Program,
    vertex_array: glow::VertexArray,
    buffer: glow::Buffer,
    count: i32,
    /// The gizmo's half-axes (start, end, colour), for the checks.
    axes: Vec<(Vec3, Vec3, [u8; 3])>,
    gl: Rc<glow::Context>,
}

/// Pixels (x, y in memory order) the checks look at.
pub struct Probes {
    pub hidden: Option<(usize, usize, [u8; 3])>,
    pub visible: Option<(usize, usize, [u8; 3])>,
}

impl Overlays {
    pub fn new(gl: &Rc<glow::Context>, scene: &Scene, select: usize) -> Result<Self> {
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
        let program =
            crate::gl::program(gl, LINES_VERTEX, LINES_FRAGMENT).context("the overlay lines' program")?;
        let bytes = crate::gbuffer::as_bytes(&vertices);
        let (vertex_array, buffer) = unsafe {
            let buffer = gl.create_named_buffer().map_err(anyhow::Error::msg);
            let buffer = buffer.inspect_err(|_| gl.delete_program(program)).context("glCreateBuffers")?;
            gl.named_buffer_data_u8_slice(buffer, bytes, glow::STATIC_DRAW);
            crate::resources::created("gl_buffer", bytes.len() as u64);
            let vao = gl.create_named_vertex_array().map_err(anyhow::Error::msg).inspect_err(|_| {
                gl.delete_buffer(buffer);
                gl.delete_program(program);
            });
            let vao = vao.context("glCreateVertexArrays")?;
            gl.vertex_array_vertex_buffer(vao, 0, Some(buffer), 0, size_of::<LineVertex>() as i32);
            for (location, offset) in [(0, 0), (1, 12)] {
                gl.enable_vertex_array_attrib(vao, location);
                gl.vertex_array_attrib_format_f32(vao, location, 3, glow::FLOAT, false, offset);
                gl.vertex_array_attrib_binding_f32(vao, location, 0);
            }
            (vao, buffer)
        };
        Ok(Overlays { program, vertex_array, buffer, count: vertices.len() as i32, axes, gl: gl.clone() })
    }

    // ANCHOR: draw_lines
    /// Lines over the picture, depth-tested against the scene's depth but not writing it.
    pub fn draw(&self, gl: &glow::Context, target: &Target, view_projection: Mat4) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(target.framebuffer));
            gl.viewport(0, 0, target.width as i32, target.height as i32);
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
    /// or certainly visible (nothing at all in front, all around), by the scene's view depth per
    /// pixel (`scene_depth`: `width` x `height`, GL's bottom row first, 0 where nothing was drawn).
    pub fn probe(&self, scene_depth: &[f32], (width, height): (usize, usize), camera: &Camera) -> Probes {
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
                let depth = forward.dot(point - eye);
                let around = |test: &dyn Fn(f32) -> bool| {
                    (y - 2..=y + 2).all(|v| (x - 2..=x + 2).all(|u| test(scene_depth[v * width + u])))
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
}

impl Drop for Overlays {
    fn drop(&mut self) {
        unsafe {
            self.gl.delete_vertex_array(self.vertex_array);
            self.gl.delete_buffer(self.buffer);
            self.gl.delete_program(self.program);
        }
    }
}

/// Does the line's colour appear within a pixel of (x, y)? (A 1-pixel line may be rasterised on
/// a neighbour of the point's own pixel.)
pub fn shows_colour(pixels: &[u8], width: usize, (x, y, colour): (usize, usize, [u8; 3])) -> bool {
    (y - 1..=y + 1).any(|v| {
        (x - 1..=x + 1).any(|u| {
            let p = &pixels[(v * width + u) * 4..][..3];
            p.iter().zip(colour).all(|(&a, b)| a.abs_diff(b) <= 3)
        })
    })
}
