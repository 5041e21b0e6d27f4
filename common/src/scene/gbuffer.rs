//! The scene's shared buffers and the G-buffers GL rasterises them into (taught in chapter 05;
//! chapters 06-08 draw the same way).

use crate::base::chapter;
use crate::base::cli::{CommonArgs, Size};
use crate::base::gl::{GlContext, Owned, create, renderbuffer};
use crate::base::vulkan::{Requirements, VulkanContext};
use crate::base::window::Window;
use crate::instruments::report::Report;
use crate::interop::handoff::Handoff;
use crate::interop::{BufferPair, SharedBuffer, SharedFormat, SharedImage, share_buffer};
use crate::scene::{Camera, Instance, Scene, Vertex};
use anyhow::{Result, ensure};
use ash::vk;
use glow::HasContext;

// ANCHOR: gbuffers
/// One G-buffer: its name (in pictures and reports) and its format in both APIs.
pub struct GBuffer {
    pub name: &'static str,
    pub format: SharedFormat,
}

/// The G-buffers, in the order of the fragment shader's outputs.
pub const GBUFFERS: [GBuffer; 3] = [
    // World position; w = view depth (0 where nothing was drawn), for chapter 08's filter.
    GBuffer { name: "position", format: SharedFormat::RGBA32F },
    // xyz: the shading normal; w: the triangle's own normal, packed (gbuffer.frag, chapter 07).
    GBuffer { name: "normal", format: SharedFormat::RGBA32F },
    GBuffer { name: "albedo", format: SharedFormat::RGBA8 },
];
// ANCHOR_END: gbuffers

/// The G-buffer pass's three stages (chapter 16 compiles them with `#define TEXTURED`).
pub const VERTEX_SHADER: &str = include_str!("../../../shaders/gl/gbuffer.vert");
pub const GEOMETRY_SHADER: &str = include_str!("../../../shaders/gl/gbuffer.geom");
pub const FRAGMENT_SHADER: &str = include_str!("../../../shaders/gl/gbuffer.frag");
/// What `gbuffer.frag` includes: the normal's packing, which Vulkan's shaders include too.
pub const OCTAHEDRAL: (&str, &str) = ("octahedral.glsl", include_str!("../../../shaders/octahedral.glsl"));

/// Every mesh's vertices and indices, and all instances, in buffers Vulkan allocated and GL
/// imported: Vulkan's side (`.vk`, for the acceleration structures) and GL's (`.gl`, for drawing).
/// Dropped, each buffer's GL side goes first (buffer, memory object), then Vulkan's: a
/// [`BufferPair`] drops in that order wherever it is, a half-built list of them included.
pub struct SceneBuffers {
    pub meshes: Vec<[BufferPair; 2]>,
    pub instances: BufferPair,
}

impl SceneBuffers {
    // ANCHOR: share_scene
    /// `usage`: what Vulkan will do with the buffers itself (nothing in chapter 05; build
    /// acceleration structures from them in chapter 06).
    pub fn share(
        vk: &VulkanContext,
        gl: &GlContext,
        scene: &Scene,
        usage: vk::BufferUsageFlags,
    ) -> Result<Self> {
        let mut meshes = Vec::new();
        for mesh in &scene.meshes {
            let vertices = share_buffer(
                vk,
                gl,
                bytemuck::cast_slice(&mesh.vertices),
                usage | vk::BufferUsageFlags::VERTEX_BUFFER,
            )?;
            let indices = share_buffer(
                vk,
                gl,
                bytemuck::cast_slice(&mesh.indices),
                usage | vk::BufferUsageFlags::INDEX_BUFFER,
            )?;
            meshes.push([vertices, indices]);
        }
        let instances = share_buffer(
            vk,
            gl,
            bytemuck::cast_slice(&scene.instances),
            usage | vk::BufferUsageFlags::VERTEX_BUFFER,
        )?;
        Ok(SceneBuffers { meshes, instances })
    }
    // ANCHOR_END: share_scene

    /// Bytes of Vulkan memory GL sees through these buffers.
    pub fn bytes(&self) -> u64 {
        self.meshes.iter().flatten().chain([&self.instances]).map(|pair| pair.vk.memory.size).sum()
    }
}

/// The three G-buffer images (Vulkan's, imported by GL), GL's framebuffer over them with a
/// depth buffer only GL needs, and what GL draws the scene with. Dropped, GL's own objects go
/// first, then the images (each GL side first); the GPU must be done with them.
pub struct GBuffers {
    vertex_arrays: Vec<Owned<glow::VertexArray>>,
    program: Owned<glow::Program>,
    framebuffer: Owned<glow::Framebuffer>,
    /// GL's depth of the scene, from the G-buffer pass: chapter 08 draws overlays against it.
    pub depth: Owned<glow::Renderbuffer>,
    pub images: Vec<SharedImage>,
    pub extent: vk::Extent2D,
}

impl GBuffers {
    /// `usage`: what Vulkan does with the images besides GL drawing into them (COLOR_ATTACHMENT
    /// is always added).
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        handoff: &Handoff,
        buffers: &SceneBuffers,
        extent: vk::Extent2D,
        usage: vk::ImageUsageFlags,
    ) -> Result<Self> {
        check_size(vk, gl, extent)?;
        // ANCHOR: images
        let usage = usage | vk::ImageUsageFlags::COLOR_ATTACHMENT; // GL draws into them
        let mut images = Vec::new();
        for GBuffer { format, .. } in GBUFFERS {
            images.push(SharedImage::new(vk, gl, format, usage, extent)?);
        }
        // GL draws into them first: Vulkan hands them over, in GENERAL, before it does.
        let new: Vec<_> = images.iter().map(|i| (*i.image, *i.texture.texture)).collect();
        crate::interop::hand_new_images_to_gl(vk, gl, handoff, &new)?;
        // ANCHOR_END: images
        let gl_ = &gl.gl;
        let (framebuffer, depth) = unsafe { framebuffer(gl_, &images, extent)? };
        let fragment = crate::base::gl::with_includes(FRAGMENT_SHADER, &[OCTAHEDRAL])?;
        let program = crate::base::gl::program_with_geometry(gl_, VERTEX_SHADER, GEOMETRY_SHADER, &fragment)?;
        let vertex_arrays = vertex_arrays(gl_, buffers)?;
        Ok(GBuffers { vertex_arrays, program, framebuffer, depth, images, extent })
    }

    /// GL's framebuffer over the G-buffers and their depth, for a pass that draws into them with
    /// a program of its own (chapter 16's textured one).
    pub fn framebuffer(&self) -> glow::Framebuffer {
        *self.framebuffer
    }

    /// GL's textures, in `GBUFFERS` order, for the hand-overs.
    pub fn textures(&self) -> Vec<glow::Texture> {
        self.images.iter().map(|i| *i.texture.texture).collect()
    }

    // ANCHOR: draw
    /// Clears the G-buffers and draws the scene: one instanced draw per mesh.
    pub fn draw(&self, gl: &glow::Context, scene: &Scene, camera: &Camera) {
        unsafe {
            self.bind(gl, camera);
            for attachment in 0..GBUFFERS.len() as u32 {
                gl.clear_buffer_f32_slice(glow::COLOR, attachment, &[0.0; 4]);
            }
            gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
            draw_meshes(gl, scene, &self.vertex_arrays);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
    }

    /// The framebuffer, its viewport, the depth test, the program and the camera's matrices.
    unsafe fn bind(&self, gl: &glow::Context, camera: &Camera) {
        let (width, height) = (self.extent.width, self.extent.height);
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.viewport(0, 0, width as i32, height as i32);
            gl.enable(glow::DEPTH_TEST);
            gl.use_program(Some(*self.program));
            let uniform = |name| gl.get_uniform_location(*self.program, name);
            let projection = camera.projection(width as f32 / height as f32);
            gl.uniform_matrix_4_f32_slice(uniform("view").as_ref(), false, &camera.view().to_cols_array());
            gl.uniform_matrix_4_f32_slice(uniform("projection").as_ref(), false, &projection.to_cols_array());
        }
    }

    // ANCHOR_END: draw

    // ANCHOR: depth_first
    /// The same pictures as [`GBuffers::draw`], drawn depth first (`bench --depth-prepass`): a
    /// first pass writes only depth, a second writes the three colour targets only where its
    /// depth equals the nearest (the same program and inputs give the same depth, bit for bit).
    /// Each pixel's fragment shader and its 36 bytes of writes then run once, not once per
    /// overlapping triangle, at the price of transforming the scene twice.
    pub fn draw_depth_first(&self, gl: &glow::Context, scene: &Scene, camera: &Camera) {
        unsafe {
            self.bind(gl, camera);
            gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
            gl.color_mask(false, false, false, false);
            draw_meshes(gl, scene, &self.vertex_arrays);
            gl.color_mask(true, true, true, true);
            for attachment in 0..GBUFFERS.len() as u32 {
                gl.clear_buffer_f32_slice(glow::COLOR, attachment, &[0.0; 4]);
            }
            gl.depth_func(glow::EQUAL);
            gl.depth_mask(false);
            draw_meshes(gl, scene, &self.vertex_arrays);
            gl.depth_func(glow::LESS);
            gl.depth_mask(true);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
    }
    // ANCHOR_END: depth_first
}

/// What every chapter that draws G-buffers (05 on) stands on: both contexts for a picture of
/// `size` ([`chapter::contexts`]), the size refused if the device cannot hold its G-buffers
/// ([`check_size`]) before anything is allocated, and the hand-off between the two APIs (chapter
/// 03's [`Handoff`]). Bound in this order, they are dropped newest first.
pub fn contexts(
    chapter: &str,
    report: &mut Report,
    requirements: &Requirements,
    size: Size,
) -> Result<(VulkanContext, GlContext, Handoff)> {
    let (vk, gl) = chapter::contexts(chapter, report, requirements, size)?;
    check_size(&vk, &gl, size.extent())?;
    let handoff = Handoff::new(&vk, &gl)?;
    Ok((vk, gl, handoff))
}

/// [`contexts`], with GL in a window when there is a display ([`chapter::contexts_in_window`]).
pub fn contexts_in_window(
    chapter: &str,
    report: &mut Report,
    requirements: &Requirements,
    common: &CommonArgs,
) -> Result<(VulkanContext, Option<Window>, GlContext, Handoff)> {
    let (vk, window, gl) = chapter::contexts_in_window(chapter, report, requirements, common)?;
    check_size(&vk, &gl, common.size.extent())?;
    let handoff = Handoff::new(&vk, &gl)?;
    Ok((vk, window, gl, handoff))
}

/// Refuses a size the device cannot hold, naming the bytes, before anything is allocated: each
/// side's largest image, the largest device-local memory heap (the G-buffers, GL's depth and the
/// AO image together), and GL's read-back of one image (`glGetTexImage` writes at most
/// `i32::MAX` bytes: a GLsizei), which the chapters' checks use.
pub fn check_size(vk: &VulkanContext, gl: &GlContext, extent: vk::Extent2D) -> Result<()> {
    let (width, height) = (extent.width as u64, extent.height as u64);
    let name = format!("--size {width}x{height}");
    let limits = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }.limits;
    let gl_largest = unsafe { gl.gl.get_parameter_i32(glow::MAX_TEXTURE_SIZE) } as u64;
    let largest = (limits.max_image_dimension2_d as u64).min(gl_largest);
    ensure!(
        width <= largest && height <= largest,
        "{name}: {} allows images of at most {largest}x{largest} (Vulkan {}, GL {gl_largest})",
        vk.info.name,
        limits.max_image_dimension2_d
    );
    let per_pixel: u64 = GBUFFERS.iter().map(|g| g.format.bytes_per_pixel as u64).sum::<u64>() + 4 + 4; // + depth, AO
    let needed = width * height * per_pixel;
    let heaps = &vk.memory_properties.memory_heaps[..vk.memory_properties.memory_heap_count as usize];
    let heap = heaps
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    ensure!(
        needed <= heap,
        "{name}: the G-buffers, depth and AO image need {needed} bytes ({:.1} GiB), but the largest \
         device-local memory heap of {} holds {heap} bytes ({:.1} GiB)",
        needed as f64 / (1u64 << 30) as f64,
        vk.info.name,
        heap as f64 / (1u64 << 30) as f64
    );
    let read_back = width * height * 16; // the position G-buffer, RGBA32F
    ensure!(
        read_back <= i32::MAX as u64,
        "{name}: reading the position G-buffer back for the checks takes {read_back} bytes, more than \
         GL's {} bytes in one call; choose at most {} pixels (e.g. {}x{})",
        i32::MAX,
        i32::MAX as u64 / 16,
        (i32::MAX as f64 / 16.0).sqrt() as u64,
        (i32::MAX as f64 / 16.0).sqrt() as u64
    );
    Ok(())
}

// ANCHOR: draw_meshes
/// One instanced draw per mesh, each through its vertex array, into the framebuffer bound with
/// the program bound (`bench --probe layouts` draws another lean buffer with it too).
///
/// # Safety
/// GL's context must be current, and `vertex_arrays` the scene's, one per mesh.
pub unsafe fn draw_meshes(gl: &glow::Context, scene: &Scene, vertex_arrays: &[Owned<glow::VertexArray>]) {
    unsafe {
        for ((mesh, instances), vao) in scene.meshes.iter().zip(&scene.mesh_instances).zip(vertex_arrays) {
            gl.bind_vertex_array(Some(**vao));
            let (indices, count) = (mesh.indices.len() as i32, instances.len() as i32);
            // base_instance: this mesh's instances start this many entries into the buffer.
            let first = instances.start;
            gl.draw_elements_instanced_base_vertex_base_instance(
                glow::TRIANGLES,
                indices,
                glow::UNSIGNED_INT,
                0,
                count,
                0,
                first,
            );
        }
        gl.bind_vertex_array(None);
    }
}
// ANCHOR_END: draw_meshes

// ANCHOR: vertex_array
/// How GL reads a mesh: per-vertex attributes from its vertex buffer (binding 0) and
/// per-instance ones from the shared instance buffer (binding 1, advancing once per instance).
/// Chapter 12's visibility pass reads the same buffers the same way.
///
/// # Safety
/// GL's context must be current, and the three buffers GL's names for live shared buffers.
pub unsafe fn vertex_array(
    gl: &std::rc::Rc<glow::Context>,
    vertices: &SharedBuffer,
    indices: &SharedBuffer,
    instances: &SharedBuffer,
) -> Result<Owned<glow::VertexArray>> {
    let owned =
        create(gl, "glCreateVertexArrays for a mesh", |gl| unsafe { gl.create_named_vertex_array() })?;
    let vao = *owned;
    unsafe {
        gl.vertex_array_vertex_buffer(vao, 0, Some(*vertices.buffer), 0, size_of::<Vertex>() as i32);
        gl.vertex_array_vertex_buffer(vao, 1, Some(*instances.buffer), 0, size_of::<Instance>() as i32);
        gl.vertex_array_element_buffer(vao, Some(*indices.buffer));
        // (location, binding, components, byte offset): position, normal, the transform's rows.
        let float_attributes = [(0, 0, 3, 0), (1, 0, 3, 12), (2, 1, 4, 0), (3, 1, 4, 16), (4, 1, 4, 32)];
        for (location, binding, size, offset) in float_attributes {
            gl.enable_vertex_array_attrib(vao, location);
            gl.vertex_array_attrib_format_f32(vao, location, size, glow::FLOAT, false, offset);
            gl.vertex_array_attrib_binding_f32(vao, location, binding);
        }
        // The custom index + mask word, read as an integer (not converted to float).
        gl.enable_vertex_array_attrib(vao, 5);
        gl.vertex_array_attrib_format_i32(vao, 5, 1, glow::UNSIGNED_INT, 48);
        gl.vertex_array_attrib_binding_f32(vao, 5, 1);
        // glow has no glVertexArrayBindingDivisor: bind, then set binding 1's divisor.
        gl.bind_vertex_array(Some(vao));
        gl.vertex_binding_divisor(1, 1);
        gl.bind_vertex_array(None);
    }
    Ok(owned)
}
// ANCHOR_END: vertex_array

/// One [`vertex_array`] per mesh of the shared scene, in the scene's order (GL's context current).
pub fn vertex_arrays(
    gl: &std::rc::Rc<glow::Context>,
    buffers: &SceneBuffers,
) -> Result<Vec<Owned<glow::VertexArray>>> {
    let instances = &buffers.instances.gl;
    buffers.meshes.iter().map(|[v, i]| unsafe { vertex_array(gl, &v.gl, &i.gl, instances) }).collect()
}

// ANCHOR: framebuffer
/// One FBO over the three imported textures, plus a depth buffer only GL needs.
unsafe fn framebuffer(
    gl: &std::rc::Rc<glow::Context>,
    images: &[SharedImage],
    extent: vk::Extent2D,
) -> Result<(Owned<glow::Framebuffer>, Owned<glow::Renderbuffer>)> {
    let what = "glCreateRenderbuffers for the G-buffers' depth";
    let depth_32f = (glow::DEPTH_COMPONENT32F, "DEPTH_COMPONENT32F", 4);
    let depth = renderbuffer(gl, what, depth_32f, (extent.width, extent.height))?;
    let fb =
        create(gl, "glCreateFramebuffers for the G-buffers", |gl| unsafe { gl.create_named_framebuffer() })?;
    unsafe {
        let mut draw_buffers = Vec::new();
        for (i, image) in images.iter().enumerate() {
            let attachment = glow::COLOR_ATTACHMENT0 + i as u32;
            gl.named_framebuffer_texture(Some(*fb), attachment, Some(*image.texture.texture), 0);
            draw_buffers.push(attachment);
        }
        // Fragment output location i goes to attachment i.
        gl.named_framebuffer_draw_buffers(Some(*fb), &draw_buffers);
        gl.named_framebuffer_renderbuffer(
            Some(*fb),
            glow::DEPTH_ATTACHMENT,
            glow::RENDERBUFFER,
            Some(*depth),
        );
        let status = gl.check_named_framebuffer_status(Some(*fb), glow::FRAMEBUFFER);
        // Incomplete: `fb` and `depth` are dropped on the way out, which deletes them.
        ensure!(status == glow::FRAMEBUFFER_COMPLETE, "G-buffer framebuffer incomplete: {status:#x}");
    }
    Ok((fb, depth))
}
// ANCHOR_END: framebuffer
