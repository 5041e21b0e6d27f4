//! Chapter 16's G-buffer pass: chapter 05's shaders compiled with `TEXTURED`, each mesh drawn
//! with its texture bound and its cut-out's threshold, into the same G-buffers.

use crate::scene::{CUTOFF, TexturedScene};
use crate::textures::Texture;
use anyhow::Result;
use common::base::gl::{Owned, program_with_geometry, with_includes};
use common::interop::BufferPair;
use common::scene::Camera;
use common::scene::gbuffer::{self, GBUFFERS, GBuffers, OCTAHEDRAL, SceneBuffers};
use glow::HasContext;

/// What GL draws a textured scene with: one vertex array per mesh (chapter 05's, with the
/// texture coordinates added), and the program. Dropped: the vertex arrays, then the program.
pub struct TexturedPass {
    vertex_arrays: Vec<Owned<glow::VertexArray>>,
    program: Owned<glow::Program>,
}

/// `#define TEXTURED` right after a shader's `#version` line.
fn textured(source: &str) -> String {
    let at = source.find("#version").and_then(|v| source[v..].find('\n').map(|n| v + n + 1));
    let at = at.unwrap_or(0);
    format!("{}#define TEXTURED\n{}", &source[..at], &source[at..])
}

impl TexturedPass {
    // ANCHOR: vertex_arrays
    /// `uvs`: each textured mesh's shared texture coordinates (None for a mesh without).
    pub fn new(
        gl: &std::rc::Rc<glow::Context>,
        buffers: &SceneBuffers,
        uvs: &[Option<BufferPair>],
    ) -> Result<Self> {
        let fragment = with_includes(&textured(gbuffer::FRAGMENT_SHADER), &[OCTAHEDRAL])?;
        let vertex = textured(gbuffer::VERTEX_SHADER);
        let program = program_with_geometry(gl, &vertex, &textured(gbuffer::GEOMETRY_SHADER), &fragment)?;
        let mut vertex_arrays = Vec::new();
        for ([vertices, indices], uv) in buffers.meshes.iter().zip(uvs) {
            let vao = unsafe { gbuffer::vertex_array(gl, &vertices.gl, &indices.gl, &buffers.instances.gl)? };
            if let Some(uv) = uv {
                // Binding 2, 8 bytes a vertex, to location 6. A mesh without stays at (0, 0, 0, 1),
                // GL's value for a disabled attribute, and samples its one white texel there.
                unsafe {
                    gl.vertex_array_vertex_buffer(*vao, 2, Some(*uv.gl.buffer), 0, 8);
                    gl.enable_vertex_array_attrib(*vao, 6);
                    gl.vertex_array_attrib_format_f32(*vao, 6, 2, glow::FLOAT, false, 0);
                    gl.vertex_array_attrib_binding_f32(*vao, 6, 2);
                }
            }
            vertex_arrays.push(vao);
        }
        Ok(TexturedPass { vertex_arrays, program })
    }
    // ANCHOR_END: vertex_arrays

    // ANCHOR: draw
    /// Clears the G-buffers and draws the scene, each mesh with its texture on unit 0 and the
    /// threshold below which its fragments are holes. `white`: the texture of a mesh without one.
    pub fn draw(
        &self,
        gl: &glow::Context,
        gbuffers: &GBuffers,
        (scene, textures, white): (&TexturedScene, &[Texture], Option<usize>),
        camera: &Camera,
    ) {
        let (width, height) = (gbuffers.extent.width, gbuffers.extent.height);
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(gbuffers.framebuffer()));
            gl.viewport(0, 0, width as i32, height as i32);
            gl.enable(glow::DEPTH_TEST);
            for attachment in 0..GBUFFERS.len() as u32 {
                gl.clear_buffer_f32_slice(glow::COLOR, attachment, &[0.0; 4]);
            }
            gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
            gl.use_program(Some(*self.program));
            let uniform = |name| gl.get_uniform_location(*self.program, name);
            let projection = camera.projection(width as f32 / height as f32);
            gl.uniform_matrix_4_f32_slice(uniform("view").as_ref(), false, &camera.view().to_cols_array());
            gl.uniform_matrix_4_f32_slice(uniform("projection").as_ref(), false, &projection.to_cols_array());
            gl.uniform_1_i32(uniform("colour").as_ref(), 0);
            let meshes = scene.scene.meshes.iter().zip(&scene.scene.mesh_instances).zip(&scene.surfaces);
            for (((mesh, instances), surface), vao) in meshes.zip(&self.vertex_arrays) {
                let texture = surface.map(|s| s.picture).or(white).map(|t| *textures[t].gl.texture);
                let cut_out = surface.is_some_and(|s| s.cut_out);
                gl.bind_texture_unit(0, texture);
                gl.uniform_1_f32(uniform("cutoff").as_ref(), if cut_out { CUTOFF } else { 0.0 });
                gl.bind_vertex_array(Some(**vao));
                let (indices, count) = (mesh.indices.len() as i32, instances.len() as i32);
                gl.draw_elements_instanced_base_vertex_base_instance(
                    glow::TRIANGLES,
                    indices,
                    glow::UNSIGNED_INT,
                    0,
                    count,
                    0,
                    instances.start,
                );
            }
            gl.bind_vertex_array(None);
            gl.bind_texture_unit(0, None);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
    }
    // ANCHOR_END: draw
}
