//! Chapter 11's GL side: the pixel buffer object and its textures (path 1), the composite pass
//! that turns hit distances into depth, and the lines drawn over it with the depth test on.

use crate::scene::{GROUND_HALF, Sphere};
use anyhow::Result;
use common::base::gl::{Owned, create, create_n};
use common::frame::{HalfAxis, LineBuffer, LineVertex, Lines, gizmo};
use glam::{Mat4, Vec3};
use glow::HasContext;
use std::rc::Rc;

const FULLSCREEN: &str = include_str!("../../shaders/gl/fullscreen.vert");
const RAYTRACED: &str = include_str!("../../shaders/gl/raytraced.frag");
const LINES_VERTEX: &str = include_str!("../../shaders/gl/lines.vert");
const LINES_FRAGMENT: &str = include_str!("../../shaders/gl/lines.frag");

/// Bytes the tracer writes per frame: an RGBA8 colour and an f32 distance per pixel.
pub fn traced_bytes(width: u32, height: u32) -> u64 {
    8 * width as u64 * height as u64
}

// ANCHOR: pbo
/// Path 1, as published: a GL pixel buffer object the tracer writes, and the two textures GL
/// copies it into. Deleted when dropped (the textures, then the buffer).
pub struct PixelBuffer {
    pub distance: Owned<glow::Texture>,
    pub colour: Owned<glow::Texture>,
    pub pbo: Owned<glow::Buffer>,
    width: u32,
    height: u32,
}

impl PixelBuffer {
    pub fn new(gl: &Rc<glow::Context>, width: u32, height: u32) -> Result<Self> {
        let pbo = create(gl, "glCreateBuffers for the PBO", |gl| unsafe { gl.create_named_buffer() })?;
        // Written by the tracer every frame, read by GL's copies: STREAM_DRAW.
        unsafe { gl.named_buffer_data_size(*pbo, traced_bytes(width, height) as i32, glow::STREAM_DRAW) };
        common::instruments::resources::created("gl_buffer: PBO", traced_bytes(width, height));
        let texture = |format| -> Result<Owned<glow::Texture>> {
            let what = format!("glCreateTextures for the PBO's {format:#x} copy");
            let texture = create(gl, &what, |gl| unsafe { gl.create_named_texture(glow::TEXTURE_2D) })?;
            unsafe { gl.texture_storage_2d(*texture, 1, format, width as i32, height as i32) };
            common::instruments::resources::created(
                &format!("gl_texture: {format:#x}"),
                4 * (width * height) as u64,
            );
            Ok(texture)
        };
        let colour = texture(glow::RGBA8)?;
        Ok(PixelBuffer { distance: texture(glow::R32F)?, colour, pbo, width, height })
    }

    /// GL copies the buffer into the textures: from the bound unpack buffer, the "pixels"
    /// argument is an offset into it. No bytes cross to the CPU.
    pub fn upload(&self, gl: &glow::Context) {
        let (w, h) = (self.width as i32, self.height as i32);
        unsafe {
            gl.bind_buffer(glow::PIXEL_UNPACK_BUFFER, Some(*self.pbo));
            gl.pixel_store_i32(glow::UNPACK_ALIGNMENT, 4);
            let colour = glow::PixelUnpackData::BufferOffset(0);
            gl.texture_sub_image_2d(*self.colour, 0, 0, 0, w, h, glow::RGBA, glow::UNSIGNED_BYTE, colour);
            let distance = glow::PixelUnpackData::BufferOffset(4 * self.width * self.height);
            gl.texture_sub_image_2d(*self.distance, 0, 0, 0, w, h, glow::RED, glow::FLOAT, distance);
            gl.bind_buffer(glow::PIXEL_UNPACK_BUFFER, None);
        }
    }
    // ANCHOR_END: pbo

    /// The CPU tracer's way in: map the buffer for writing, discarding what it held (as CUDA's
    /// WRITE_DISCARD registration does), fill it, unmap.
    pub fn write_with(&self, gl: &glow::Context, fill: impl FnOnce(&mut [u32])) {
        let bytes = traced_bytes(self.width, self.height);
        unsafe {
            gl.bind_buffer(glow::PIXEL_UNPACK_BUFFER, Some(*self.pbo));
            let access = glow::MAP_WRITE_BIT | glow::MAP_INVALIDATE_BUFFER_BIT;
            let mapped = gl.map_buffer_range(glow::PIXEL_UNPACK_BUFFER, 0, bytes as i32, access);
            // SAFETY: GL mapped `bytes` bytes for writing, 4-byte aligned (buffers map at least 64-aligned).
            fill(bytemuck::cast_slice_mut(std::slice::from_raw_parts_mut(mapped, bytes as usize)));
            gl.unmap_buffer(glow::PIXEL_UNPACK_BUFFER);
            gl.bind_buffer(glow::PIXEL_UNPACK_BUFFER, None);
        }
    }
}

/// Where the composite pass reads the traced pixels from.
#[derive(Clone, Copy)]
pub enum Source<'a> {
    Textures(&'a PixelBuffer),
    /// Path 2: a GL buffer whose storage is the memory the tracer wrote.
    Buffer(glow::Buffer),
}

/// The offscreen target (RGBA8 colour, 24-bit depth), the pass that writes the traced colour
/// and its depth into it, and the lines drawn over it, depth-tested (common::frame::Composite
/// composites G-buffers and AO instead; this one has no G-buffers).
pub struct DepthComposite {
    framebuffer: Owned<glow::Framebuffer>,
    /// Held to be deleted after the framebuffer that uses them.
    _depth: Owned<glow::Renderbuffer>,
    _colour: Owned<glow::Renderbuffer>,
    /// The lines, then the ground square's two triangles.
    vertices: LineBuffer,
    line_vertices: i32,
    empty: Owned<glow::VertexArray>,
    lines_program: Owned<glow::Program>,
    traced_program: Owned<glow::Program>,
    pub width: u32,
    pub height: u32,
    /// The gizmo's half-axes, for the checks.
    pub axes: Vec<HalfAxis>,
}

/// The camera as the composite shader needs it.
pub struct DepthUniforms {
    pub tan_half: (f32, f32),
    pub near: f32,
    pub far: f32,
}

impl DepthComposite {
    pub fn new(gl: &Rc<glow::Context>, width: u32, height: u32, spheres: &[Sphere]) -> Result<Self> {
        let traced_program = common::base::gl::program(gl, FULLSCREEN, RAYTRACED)?;
        let lines_program = common::base::gl::program(gl, LINES_VERTEX, LINES_FRAGMENT)?;
        // ANCHOR: lines
        let mut lines = Lines::default();
        // An axis gizmo from the first sphere's centre: each half-axis starts inside the sphere
        // (hidden) and leaves it (shown); -y goes into the ground.
        let axes = gizmo(Vec3::from(spheres[0].centre), 2.5);
        // Each sphere's bounding box: the sphere hides the box's far edges.
        for s in spheres {
            let (c, r) = (Vec3::from(s.centre), s.radius);
            let corner = |i: u32| {
                c + r * Vec3::new(
                    [-1.0, 1.0][i as usize & 1],
                    [-1.0, 1.0][(i as usize >> 1) & 1],
                    [-1.0, 1.0][i as usize >> 2],
                )
            };
            lines.box_edges(corner, [255, 0, 255]);
        }
        // A wireframe grid through the middle of the ground's squares, a little above it (on it
        // exactly, the two depths would tie and the line would flicker in and out).
        let lift = 0.01;
        for i in -4..4 {
            let v = i as f32 + 0.5;
            lines.line(Vec3::new(v, lift, -GROUND_HALF), Vec3::new(v, lift, GROUND_HALF), [0, 170, 170]);
            lines.line(Vec3::new(-GROUND_HALF, lift, v), Vec3::new(GROUND_HALF, lift, v), [0, 170, 170]);
        }
        // The gizmo last, so that no other line is drawn over it where the checks look.
        lines.half_axes(&axes);
        // ANCHOR_END: lines
        let mut vertices = lines.vertices;
        let line_vertices = vertices.len() as i32;
        // Then the ground square as two triangles, for the depth check only.
        let g = GROUND_HALF;
        for [x, z] in [[-g, -g], [g, -g], [g, g], [-g, -g], [g, g], [-g, g]] {
            vertices.push(LineVertex { position: [x, 0.0, z], colour: [1.0; 3] });
        }
        let empty = create(gl, "glCreateVertexArrays for the composite", |gl| unsafe {
            gl.create_named_vertex_array()
        })?;
        let vertices = LineBuffer::new(gl, &vertices)?;
        let renderbuffer = |format, bytes_per_pixel: u32| -> Result<Owned<glow::Renderbuffer>> {
            let what = format!("glCreateRenderbuffers ({format:#x})");
            let rb = create(gl, &what, |gl| unsafe { gl.create_renderbuffer() })?
                .counted(&format!("gl_renderbuffer: {format:#x}"), (bytes_per_pixel * width * height) as u64);
            unsafe {
                gl.bind_renderbuffer(glow::RENDERBUFFER, Some(*rb));
                gl.renderbuffer_storage(glow::RENDERBUFFER, format, width as i32, height as i32);
                gl.bind_renderbuffer(glow::RENDERBUFFER, None);
            }
            Ok(rb)
        };
        let colour = renderbuffer(glow::RGBA8, 4)?;
        // 24 bits: the depth precision most GL programs draw with; the check counts its steps.
        let depth = renderbuffer(glow::DEPTH_COMPONENT24, 4)?;
        let framebuffer = create(gl, "glCreateFramebuffers for the composite", |gl| unsafe {
            gl.create_named_framebuffer()
        })?;
        unsafe {
            let attach = |point, rb: &Owned<glow::Renderbuffer>| {
                gl.named_framebuffer_renderbuffer(Some(*framebuffer), point, glow::RENDERBUFFER, Some(**rb))
            };
            attach(glow::COLOR_ATTACHMENT0, &colour);
            attach(glow::DEPTH_ATTACHMENT, &depth);
            let status = gl.check_named_framebuffer_status(Some(*framebuffer), glow::FRAMEBUFFER);
            // Incomplete: everything made so far is dropped on the way out, which deletes it.
            anyhow::ensure!(
                status == glow::FRAMEBUFFER_COMPLETE,
                "composite framebuffer incomplete: {status:#x}"
            );
        }
        Ok(DepthComposite {
            framebuffer,
            _depth: depth,
            _colour: colour,
            vertices,
            line_vertices,
            empty,
            lines_program,
            traced_program,
            width,
            height,
            axes,
        })
    }

    // ANCHOR: composite
    /// The traced colour, and its depth in gl_FragDepth: afterwards the depth buffer holds what
    /// rasterising the ray-traced scene would have left there.
    pub fn draw_traced(&self, gl: &glow::Context, source: Source, u: &DepthUniforms) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.viewport(0, 0, self.width as i32, self.height as i32);
            // Every pixel is written, colour and depth: no clear, and no depth *test* (ALWAYS),
            // but depth *writes* on.
            gl.enable(glow::DEPTH_TEST);
            gl.depth_func(glow::ALWAYS);
            gl.depth_mask(true);
            gl.use_program(Some(*self.traced_program));
            match source {
                Source::Textures(pbo) => {
                    gl.bind_texture_unit(0, Some(*pbo.colour));
                    gl.bind_texture_unit(1, Some(*pbo.distance));
                }
                Source::Buffer(buffer) => gl.bind_buffer_base(glow::SHADER_STORAGE_BUFFER, 0, Some(buffer)),
            }
            let at = |name| gl.get_uniform_location(*self.traced_program, name);
            gl.uniform_1_i32(at("from_buffer").as_ref(), matches!(source, Source::Buffer(_)) as i32);
            gl.uniform_2_i32(at("size").as_ref(), self.width as i32, self.height as i32);
            gl.uniform_2_f32(at("tan_half").as_ref(), u.tan_half.0, u.tan_half.1);
            gl.uniform_1_f32(at("near_plane").as_ref(), u.near);
            gl.uniform_1_f32(at("far_plane").as_ref(), u.far);
            gl.bind_vertex_array(Some(*self.empty));
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
            gl.bind_vertex_array(None);
            gl.bind_buffer_base(glow::SHADER_STORAGE_BUFFER, 0, None);
            gl.depth_func(glow::LESS);
        }
    }
    // ANCHOR_END: composite

    // ANCHOR: draw_lines
    /// The lines, tested against the ray-traced depth (LESS: hidden behind any surface nearer
    /// than them), without writing depth.
    pub fn draw_lines(&self, gl: &glow::Context, view_projection: Mat4) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.enable(glow::DEPTH_TEST);
            gl.depth_func(glow::LESS);
            gl.depth_mask(false);
            self.draw_vertices(gl, view_projection, glow::LINES, 0, self.line_vertices);
            gl.depth_mask(true);
        }
    }
    // ANCHOR_END: draw_lines

    /// For the depth check: clears the depth and rasterises the ground square, as any GL
    /// program would draw it.
    pub fn rasterise_ground(&self, gl: &glow::Context, view_projection: Mat4) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.clear_named_framebuffer_f32_slice(Some(*self.framebuffer), glow::DEPTH, 0, &[1.0]);
            gl.enable(glow::DEPTH_TEST);
            gl.depth_func(glow::LESS);
            // Its colour lands in the picture too, which was read before and is drawn anew after.
            self.draw_vertices(gl, view_projection, glow::TRIANGLES, self.line_vertices, 6);
        }
    }

    unsafe fn draw_vertices(
        &self,
        gl: &glow::Context,
        view_projection: Mat4,
        mode: u32,
        first: i32,
        count: i32,
    ) {
        unsafe {
            gl.viewport(0, 0, self.width as i32, self.height as i32);
            gl.use_program(Some(*self.lines_program));
            let at = gl.get_uniform_location(*self.lines_program, "view_projection");
            gl.uniform_matrix_4_f32_slice(at.as_ref(), false, &view_projection.to_cols_array());
            gl.bind_vertex_array(Some(*self.vertices.vertex_array));
            gl.draw_arrays(mode, first, count);
            gl.bind_vertex_array(None);
        }
    }

    /// The colour, RGBA8, bottom row first.
    pub fn read_colour(&self, gl: &glow::Context) -> Vec<u8> {
        let mut pixels = vec![0u8; (self.width * self.height * 4) as usize];
        self.read(gl, glow::RGBA, glow::UNSIGNED_BYTE, &mut pixels);
        pixels
    }

    /// The depth buffer in depth steps (0 ..= 2^24 - 1), bottom row first.
    pub fn read_depth(&self, gl: &glow::Context) -> Vec<u32> {
        let mut bytes = vec![0u8; (self.width * self.height * 4) as usize];
        // As UNSIGNED_INT, GL scales depth to 0 ..= 2^32 - 1: the top 24 bits are the steps.
        self.read(gl, glow::DEPTH_COMPONENT, glow::UNSIGNED_INT, &mut bytes);
        bytes.chunks_exact(4).map(|b| u32::from_ne_bytes(b.try_into().unwrap()) >> 8).collect()
    }

    fn read(&self, gl: &glow::Context, format: u32, ty: u32, into: &mut [u8]) {
        unsafe {
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, Some(*self.framebuffer));
            gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
            let data = glow::PixelPackData::Slice(Some(into));
            gl.read_pixels(0, 0, self.width as i32, self.height as i32, format, ty, data);
            gl.bind_framebuffer(glow::READ_FRAMEBUFFER, None);
        }
    }
}

/// GPU time of GL commands, from two GL_TIMESTAMP queries read back at once (a measurement,
/// not a way to run). (llvmpipe misreads a GL_TIME_ELAPSED query around a PBO upload.)
pub fn gl_time_ms(gl: &Rc<glow::Context>, commands: impl FnOnce()) -> Result<f64> {
    let queries = create_n(gl, "glGenQueries for a GL timing", 2, |gl| unsafe { gl.create_query() })?;
    let (start, end) = (*queries[0], *queries[1]);
    unsafe {
        gl.query_counter(start, glow::TIMESTAMP);
        commands();
        gl.query_counter(end, glow::TIMESTAMP);
        let at = |query| gl.get_query_parameter_u64(query, glow::QUERY_RESULT);
        let nanoseconds = at(end).saturating_sub(at(start));
        Ok(nanoseconds as f64 / 1e6) // `queries` are deleted as they go
    }
}
