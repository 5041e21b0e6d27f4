//! Chapter 02: GL buffer import.
//!
//! Vulkan exports a vertex buffer (as in chapter 01); OpenGL imports the fd as a memory object,
//! makes a buffer whose storage *is* that memory, and draws a triangle straight from it. Then
//! each API writes bytes that the other reads, with no copy in between.
//!
//! Run: `cargo run --bin 02-gl-buffer-import` (writes out/02-gl-buffer-import/*.png).

use anyhow::Result;
use ash::vk;
use common::base::cli::Smallest;
use common::base::gl::{
    DEDICATED_MEMORY_OBJECT_EXT, GlContext, HANDLE_TYPE_OPAQUE_FD_EXT, MEMORY_EXTENSIONS, MemoryObject,
    RenderTarget, ensure_same_device, made, program, uuids_match,
};
use common::base::owned::create;
use common::instruments::fail;
use common::instruments::output;
use common::interop::exportable::{self, Dedicated, HANDLE_TYPE};
use common::{Flags, Report, Requirements, VulkanContext, ms_since, open_fd_count};
use glow::HasContext;
use std::ffi::CStr;
use std::os::fd::{AsRawFd, IntoRawFd};
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "02-gl-buffer-import";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 8,
    height: 8,
    why: "the pixels that hold the points it probes, (-0.6, -0.7) and (-0.6, 0.7), must have their \
          centres inside the triangle and outside it",
    shape: None,
};
const DEVICE_EXTENSIONS: &[&CStr] = &[ash::khr::external_memory_fd::NAME];

// ANCHOR: vertices
/// (x, y, u, v) per vertex, 16 bytes: the layout both APIs agree on.
type Triangle = [[f32; 4]; 3];
const TRIANGLE: Triangle = [[0.0, 0.8, 0.5, 0.0], [-0.8, -0.8, 0.0, 1.0], [0.8, -0.8, 1.0, 1.0]];
/// The same triangle upside down: what Vulkan writes once GL has drawn the first.
const FLIPPED: Triangle = [[0.0, -0.8, 0.5, 1.0], [-0.8, 0.8, 0.0, 0.0], [0.8, 0.8, 1.0, 0.0]];
const BUFFER_BYTES: u64 = std::mem::size_of::<Triangle>() as u64;
const STRIDE: i32 = 16;
// ANCHOR_END: vertices

const VERTEX_SHADER: &str = include_str!("../../shaders/gl/textured_triangle.vert");
const FRAGMENT_SHADER: &str = include_str!("../../shaders/gl/uv_colour.frag");
const CLEAR: [f32; 4] = [0.1, 0.1, 0.12, 1.0];

/// Chapter 02: OpenGL draws from a buffer whose memory Vulkan allocated.
#[derive(clap::Parser)]
struct Args {} // no flags of its own (chapter 01's `args.common` only)

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let (width, height) = (args.common.size.width, args.common.size.height);
    let out_dir = args.common.out_dir(CHAPTER);

    // 1. Create both contexts
    // ANCHOR: contexts
    let vk = VulkanContext::new(&Requirements { extensions: DEVICE_EXTENSIONS, ..Default::default() })?;
    let gl_context = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    // ANCHOR_END: contexts
    report.vulkan = Some(vk.report());
    report.gl = Some(gl_context.report());

    // 2. Check that both run on the same device
    // ANCHOR: uuids
    report.uuids_match = Some(uuids_match(&vk.info, &gl_context));
    ensure_same_device(&vk.info, &gl_context)?;
    // ANCHOR_END: uuids
    common::largest_size(&vk, &gl_context).check(CHAPTER, args.common.size)?;
    let open_fds_before = open_fd_count()?;

    // 3. Export a vertex buffer from Vulkan
    // ANCHOR: export
    let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE_TYPE);
    let buffer_info = vk::BufferCreateInfo::default()
        .size(BUFFER_BYTES)
        .usage(vk::BufferUsageFlags::VERTEX_BUFFER)
        .push_next(&mut external);
    // Each handle is owned as it is made (chapter 01): an early return destroys it.
    let buffer =
        create(&vk.device, "vkCreateBuffer", || unsafe { vk.device.create_buffer(&buffer_info, None) })?
            .counted("vk_buffer_exportable", 0); // for the report's list of resources
    let requirements = unsafe { vk.device.get_buffer_memory_requirements(*buffer) };
    let host_visible = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
    let memory = exportable::allocate(&vk, &requirements, host_visible, Dedicated::No)?;
    fail::call("vkBindBufferMemory", || unsafe { vk.device.bind_buffer_memory(*buffer, *memory.memory, 0) })?;
    // Mapped for the whole chapter: Vulkan's view of the bytes. (Freeing the memory unmaps it.)
    let mapped = fail::call("vkMapMemory", || unsafe {
        vk.device.map_memory(*memory.memory, 0, BUFFER_BYTES, vk::MemoryMapFlags::empty())
    })?
    .cast::<Triangle>();
    // SAFETY: `mapped` is BUFFER_BYTES of host-coherent memory that only this thread touches.
    unsafe { mapped.write_unaligned(TRIANGLE) };
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    let fd = exportable::export_fd(&fd_loader, *memory.memory)?;
    // ANCHOR_END: export

    // 4. Import it into GL
    // ANCHOR: import
    let started = Instant::now();
    let ext = gl_context.memory_fns()?; // GL_EXT_memory_object(_fd), loaded by hand: glow lacks them
    // GL's counterpart of VkDeviceMemory: a handle on an allocation, empty until the import.
    // Owned from the moment it exists (chapter 01's rule, for GL): any `?` below deletes it.
    let memory_object = common::base::gl::create(ext, "glCreateMemoryObjectsEXT", |ext| {
        let mut name = 0;
        unsafe { (ext.CreateMemoryObjectsEXT)(1, &mut name) };
        made(name, "glCreateMemoryObjectsEXT").map(MemoryObject)
    })?
    .counted("gl_memory_object", 0); // for the report (its bytes are Vulkan's allocation)
    if memory.dedicated {
        // Must say what Vulkan's allocation said, and before the import: GL cannot be told after.
        let yes = glow::TRUE as i32;
        unsafe { (ext.MemoryObjectParameterivEXT)(memory_object.0, DEDICATED_MEMORY_OBJECT_EXT, &yes) };
    }
    fail::step("glImportMemoryFdEXT")?;
    // An earlier call's error would be read below as the import's, and the fd then closed
    // although GL took it: look now, while the fd is still only ours.
    gl_context.check_error("a GL call before glImportMemoryFdEXT")?;
    // The size of the whole allocation (slack included), as Vulkan's own re-import stated it.
    let opaque_fd = HANDLE_TYPE_OPAQUE_FD_EXT; // the only fd type GL_EXT_memory_object_fd takes
    unsafe { (ext.ImportMemoryFdEXT)(memory_object.0, memory.size, opaque_fd, fd.as_raw_fd()) };
    // Some drivers list the extension yet fail the import: always look. On failure the `?`
    // drops `fd`, which closes it: a failed import did not take it.
    gl_context.check_error("glImportMemoryFdEXT")?;
    // SAFETY: the import succeeded, so the fd is GL's now; closing it too would be a double close.
    let _ = fd.into_raw_fd();

    // A GL buffer whose storage is the memory object: glNamedBufferStorage for storage that
    // already exists. Immutable, like any buffer with storage; offset 0, as in Vulkan.
    let what = "glCreateBuffers (imported)";
    let buffer_gl = common::base::gl::create(gl, what, |gl| unsafe { gl.create_named_buffer() })?
        .counted("gl_buffer_imported", 0);
    fail::step("glNamedBufferStorageMemEXT")?;
    unsafe { (ext.NamedBufferStorageMemEXT)(buffer_gl.0.get(), BUFFER_BYTES as isize, memory_object.0, 0) };
    gl_context.check_error("glNamedBufferStorageMemEXT")?;
    report.time_ms("import", ms_since(started));
    // ANCHOR_END: import

    // 5. Draw from it
    // ANCHOR: draw_setup
    let program = program(gl, VERTEX_SHADER, FRAGMENT_SHADER)?;
    // Owned as the memory object is, as every GL object made from here on is.
    let vertex_array =
        common::base::gl::create(gl, "glCreateVertexArrays", |gl| unsafe { gl.create_named_vertex_array() })?;
    unsafe {
        let vao = *vertex_array;
        // The imported buffer is an ordinary GL buffer now: bind it like any other.
        gl.vertex_array_vertex_buffer(vao, 0, Some(*buffer_gl), 0, STRIDE);
        for (location, offset) in [(0, 0), (1, 8)] {
            gl.enable_vertex_array_attrib(vao, location);
            gl.vertex_array_attrib_format_f32(vao, location, 2, glow::FLOAT, false, offset);
            gl.vertex_array_attrib_binding_f32(vao, location, 0);
        }
    }
    let target = RenderTarget::new(gl, width, height)?;
    // ANCHOR_END: draw_setup
    // The draw's GPU time (common::clocks::timing; the read-back waits for it anyway).
    let (mut gl_timer, mut times) =
        (common::clocks::timing::GlPassTimer::new(gl)?, common::clocks::timing::PassTimes::new());
    let mut draw = |name: &str, report: &mut Report| -> Result<Vec<u8>> {
        gl_timer.time(gl, "gl_draw", || unsafe {
            target.bind(gl);
            gl.clear_color(CLEAR[0], CLEAR[1], CLEAR[2], CLEAR[3]);
            gl.clear(glow::COLOR_BUFFER_BIT);
            gl.use_program(Some(*program));
            gl.bind_vertex_array(Some(*vertex_array));
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
        })?;
        gl_context.check_error("drawing from the imported buffer")?;
        let pixels = output::read_gl_rgba8(gl, width, height);
        output::save_rgba8(report, &out_dir, name, (width, height), &pixels)?;
        Ok(pixels)
    };
    let first = draw(CHAPTER, report)?;
    // Left of the base (bottom) is inside the triangle; the same spot mirrored to the top is not.
    let (bottom_left, centre) = pixel(&first, width, height, -0.6, -0.7);
    let (top_left, _) = pixel(&first, width, height, -0.6, 0.7);
    report.check("triangle_drawn_from_vulkan_memory", is_lit(bottom_left) && !is_lit(top_left));
    // uv (0.125, 0.9375) at (-0.6, -0.7); GL interpolated it at the centre of that pixel, and
    // the colour proves the uv attribute came through too.
    report.check("uv_attribute_read_correctly", close(bottom_left, uv_colour(centre)));

    // 6. Vulkan writes, GL reads
    // ANCHOR: vulkan_writes
    // A plain CPU store into Vulkan's mapping. No GL call touches the buffer before it draws again.
    unsafe { mapped.write_unaligned(FLIPPED) };
    let second = draw(&format!("{CHAPTER}-flipped"), report)?;
    let mut seen_by_gl = [0u8; BUFFER_BYTES as usize];
    unsafe {
        gl.bind_buffer(glow::COPY_READ_BUFFER, Some(*buffer_gl));
        gl.get_buffer_sub_data(glow::COPY_READ_BUFFER, 0, &mut seen_by_gl);
        gl.bind_buffer(glow::COPY_READ_BUFFER, None);
    }
    // ANCHOR_END: vulkan_writes
    report.check("gl_reads_what_vulkan_wrote", seen_by_gl == bytes_of(&FLIPPED));
    let flipped_ok = !is_lit(pixel(&second, width, height, -0.6, -0.7).0)
        && is_lit(pixel(&second, width, height, -0.6, 0.7).0);
    report.check("gl_draws_what_vulkan_wrote", flipped_ok);

    // 7. GL writes, Vulkan reads
    // ANCHOR: gl_writes
    unsafe { gl.named_buffer_sub_data_u8_slice(*buffer_gl, 0, &bytes_of(&TRIANGLE)) };
    // glFinish: the write has reached memory before the CPU looks (no semaphores yet: chapter 03).
    unsafe { gl.finish() };
    let seen_by_vulkan = unsafe { mapped.read_unaligned() };
    // ANCHOR_END: gl_writes
    report.check("vulkan_reads_what_gl_wrote", seen_by_vulkan == TRIANGLE);

    report.set("shared_bytes", memory.size);

    // 8. Clean up, newest first
    // ANCHOR: cleanup
    gl_timer.finish(gl, &mut times);
    times.record(report);
    // GL first: step 7's glFinish drained it, and Vulkan never submitted any work.
    drop(gl_timer); // its queries
    drop(target); // the framebuffer, then its renderbuffer
    drop(vertex_array);
    drop(program);
    drop(buffer_gl); // glDeleteBuffers
    drop(memory_object); // glDeleteMemoryObjectsEXT: releases the fd GL took over
    drop(buffer); // vkDestroyBuffer
    drop(memory); // vkFreeMemory, which unmaps it too
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    let open_fds_after = common::settled_fd_count(open_fds_before)?;
    eprintln!("open fds: {open_fds_before} before exporting, {open_fds_after} after cleaning up");
    report.check("no_fd_leaked", open_fds_after == open_fds_before);
    Ok(())
}

/// The pixel at normalised device coordinates (x, y), from an image whose top row comes first,
/// and the centre of that pixel in the same coordinates.
fn pixel(pixels: &[u8], width: u32, height: u32, x: f32, y: f32) -> ([u8; 4], [f32; 2]) {
    let column = ((((x + 1.0) / 2.0) * width as f32) as usize).min(width as usize - 1);
    let row = ((((1.0 - y) / 2.0) * height as f32) as usize).min(height as usize - 1);
    let at = (row * width as usize + column) * 4;
    let centre =
        [(column as f32 + 0.5) / width as f32 * 2.0 - 1.0, 1.0 - (row as f32 + 0.5) / height as f32 * 2.0];
    (pixels[at..at + 4].try_into().unwrap(), centre)
}

/// uv_colour.frag's colour, (u, v, 1 - v), at `p` inside TRIANGLE: u and v grow linearly
/// across it, from (0.5, 0) at the apex (0, 0.8) to (0, 1) and (1, 1) at the base's ends.
fn uv_colour(p: [f32; 2]) -> [u8; 3] {
    let (u, v) = ((p[0] + 0.8) / 1.6, (0.8 - p[1]) / 1.6);
    [u, v, 1.0 - v].map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)
}

fn is_lit(p: [u8; 4]) -> bool {
    !close(p, CLEAR.map(|c| (c * 255.0).round() as u8)[..3].try_into().unwrap())
}

/// Equal within the interpolation and rounding differences between drivers.
fn close(p: [u8; 4], rgb: [u8; 3]) -> bool {
    p.iter().zip(rgb).all(|(&a, b)| a.abs_diff(b) <= 12)
}

fn bytes_of(triangle: &Triangle) -> [u8; BUFFER_BYTES as usize] {
    // [[f32; 4]; 3] is plain data with no padding: bytemuck checks that, and the size, for us.
    bytemuck::cast(*triangle)
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
