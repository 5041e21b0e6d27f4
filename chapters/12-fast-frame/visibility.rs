//! Chapter 12's lean buffer: the ids that number every instanced triangle, the images of one
//! size (the visibility buffer GL draws and Vulkan reads, the surface Vulkan writes and GL reads,
//! GL's depth and picture), and the pass that draws the ids.

use anyhow::{Context as _, Result, ensure};
use ash::vk;
use common::base::gl::GlContext;
use common::base::gl::{Owned, create, renderbuffer};
use common::base::vulkan::VulkanContext;
use common::frame::Target;
use common::interop::handoff::Handoff;
use common::interop::{SharedFormat, SharedImage};
use common::scene::gbuffer::SceneBuffers;
use common::scene::{Camera, Scene};
use glow::HasContext;

const VERTEX_SHADER: &str = include_str!("../../shaders/gl/visibility.vert");
const FRAGMENT_SHADER: &str = include_str!("../../shaders/gl/visibility.frag");

// ANCHOR: mesh_ids
/// One mesh's share of the ids, and where its triangles are (`MeshIds` in visibility_ao.rgen).
/// Mesh m's instance i's triangle t is id `first_id + i * triangles + t + 1`: every instanced
/// triangle of the scene has its own number, and 0 is left for the background.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MeshIds {
    /// Device addresses of the mesh's shared vertex and index buffers.
    pub vertices: u64,
    pub indices: u64,
    pub first_id: u32,
    pub triangles: u32,
    pub first_instance: u32,
    pub instances: u32,
}

/// Numbers the scene's instanced triangles, mesh by mesh, refusing a scene with more than a
/// 32-bit id can name.
pub fn number_triangles(vk: &VulkanContext, scene: &Scene, buffers: &SceneBuffers) -> Result<Vec<MeshIds>> {
    let mut ids = Vec::new();
    let mut next = 0u64;
    for ((mesh, instances), [vertices, indices]) in
        scene.meshes.iter().zip(&scene.mesh_instances).zip(&buffers.meshes)
    {
        let triangles = (mesh.indices.len() / 3) as u64;
        ids.push(MeshIds {
            vertices: vertices.vk.device_address(vk),
            indices: indices.vk.device_address(vk),
            first_id: next as u32,
            triangles: triangles as u32,
            first_instance: instances.start,
            instances: instances.len() as u32,
        });
        next += triangles * instances.len() as u64;
        ensure!(
            next < u32::MAX as u64,
            "the scene has over {next} instanced triangles; a 32-bit visibility id numbers at most {} \
             (0 is the background): draw fewer instances (--instances)",
            u32::MAX - 1
        );
    }
    Ok(ids)
}
// ANCHOR_END: mesh_ids

// ANCHOR: targets
/// Everything of one size. GL draws ids into `visibility`; Vulkan reads them and writes
/// `surface`; GL's compute composite reads that and writes `picture`, and the overlays are drawn
/// over `picture`, tested against `depth`, GL's depth of the visibility pass.
/// Dropped, GL's own objects go first, then the two shared images, each GL side first.
pub struct Targets {
    /// `picture` and `depth`: where the overlays are drawn.
    pub picture_framebuffer: Owned<glow::Framebuffer>,
    visibility_framebuffer: Owned<glow::Framebuffer>,
    /// GL only, RGBA8: what the frame shows.
    pub picture: Owned<glow::Texture>,
    /// GL only: the ids' depth buffer, then the overlays'.
    pub depth: Owned<glow::Renderbuffer>,
    /// R32UI, 4 bytes a pixel: GL's only colour output.
    pub visibility: SharedImage,
    /// RGBA32F: visibility, view depth, packed normal, albedo (visibility_ao.rgen).
    pub surface: SharedImage,
    pub extent: vk::Extent2D,
    /// Has GL had `surface` yet? A new one starts undefined, never handed over: Vulkan's first
    /// frame takes it as it is and overwrites every pixel (`trace::hand_over_around`).
    pub gl_has_surface: std::cell::Cell<bool>,
}
// ANCHOR_END: targets

impl Targets {
    pub fn new(vk: &VulkanContext, gl: &GlContext, handoff: &Handoff, extent: vk::Extent2D) -> Result<Self> {
        common::scene::gbuffer::check_size(vk, gl, extent)?;
        // ANCHOR: images
        // GL draws the ids (COLOR_ATTACHMENT), Vulkan reads them (STORAGE); Vulkan writes the
        // surface (STORAGE), GL samples it (SAMPLED).
        let attachment = vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::STORAGE;
        let visibility = SharedImage::new(vk, gl, SharedFormat::R32UI, attachment, extent)?;
        let sampled = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
        let surface = SharedImage::new(vk, gl, SharedFormat::RGBA32F, sampled, extent)?;
        // GL draws the ids first: Vulkan hands the image over, in GENERAL, before it does.
        let new = [(*visibility.image, *visibility.texture.texture)];
        common::interop::hand_new_images_to_gl(vk, gl, handoff, &new)?;
        // ANCHOR_END: images
        let g = &gl.gl;
        let (w, h) = (extent.width as i32, extent.height as i32);
        // Each GL object is owned from the moment it exists: a later failure deletes them.
        let what = "glCreateRenderbuffers for the ids' depth";
        let depth_32f = (glow::DEPTH_COMPONENT32F, "DEPTH_COMPONENT32F", 4);
        let depth = renderbuffer(g, what, depth_32f, (extent.width, extent.height))?;
        let picture = create(g, "glCreateTextures for the picture", |g| unsafe {
            g.create_named_texture(glow::TEXTURE_2D)
        })?;
        let framebuffer = |what| create(g, what, |g| unsafe { g.create_named_framebuffer() });
        let targets = Targets {
            picture_framebuffer: framebuffer("glCreateFramebuffers for the picture")?,
            visibility_framebuffer: framebuffer("glCreateFramebuffers for the ids")?,
            picture,
            depth,
            visibility,
            surface,
            extent,
            gl_has_surface: std::cell::Cell::new(false),
        };
        let (depth, picture) = (*targets.depth, *targets.picture);
        let (visibility_framebuffer, picture_framebuffer) =
            (*targets.visibility_framebuffer, *targets.picture_framebuffer);
        unsafe {
            g.texture_storage_2d(picture, 1, glow::RGBA8, w, h);
            let depth_attachment = |fb| {
                g.named_framebuffer_renderbuffer(
                    Some(fb),
                    glow::DEPTH_ATTACHMENT,
                    glow::RENDERBUFFER,
                    Some(depth),
                )
            };
            let ids = *targets.visibility.texture.texture;
            g.named_framebuffer_texture(Some(visibility_framebuffer), glow::COLOR_ATTACHMENT0, Some(ids), 0);
            depth_attachment(visibility_framebuffer);
            g.named_framebuffer_texture(Some(picture_framebuffer), glow::COLOR_ATTACHMENT0, Some(picture), 0);
            depth_attachment(picture_framebuffer);
            for (name, fb) in [("visibility", visibility_framebuffer), ("picture", picture_framebuffer)] {
                let status = g.check_named_framebuffer_status(Some(fb), glow::FRAMEBUFFER);
                // Incomplete: dropping `targets` on the way out deletes everything.
                ensure!(
                    status == glow::FRAMEBUFFER_COMPLETE,
                    "the {name} framebuffer is incomplete: {status:#x}"
                );
            }
        }
        Ok(targets)
    }

    /// Where the ids are drawn: their image and GL's depth.
    pub fn ids_target(&self) -> Target {
        Target {
            framebuffer: *self.visibility_framebuffer,
            width: self.extent.width,
            height: self.extent.height,
        }
    }

    /// Where the overlays are drawn: the picture, tested against the ids' depth.
    pub fn overlay_target(&self) -> Target {
        Target {
            framebuffer: *self.picture_framebuffer,
            width: self.extent.width,
            height: self.extent.height,
        }
    }

    /// Copies the picture into the window's back buffer, scaled to fit.
    pub fn show(&self, gl: &glow::Context, (width, height): (u32, u32)) {
        let (w, h) = (self.extent.width as i32, self.extent.height as i32);
        unsafe {
            gl.blit_named_framebuffer(
                Some(*self.picture_framebuffer),
                None,
                0,
                0,
                w,
                h,
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

/// The visibility pass: the program and one vertex array per mesh, over the shared buffers.
/// Deleted when dropped.
pub struct VisibilityPass {
    vertex_arrays: Vec<Owned<glow::VertexArray>>,
    program: Owned<glow::Program>,
}

impl VisibilityPass {
    pub fn new(gl: &GlContext, buffers: &SceneBuffers) -> Result<Self> {
        let g = &gl.gl;
        let program =
            common::base::gl::program(g, VERTEX_SHADER, FRAGMENT_SHADER).context("the visibility program")?;
        // Chapter 05's vertex arrays: the same buffers, read the same way.
        let vertex_arrays = common::scene::gbuffer::vertex_arrays(g, buffers)?;
        Ok(VisibilityPass { vertex_arrays, program })
    }

    // ANCHOR: draw
    /// Clears the ids to 0 (background) and the depth to 1, then one instanced draw per mesh,
    /// each told where its ids start. `target`: the ids' framebuffer (`Targets::ids_target`).
    pub fn draw(&self, gl: &glow::Context, target: &Target, scene: &Scene, ids: &[MeshIds], camera: &Camera) {
        let (width, height) = (target.width, target.height);
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(target.framebuffer));
            gl.viewport(0, 0, width as i32, height as i32);
            gl.enable(glow::DEPTH_TEST);
            gl.clear_buffer_u32_slice(glow::COLOR, 0, &[0; 4]);
            gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
            gl.use_program(Some(*self.program));
            let uniform = |name| gl.get_uniform_location(*self.program, name);
            let projection = camera.projection(width as f32 / height as f32);
            gl.uniform_matrix_4_f32_slice(uniform("view").as_ref(), false, &camera.view().to_cols_array());
            gl.uniform_matrix_4_f32_slice(uniform("projection").as_ref(), false, &projection.to_cols_array());
            for ((mesh, vao), numbering) in scene.meshes.iter().zip(&self.vertex_arrays).zip(ids) {
                gl.uniform_1_u32(uniform("first_id").as_ref(), numbering.first_id);
                gl.uniform_1_u32(uniform("triangles").as_ref(), numbering.triangles);
                gl.bind_vertex_array(Some(**vao));
                gl.draw_elements_instanced_base_vertex_base_instance(
                    glow::TRIANGLES,
                    mesh.indices.len() as i32,
                    glow::UNSIGNED_INT,
                    0,
                    numbering.instances as i32,
                    0,
                    numbering.first_instance, // this mesh's instances start here in the buffer
                );
            }
            gl.bind_vertex_array(None);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
    }
    // ANCHOR_END: draw
}
