//! Chapter 05: G-buffers.
//!
//! Vulkan allocates the scene's buffers and three G-buffer images; GL imports them all, draws the
//! scene into the images (one instanced draw per mesh), and hands them back. Vulkan then reads
//! what GL wrote, which is exactly what its ray tracer will read in chapter 07.
//!
//! Run: `cargo run --release --bin 05-g-buffers` (or `-- --scene assets/bunny.obj`).

use anyhow::Result;
use ash::vk;
use common::commands::{COLOR_RANGE, Commands, HostBuffer};
use common::gl::{GlContext, MEMORY_EXTENSIONS, ensure_same_device, layout};
use common::interop::{SharedBuffer, SharedImage, share_buffer};
use common::scene::{self, Camera, Instance, Normals, Scene, Vertex};
use common::sync::{SEMAPHORE_EXTENSION, Sync};
use common::{CommonArgs, Report, Requirements, VulkanContext, ms_since, open_fd_count, output};
use glow::HasContext;
use std::ffi::CStr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "05-g-buffers";
const REQUIRED: &[&CStr] = &[ash::khr::external_memory_fd::NAME];
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];
const VERTEX_SHADER: &str = include_str!("../../shaders/gl/gbuffer.vert");
const FRAGMENT_SHADER: &str = include_str!("../../shaders/gl/gbuffer.frag");

// ANCHOR: gbuffers
/// The G-buffers: (name, Vulkan format, GL's name for it, bytes per pixel).
const GBUFFERS: [(&str, vk::Format, u32, u32); 3] = [
    // World position; w = view depth (0 where nothing was drawn), for chapter 08's filter.
    ("position", vk::Format::R32G32B32A32_SFLOAT, glow::RGBA32F, 16),
    ("normal", vk::Format::R32G32B32A32_SFLOAT, glow::RGBA32F, 16),
    ("albedo", vk::Format::R8G8B8A8_UNORM, glow::RGBA8, 4),
];
// ANCHOR_END: gbuffers

/// Chapter 05: GL rasterises G-buffers into Vulkan-owned images.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// An OBJ file to draw instead of the default scene.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Normals for an OBJ file that has none.
    #[arg(long, value_enum, default_value = "smooth")]
    normals: Normals,
    /// Tetrahedra in the default scene.
    #[arg(long, default_value_t = 10_000)]
    instances: u32,
}

impl AsRef<CommonArgs> for Args {
    fn as_ref(&self) -> &CommonArgs {
        &self.common
    }
}

fn main() -> ExitCode {
    common::run_chapter::<Args>(CHAPTER, run)
}

/// The scene's buffers, shared: Vulkan's side (for chapter 06) and GL's (for drawing).
struct SceneBuffers {
    meshes: Vec<[(common::exportable::ExportedBuffer, SharedBuffer); 2]>,
    instances: (common::exportable::ExportedBuffer, SharedBuffer),
}

fn run(args: &Args, report: &mut Report) -> Result<()> {
    let extent = vk::Extent2D { width: args.common.size.width, height: args.common.size.height };

    // 1. Load the scene
    // ANCHOR: load
    let scene = match &args.scene {
        Some(path) => scene::load_obj(path, args.normals)?,
        None => scene::default_scene(args.instances, 1),
    };
    let camera = Camera::framing(scene.bounds, extent.width as f32 / extent.height as f32);
    // ANCHOR_END: load
    eprintln!(
        "scene: {} meshes, {} instances, {} triangles",
        scene.meshes.len(),
        scene.instances.len(),
        scene.triangles()
    );

    // 2. Create both contexts
    let vk = VulkanContext::new(&Requirements {
        extensions: REQUIRED,
        optional_extensions: OPTIONAL,
        ..Default::default()
    })?;
    let gl_context = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    report.vulkan = Some(vk.report());
    report.gl = Some(gl_context.report());
    report.uuids_match = Some(vk.info.device_uuid == gl_context.device_uuid);
    ensure_same_device(&vk.info, &gl_context)?;
    let sync = Sync::new(&vk, &gl_context)?;
    report.sync = Some(sync.name());
    let open_fds_before = open_fd_count()?;

    // 3. Share the scene's buffers
    let buffers = share_scene(&vk, &gl_context, &scene)?;

    // 4. Share the G-buffer images, and make them GL's render targets
    // ANCHOR: images
    // COLOR_ATTACHMENT: GL draws into them. TRANSFER_SRC: this chapter copies them out.
    // STORAGE: chapter 07's ray tracer reads them.
    let usage = vk::ImageUsageFlags::COLOR_ATTACHMENT
        | vk::ImageUsageFlags::TRANSFER_SRC
        | vk::ImageUsageFlags::STORAGE;
    let mut images = Vec::new();
    for (_, format, gl_format, _) in GBUFFERS {
        images.push(SharedImage::new(&vk, &gl_context, format, gl_format, usage, extent)?);
    }
    let framebuffer = unsafe { gbuffer_framebuffer(gl, &images, extent)? };
    // ANCHOR_END: images
    let program = common::gl::program(gl, VERTEX_SHADER, FRAGMENT_SHADER)?;
    let vertex_arrays: Vec<glow::VertexArray> = buffers
        .meshes
        .iter()
        .map(|[v, i]| unsafe { vertex_array(gl, &v.1, &i.1, &buffers.instances.1) })
        .collect::<Result<_>>()?;

    // 5. Rasterise: one instanced draw per mesh
    let started = Instant::now();
    let query = unsafe { gl.create_query() }.map_err(anyhow::Error::msg)?;
    // ANCHOR: draw
    unsafe {
        gl.bind_framebuffer(glow::FRAMEBUFFER, Some(framebuffer.0));
        gl.viewport(0, 0, extent.width as i32, extent.height as i32);
        gl.enable(glow::DEPTH_TEST);
        for attachment in 0..GBUFFERS.len() as u32 {
            gl.clear_buffer_f32_slice(glow::COLOR, attachment, &[0.0; 4]);
        }
        gl.clear_buffer_f32_slice(glow::DEPTH, 0, &[1.0]);
        gl.use_program(Some(program));
        let aspect = extent.width as f32 / extent.height as f32;
        let uniform = |name| gl.get_uniform_location(program, name);
        gl.uniform_matrix_4_f32_slice(uniform("view").as_ref(), false, &camera.view().to_cols_array());
        gl.uniform_matrix_4_f32_slice(
            uniform("projection").as_ref(),
            false,
            &camera.projection(aspect).to_cols_array(),
        );
        gl.begin_query(glow::TIME_ELAPSED, query);
        for ((mesh, instances), vertex_array) in
            scene.meshes.iter().zip(&scene.mesh_instances).zip(&vertex_arrays)
        {
            gl.bind_vertex_array(Some(*vertex_array));
            let (count, first) = (instances.len() as i32, instances.start);
            // base_instance: this mesh's instances start `first` entries into the shared buffer.
            let indices = mesh.indices.len() as i32;
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
        gl.end_query(glow::TIME_ELAPSED);
    }
    // ANCHOR_END: draw
    gl_context.check_error("drawing the G-buffers")?;

    // 6. Hand the G-buffers to Vulkan, which copies them out
    let commands = Commands::new(&vk)?;
    let mut readbacks = Vec::new();
    for (_, _, _, bytes_per_pixel) in GBUFFERS {
        let bytes = (extent.width * extent.height * bytes_per_pixel) as u64;
        readbacks.push(HostBuffer::new(&vk, bytes, vk::BufferUsageFlags::TRANSFER_DST)?);
    }
    // ANCHOR: handover
    let textures: Vec<glow::Texture> = images.iter().map(|i| i.texture.texture).collect();
    sync.gl_release(&gl_context, &textures, &[layout::TRANSFER_SRC; 3]);
    let cb = commands.begin(&vk)?;
    unsafe { record_copies(&vk, cb, &images, &readbacks) };
    let wait = sync.vulkan_waits_on().map(|s| (s, vk::PipelineStageFlags::TRANSFER));
    commands.submit(&vk, wait, sync.vulkan_signals())?;
    sync.gl_acquire(&vk, &gl_context, commands.fence, &textures, &[layout::COLOR_ATTACHMENT; 3])?;
    unsafe { vk.device.wait_for_fences(&[commands.fence], true, u64::MAX) }?;
    // ANCHOR_END: handover
    report.time_ms("raster_and_handover_cpu", ms_since(started));
    report
        .time_ms("raster_gpu", unsafe { gl.get_query_parameter_u32(query, glow::QUERY_RESULT) } as f64 / 1e6);

    // 7. Check what Vulkan sees, and write it out
    let seen = GBufferPixels::from(&readbacks);
    check_gbuffers(report, &seen, &camera, &scene);
    let out = args.common.out_dir(CHAPTER);
    // Pictures of a loaded model carry its name: 05-g-buffers-bunny-albedo.png.
    let stem =
        args.scene.as_ref().and_then(|p| p.file_stem()).map(|s| format!("{CHAPTER}-{}", s.to_string_lossy()));
    let prefix = stem.as_deref().unwrap_or(CHAPTER);
    // The albedo's background has alpha 0: make it opaque black, as in the other two pictures.
    let albedo: Vec<u8> =
        readbacks[2].bytes().chunks_exact(4).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
    let pictures =
        [("position", seen.position_picture(&scene)), ("normal", seen.normal_picture()), ("albedo", albedo)];
    for (name, pixels) in pictures {
        // GL drew with its bottom row first in memory: flip, so the pictures are upright.
        let upright = output::flip_rows(&pixels, extent.width, extent.height);
        output::save_rgba8(report, &out, &format!("{prefix}-{name}"), extent.width, extent.height, &upright)?;
    }
    report.set("draw_calls", scene.meshes.len());
    report.set("instances", scene.instances.len());
    report.set("triangles", scene.triangles());
    let shared: u64 = buffers.meshes.iter().flatten().map(|b| b.0.memory.size).sum::<u64>()
        + buffers.instances.0.memory.size
        + images.iter().map(|i| i.memory.size).sum::<u64>();
    report.set("bytes_shared", shared);

    // 8. Clean up, newest first
    // ANCHOR: cleanup
    readbacks.into_iter().for_each(|b| b.destroy(&vk));
    commands.destroy(&vk);
    unsafe {
        gl.delete_query(query);
        vertex_arrays.into_iter().for_each(|v| gl.delete_vertex_array(v));
        gl.delete_program(program);
        gl.delete_framebuffer(framebuffer.0);
        gl.delete_renderbuffer(framebuffer.1);
    }
    images.into_iter().for_each(|i| i.destroy(&vk, &gl_context));
    let SceneBuffers { meshes, instances } = buffers;
    for (exported, shared) in meshes.into_iter().flatten().chain([instances]) {
        shared.delete(&gl_context);
        exported.destroy(&vk);
    }
    sync.destroy(&vk, &gl_context);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", open_fd_count()? == open_fds_before);
    Ok(())
}

// ANCHOR: share_scene
/// Every mesh's vertices and indices, and all instances, in buffers Vulkan allocates and GL imports.
fn share_scene(vk: &VulkanContext, gl: &GlContext, scene: &Scene) -> Result<SceneBuffers> {
    let usage = vk::BufferUsageFlags::empty(); // Vulkan itself does not use them until chapter 06
    let mut meshes = Vec::new();
    for mesh in &scene.meshes {
        let vertices =
            share_buffer(vk, gl, as_bytes(&mesh.vertices), usage | vk::BufferUsageFlags::VERTEX_BUFFER)?;
        let indices =
            share_buffer(vk, gl, as_bytes(&mesh.indices), usage | vk::BufferUsageFlags::INDEX_BUFFER)?;
        meshes.push([vertices, indices]);
    }
    let instances =
        share_buffer(vk, gl, as_bytes(&scene.instances), usage | vk::BufferUsageFlags::VERTEX_BUFFER)?;
    Ok(SceneBuffers { meshes, instances })
}
// ANCHOR_END: share_scene

// ANCHOR: vertex_array
/// How GL reads a mesh: per-vertex attributes from its vertex buffer (binding 0) and
/// per-instance ones from the shared instance buffer (binding 1, advancing once per instance).
unsafe fn vertex_array(
    gl: &glow::Context,
    vertices: &SharedBuffer,
    indices: &SharedBuffer,
    instances: &SharedBuffer,
) -> Result<glow::VertexArray> {
    unsafe {
        let vao = gl.create_named_vertex_array().map_err(anyhow::Error::msg)?;
        gl.vertex_array_vertex_buffer(vao, 0, Some(vertices.buffer), 0, size_of::<Vertex>() as i32);
        gl.vertex_array_vertex_buffer(vao, 1, Some(instances.buffer), 0, size_of::<Instance>() as i32);
        gl.vertex_array_element_buffer(vao, Some(indices.buffer));
        // (location, binding, components, byte offset): position, normal, then the transform's rows.
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
        Ok(vao)
    }
}
// ANCHOR_END: vertex_array

/// One FBO over the three imported textures, plus a depth buffer only GL needs.
unsafe fn gbuffer_framebuffer(
    gl: &glow::Context,
    images: &[SharedImage],
    extent: vk::Extent2D,
) -> Result<(glow::Framebuffer, glow::Renderbuffer)> {
    unsafe {
        let depth = gl.create_renderbuffer().map_err(anyhow::Error::msg)?;
        gl.bind_renderbuffer(glow::RENDERBUFFER, Some(depth));
        gl.renderbuffer_storage(
            glow::RENDERBUFFER,
            glow::DEPTH_COMPONENT32F,
            extent.width as i32,
            extent.height as i32,
        );
        let fb = gl.create_named_framebuffer().map_err(anyhow::Error::msg)?;
        let mut draw_buffers = Vec::new();
        for (i, image) in images.iter().enumerate() {
            let attachment = glow::COLOR_ATTACHMENT0 + i as u32;
            gl.named_framebuffer_texture(Some(fb), attachment, Some(image.texture.texture), 0);
            draw_buffers.push(attachment);
        }
        gl.named_framebuffer_draw_buffers(Some(fb), &draw_buffers);
        gl.named_framebuffer_renderbuffer(Some(fb), glow::DEPTH_ATTACHMENT, glow::RENDERBUFFER, Some(depth));
        let status = gl.check_named_framebuffer_status(Some(fb), glow::FRAMEBUFFER);
        anyhow::ensure!(status == glow::FRAMEBUFFER_COMPLETE, "G-buffer framebuffer incomplete: {status:#x}");
        Ok((fb, depth))
    }
}

/// Acquire each image from GL (in TRANSFER_SRC, as GL's release promised), copy it into its
/// read-back buffer, and release it to GL again as a colour attachment.
unsafe fn record_copies(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    images: &[SharedImage],
    readbacks: &[HostBuffer],
) {
    let (external, ours) = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
    let barrier = |image: &SharedImage, old, new, src_access, dst_access, from, to| {
        vk::ImageMemoryBarrier::default()
            .image(image.image)
            .subresource_range(COLOR_RANGE)
            .old_layout(old)
            .new_layout(new)
            .src_access_mask(src_access)
            .dst_access_mask(dst_access)
            .src_queue_family_index(from)
            .dst_queue_family_index(to)
    };
    let src = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
    let acquire: Vec<_> = images
        .iter()
        .map(|i| barrier(i, src, src, vk::AccessFlags::NONE, vk::AccessFlags::TRANSFER_READ, external, ours))
        .collect();
    let release: Vec<_> = images
        .iter()
        .map(|i| {
            barrier(
                i,
                src,
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::AccessFlags::NONE,
                vk::AccessFlags::NONE,
                ours,
                external,
            )
        })
        .collect();
    let (top, transfer, bottom) = (
        vk::PipelineStageFlags::TOP_OF_PIPE,
        vk::PipelineStageFlags::TRANSFER,
        vk::PipelineStageFlags::BOTTOM_OF_PIPE,
    );
    let none = vk::DependencyFlags::empty();
    unsafe {
        vk.device.cmd_pipeline_barrier(cb, top, transfer, none, &[], &[], &acquire);
        for (image, readback) in images.iter().zip(readbacks) {
            let region = vk::BufferImageCopy::default()
                .image_subresource(
                    vk::ImageSubresourceLayers::default()
                        .aspect_mask(vk::ImageAspectFlags::COLOR)
                        .layer_count(1),
                )
                .image_extent(vk::Extent3D {
                    width: image.extent.width,
                    height: image.extent.height,
                    depth: 1,
                });
            vk.device.cmd_copy_image_to_buffer(cb, image.image, src, readback.buffer, &[region]);
        }
        vk.device.cmd_pipeline_barrier(cb, transfer, bottom, none, &[], &[], &release);
        let to_host = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::HOST_READ);
        vk.device.cmd_pipeline_barrier(
            cb,
            transfer,
            vk::PipelineStageFlags::HOST,
            none,
            &[to_host],
            &[],
            &[],
        );
    }
}

/// The G-buffers as Vulkan read them back, as floats.
struct GBufferPixels {
    position: Vec<[f32; 4]>,
    normal: Vec<[f32; 4]>,
}

impl GBufferPixels {
    fn from(readbacks: &[HostBuffer]) -> Self {
        let floats = |b: &HostBuffer| -> Vec<[f32; 4]> {
            b.bytes()
                .chunks_exact(16)
                .map(|p| std::array::from_fn(|i| f32::from_le_bytes(p[i * 4..i * 4 + 4].try_into().unwrap())))
                .collect()
        };
        GBufferPixels { position: floats(&readbacks[0]), normal: floats(&readbacks[1]) }
    }

    /// Positions mapped into the scene's bounds as colours; background black.
    fn position_picture(&self, scene: &Scene) -> Vec<u8> {
        let (low, high) = scene.bounds;
        let span = (high - low).max(glam::Vec3::splat(1e-9));
        self.position
            .iter()
            .flat_map(|p| match p[3] > 0.0 {
                true => {
                    let t = (glam::Vec3::new(p[0], p[1], p[2]) - low) / span;
                    [to_u8(t.x), to_u8(t.y), to_u8(t.z), 255]
                }
                false => [0, 0, 0, 255],
            })
            .collect()
    }

    /// Normals as colours, n * 0.5 + 0.5; background black.
    fn normal_picture(&self) -> Vec<u8> {
        self.normal
            .iter()
            .zip(&self.position)
            .flat_map(|(n, p)| match p[3] > 0.0 {
                true => [to_u8(n[0] * 0.5 + 0.5), to_u8(n[1] * 0.5 + 0.5), to_u8(n[2] * 0.5 + 0.5), 255],
                false => [0, 0, 0, 255],
            })
            .collect()
    }
}

fn to_u8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// What the G-buffers must hold, checked on the pixels Vulkan read.
fn check_gbuffers(report: &mut Report, seen: &GBufferPixels, camera: &Camera, scene: &Scene) {
    let covered: Vec<usize> = (0..seen.position.len()).filter(|&i| seen.position[i][3] > 0.0).collect();
    let fraction = covered.len() as f64 / seen.position.len() as f64;
    report.set("covered_fraction", (fraction * 1000.0).round() / 1000.0);
    report.check("scene_covers_part_of_the_image", fraction > 0.01 && fraction < 1.0);
    let unit = covered.iter().all(|&i| {
        let n = seen.normal[i];
        ((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-3
    });
    report.check("every_covered_pixel_has_a_unit_normal", unit);
    // w is the view depth of the xyz beside it: recompute it from the camera and compare.
    let forward = (camera.target - camera.eye).normalize();
    let tolerance = 1e-3 * scene.size();
    let depth_ok = covered.iter().all(|&i| {
        let p = seen.position[i];
        (forward.dot(glam::Vec3::new(p[0], p[1], p[2]) - camera.eye) - p[3]).abs() < tolerance
    });
    report.check("view_depth_matches_position", depth_ok);
    let inside = covered.iter().all(|&i| {
        let p = glam::Vec3::new(seen.position[i][0], seen.position[i][1], seen.position[i][2]);
        p.cmpge(scene.bounds.0 - tolerance).all() && p.cmple(scene.bounds.1 + tolerance).all()
    });
    report.check("positions_lie_in_the_scene_bounds", inside);
}

fn as_bytes<T: Copy>(items: &[T]) -> &[u8] {
    // SAFETY: Vertex, Instance and u32 are plain #[repr(C)] data without padding.
    unsafe { std::slice::from_raw_parts(items.as_ptr().cast(), std::mem::size_of_val(items)) }
}
