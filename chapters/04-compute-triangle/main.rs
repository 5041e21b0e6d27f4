//! Chapter 04: compute triangle.
//!
//! NVIDIA's gl_vk_simple_interop, in Rust. Every frame a Vulkan compute shader writes an animated
//! image and OpenGL draws a triangle textured with it. Both the image and the triangle's vertex
//! buffer are Vulkan memory that GL imported; the CPU moves the triangle by writing through
//! Vulkan's mapping, and chapter 03's `Sync` orders the two APIs. In a window, `+` and `-` double
//! and halve the image, which recreates it (and leaks nothing); Esc quits.
//!
//! Run: `cargo run --bin 04-compute-triangle` (a window; `--headless` writes out/04-compute-triangle/*.png).

mod check;

use anyhow::{Context as _, Result, bail};
use ash::vk;
use common::commands::{Commands, Timestamps, first_use, median_p95};
use common::gl::{GlContext, MEMORY_EXTENSIONS, RenderTarget, layout};
use common::interop::{self, SharedImage, acquire_from_gl, release_to_gl};
use common::sync::{SEMAPHORE_EXTENSION, Sync};
use common::window::{self, Key, NamedKey, Window};
use common::{CommonArgs, Report, Requirements, VulkanContext, ms_since, open_fd_count, output};
use glow::HasContext;
use std::f32::consts::{FRAC_PI_2, TAU};
use std::ffi::CStr;
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "04-compute-triangle";
const REQUIRED: &[&CStr] = &[ash::khr::external_memory_fd::NAME];
/// Without it the chapter still runs, synchronising on the host.
const OPTIONAL: &[&CStr] = &[SEMAPHORE_EXTENSION];
const COMPUTE_SPIRV: &[u8] = include_bytes!("../../shaders/compute_triangle.comp.spv");
const VERTEX_SHADER: &str = include_str!("../../shaders/gl/textured_triangle.vert");
const FRAGMENT_SHADER: &str = include_str!("../../shaders/gl/textured_triangle.frag");
const CLEAR: [f32; 4] = [0.1, 0.1, 0.12, 1.0];

// ANCHOR: interface
/// The compute shader's push constants (`Push` in compute_triangle.comp).
#[repr(C)]
struct Push {
    time: f32,
}
const _: () = assert!(size_of::<Push>() == 4);
/// `local_size_x` and `local_size_y` in compute_triangle.comp.
const WORKGROUP: u32 = 16;
// ANCHOR_END: interface

// ANCHOR: vertices
/// (x, y, u, v) per vertex, as in chapter 02: a 16-byte stride.
type Triangle = [[f32; 4]; 3];
const TRIANGLE_BYTES: u64 = size_of::<Triangle>() as u64;
const STRIDE: i32 = 16;
/// Copies of the triangle in the shared buffer. Frames write them in turn, so the CPU never
/// writes the copy that GL may still be drawing from (see step 7).
const SLOTS: u64 = 2;

/// The triangle at `time` seconds: it turns and breathes about the centre of the screen, which it
/// always covers (the reference animated its vertices with sin and cos of time too).
fn triangle_at(time: f32) -> Triangle {
    let radius = 0.75 + 0.1 * (2.0 * time).sin();
    let corner = |k: f32, u: f32, v: f32| {
        let angle = FRAC_PI_2 + 0.5 * time + k * TAU / 3.0;
        [radius * angle.cos(), radius * angle.sin(), u, v]
    };
    [corner(0.0, 0.5, 0.0), corner(1.0, 0.0, 1.0), corner(2.0, 1.0, 1.0)]
}
// ANCHOR_END: vertices

/// Chapter 04: a Vulkan compute shader animates the image an OpenGL triangle shows.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// Animation time of the first frame, in seconds (frame k shows T + k/60) [default: real
    /// time in a window; 0 headless, where frames may come far faster than 60 a second].
    #[arg(long, value_name = "T")]
    time: Option<f32>,
    /// Every K frames, make the compute image anew at full, half, then quarter size (a leak test).
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u32).range(1..))]
    resize_every: Option<u32>,
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, |args: &Args| &args.common, run)
}

// ANCHOR: share_image
/// The compute shader's output: a storage image that GL samples as a texture. Writes it into
/// the descriptor set, so a resize is this call again.
fn share_image(
    vk: &VulkanContext,
    gl: &GlContext,
    set: vk::DescriptorSet,
    extent: vk::Extent2D,
) -> Result<SharedImage> {
    // STORAGE: the compute shader's imageStore. SAMPLED: GL's texture().
    let usage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
    let image = SharedImage::new(vk, gl, vk::Format::R8G8B8A8_UNORM, glow::RGBA8, usage, extent)?;
    let texture = image.texture.texture;
    for (parameter, value) in [
        (glow::TEXTURE_MIN_FILTER, glow::LINEAR), // one mip level: no mipmap filter
        (glow::TEXTURE_MAG_FILTER, glow::LINEAR),
        (glow::TEXTURE_WRAP_S, glow::CLAMP_TO_EDGE),
        (glow::TEXTURE_WRAP_T, glow::CLAMP_TO_EDGE),
    ] {
        unsafe { gl.gl.texture_parameter_i32(texture, parameter, value as i32) };
    }
    // GENERAL: the only layout in which a shader may write a storage image.
    let info =
        [vk::DescriptorImageInfo::default().image_view(image.view).image_layout(vk::ImageLayout::GENERAL)];
    let write = vk::WriteDescriptorSet::default()
        .dst_set(set)
        .dst_binding(0)
        .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
        .image_info(&info);
    unsafe { vk.device.update_descriptor_sets(&[write], &[]) };
    Ok(image)
}
// ANCHOR_END: share_image

fn run(args: &Args, report: &mut Report) -> Result<()> {
    let size = args.common.size;
    let windowed = !args.common.headless && window::display_available();
    if !args.common.headless && !windowed {
        eprintln!("no display (DISPLAY and WAYLAND_DISPLAY are unset): running headless");
    }
    // 0 frames: until the window is closed.
    let frames = args.common.frame_count(windowed);
    if let Some(k) = args.resize_every
        && frames != 0
        && frames <= 3 * k
    {
        bail!("--resize-every {k} needs more than {} --frames: one whole cycle of sizes", 3 * k);
    }

    // 1. Create both contexts, in a window or headless
    // ANCHOR: contexts
    let vk = VulkanContext::new(&Requirements {
        extensions: REQUIRED,
        optional_extensions: OPTIONAL,
        ..Default::default()
    })?;
    let (mut window, gl_context) = match windowed {
        true => Window::open(CHAPTER, size, &MEMORY_EXTENSIONS).map(|(w, gl)| (Some(w), gl))?,
        false => (None, GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?),
    };
    let gl = &gl_context.gl;
    // ANCHOR_END: contexts
    common::connect(report, &vk, &gl_context)?;
    report.set("window", windowed);
    let open_fds_before = open_fd_count()?;
    let sync = Sync::new(&vk, &gl_context)?;
    report.sync = Some(sync.name());
    let commands = Commands::new(&vk)?;
    let timestamps = Timestamps::new(&vk)?;

    // 2. Share the vertex buffer
    // ANCHOR: vertex_buffer
    // Chapter 02's buffer, SLOTS triangles long. Its contents are written before each use.
    let zeros = [0; (SLOTS * TRIANGLE_BYTES) as usize];
    let usage = vk::BufferUsageFlags::VERTEX_BUFFER;
    let (vertices_vk, vertices_gl) = interop::share_buffer(&vk, &gl_context, &zeros, usage)?;
    // Vulkan's mapping: the CPU writes the triangle here, GL draws from the same bytes.
    let mapped = vertices_vk.mapped.cast::<Triangle>();
    // ANCHOR_END: vertex_buffer

    // 3. Build the compute pipeline
    // ANCHOR: pipeline
    let device = &vk.device;
    let compute = vk::ShaderStageFlags::COMPUTE;
    let bindings = [vk::DescriptorSetLayoutBinding::default()
        .binding(0) // `binding = 0` in the shader: the image it writes
        .descriptor_type(vk::DescriptorType::STORAGE_IMAGE)
        .descriptor_count(1)
        .stage_flags(compute)];
    let set_layout_info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
    let set_layout = unsafe { device.create_descriptor_set_layout(&set_layout_info, None) }?;
    let push_range = [vk::PushConstantRange::default().stage_flags(compute).size(size_of::<Push>() as u32)];
    let set_layouts = [set_layout];
    let layout_info =
        vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts).push_constant_ranges(&push_range);
    let pipeline_layout = unsafe { device.create_pipeline_layout(&layout_info, None) }?;
    // read_spv copies the bytes into u32 words: include_bytes! promises no 4-byte alignment.
    let code = ash::util::read_spv(&mut std::io::Cursor::new(COMPUTE_SPIRV)).context("reading the SPIR-V")?;
    let module =
        unsafe { device.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None) }?;
    let stage = vk::PipelineShaderStageCreateInfo::default().stage(compute).module(module).name(c"main");
    let pipeline_info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(pipeline_layout);
    let pipeline =
        unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &[pipeline_info], None) }
            .map_err(|(_, e)| e)
            .context("vkCreateComputePipelines")?[0];
    common::resources::created("vk_pipeline: compute", 0); // for the report's list of resources
    unsafe { device.destroy_shader_module(module, None) }; // the pipeline keeps what it needs
    let pool_sizes = [vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_IMAGE, descriptor_count: 1 }];
    let pool_info = vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&pool_sizes);
    let descriptor_pool = unsafe { device.create_descriptor_pool(&pool_info, None) }?;
    let allocate =
        vk::DescriptorSetAllocateInfo::default().descriptor_pool(descriptor_pool).set_layouts(&set_layouts);
    let set = unsafe { device.allocate_descriptor_sets(&allocate) }?[0];
    // ANCHOR_END: pipeline

    // 4. Share the image it writes
    let mut extent = vk::Extent2D { width: size.width, height: size.height };
    let mut image = share_image(&vk, &gl_context, set, extent)?;
    // A new image has never been GL's: there is nothing to hand over yet (step 8).
    let mut image_is_new = true;
    let largest = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }
        .limits
        .max_image_dimension2_d;

    // 5. Prepare GL's draw
    let program = common::gl::program(gl, VERTEX_SHADER, FRAGMENT_SHADER)?;
    let vertex_array = unsafe {
        let vao = gl.create_named_vertex_array().map_err(anyhow::Error::msg)?;
        for (location, offset) in [(0, 0), (1, 8)] {
            gl.enable_vertex_array_attrib(vao, location);
            gl.vertex_array_attrib_format_f32(vao, location, 2, glow::FLOAT, false, offset);
            gl.vertex_array_attrib_binding_f32(vao, location, 0);
        }
        vao
    };
    let target = match window {
        Some(_) => None, // the window's own back buffer
        None => Some(RenderTarget::new(gl, size.width, size.height)?),
    };

    let out_dir = args.common.out_dir(CHAPTER);
    let started = Instant::now();
    let (mut gpu_ms, mut frame_ms) = (Vec::new(), Vec::new());
    let (mut centre_lit, mut shows_image) = (true, true);
    let (mut first_seen, mut last_seen) = (None, None);
    let (mut resizes, mut fds_after_cycle) = (0, None);
    let mut frame = 0;
    while frames == 0 || frame < frames {
        let frame_started = Instant::now();
        // Headless, frame k shows k/60 s: a fast GPU draws frames microseconds apart, and real
        // time would barely move between them.
        let first = args.time.or((!windowed).then_some(0.0));
        let time = first.map_or(started.elapsed().as_secs_f32(), |t| t + frame as f32 / 60.0);

        // 6. Resize the image: on a key, or every K frames
        let mut wanted = extent;
        if let Some(window) = window.as_mut() {
            let mut quit = false;
            for key in window.poll(&gl_context) {
                match key.as_ref() {
                    Key::Named(NamedKey::Escape) => quit = true,
                    Key::Character("+" | "=") => wanted = scale(extent, |side| (side * 2).min(largest)),
                    Key::Character("-") => wanted = scale(extent, |side| (side / 2).max(1)),
                    _ => {}
                }
            }
            if quit || window.close_requested() {
                break;
            }
        }
        if let Some(k) = args.resize_every
            && frame > 0
            && frame % k == 0
        {
            wanted = scale(vk::Extent2D { width: size.width, height: size.height }, |side| {
                (side >> (frame / k % 3)).max(1)
            });
        }
        // ANCHOR: resize
        if wanted != extent {
            // The old image may still be in use: by GL's last draw and by Vulkan's last dispatch.
            // Wait for both (a resize is rare; no frame waits like this), then destroy it, GL's
            // side first, and make the new one. The reference skipped the wait and leaked.
            unsafe {
                gl.finish();
                device.wait_for_fences(&[commands.fence], true, u64::MAX)?;
            }
            image.destroy(&vk, &gl_context);
            image = share_image(&vk, &gl_context, set, wanted)?;
            (extent, image_is_new, resizes) = (wanted, true, resizes + 1);
            eprintln!("compute image: {}x{}", extent.width, extent.height);
            if resizes == 3 && args.resize_every.is_some() {
                fds_after_cycle = Some(open_fd_count()?); // back at full size
            }
        }
        // ANCHOR_END: resize

        // 7. Move the triangle
        // ANCHOR: animate
        // `begin` waits for the last frame's Vulkan work, which waited for GL's signal after the
        // frame before it: GL has finished drawing from the copy written two frames ago. Write that one.
        let cb = commands.begin(&vk)?;
        if frame > 0
            && let Some(t) = &timestamps
        {
            gpu_ms.push(t.read_ms(&vk)?);
        }
        let slot = frame as u64 % SLOTS;
        let triangle = triangle_at(time);
        // SAFETY: slot < SLOTS copies are mapped, and neither API reads this one now (above).
        unsafe { mapped.add(slot as usize).write(triangle) };
        // ANCHOR_END: animate

        // 8. GL hands the image to Vulkan, which computes
        // ANCHOR: compute
        let texture = [image.texture.texture];
        // GL names the layout its release leaves the image in; Vulkan's barrier starts from the same.
        let handed = if image_is_new { 0 } else { 1 };
        sync.gl_release(&gl_context, &texture[..handed], &[layout::SHADER_READ_ONLY][..handed]);
        if let Some(t) = &timestamps {
            t.reset(&vk, cb);
        }
        record_compute(
            &vk,
            cb,
            pipeline,
            pipeline_layout,
            set,
            &image,
            image_is_new,
            time,
            timestamps.as_ref(),
        );
        // Wait for GL at the compute stage: nothing before the dispatch touches the image.
        let wait = sync.vulkan_waits_on().map(|s| (s, vk::PipelineStageFlags::COMPUTE_SHADER));
        commands.submit(&vk, wait, sync.vulkan_signals())?;
        // ANCHOR_END: compute

        // 9. Vulkan hands the image back; GL draws
        // ANCHOR: draw
        // SHADER_READ_ONLY: where Vulkan's release barrier left it. GL must be told the same.
        sync.gl_acquire(&vk, &gl_context, commands.fence, &texture, &[layout::SHADER_READ_ONLY])?;
        image_is_new = false;
        let (width, height) = window.as_ref().map_or((size.width, size.height), |w| w.size());
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, target.as_ref().map(|t| t.framebuffer));
            gl.viewport(0, 0, width as i32, height as i32);
            gl.clear_color(CLEAR[0], CLEAR[1], CLEAR[2], CLEAR[3]);
            gl.clear(glow::COLOR_BUFFER_BIT);
            gl.use_program(Some(program));
            // This frame's copy of the triangle: an offset inside GL's buffer, not the memory object.
            let offset = (slot * TRIANGLE_BYTES) as i32;
            gl.vertex_array_vertex_buffer(vertex_array, 0, Some(vertices_gl.buffer), offset, STRIDE);
            gl.bind_vertex_array(Some(vertex_array));
            gl.bind_texture_unit(0, Some(image.texture.texture)); // `binding = 0` in the shader
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
        }
        // ANCHOR_END: draw
        gl_context.check_error("drawing the triangle")?;

        // 10. Check the frame (a window's before it is shown)
        let last = frames != 0 && frame + 1 == frames;
        if (window.is_none() || frame == 0 || last) && width > 0 && height > 0 {
            let pixels = output::read_gl_rgba8(gl, width, height);
            let name = if frames == 1 { CHAPTER.to_owned() } else { format!("{CHAPTER}-frame{frame}") };
            output::save_rgba8(report, &out_dir, &name, width, height, &pixels)?;
            centre_lit &= check::is_lit(check::pixel(&pixels, width, height, [0.0, 0.0]));
            shows_image &= check::shows_compute_image(&pixels, width, height, &triangle, extent, time);
            match first_seen {
                None => first_seen = Some(pixels),
                Some(_) => last_seen = Some(pixels),
            }
        }
        if let Some(window) = &window {
            window.swap_buffers(&gl_context)?;
        }
        frame_ms.push(ms_since(frame_started));
        frame += 1;
    }
    unsafe { device.wait_for_fences(&[commands.fence], true, u64::MAX) }?;
    if frame > 0
        && let Some(t) = &timestamps
    {
        gpu_ms.push(t.read_ms(&vk)?); // the last frame's
    }

    report.check("centre_pixel_inside_triangle", centre_lit);
    report.check("triangle_shows_computed_image", shows_image);
    if let (Some(first), Some(last)) = (&first_seen, &last_seen) {
        report.check("frames_differ_over_time", check::differ(first, last));
    }
    if args.resize_every.is_some() {
        let at_end = open_fd_count()?;
        report.check("no_fd_growth_across_resizes", fds_after_cycle == Some(at_end));
        report.set("fds", serde_json::json!({ "after_first_cycle": fds_after_cycle, "at_end": at_end }));
    }
    for (name, samples) in [("compute_gpu", &gpu_ms), ("frame_cpu", &frame_ms)] {
        let (median, p95) = median_p95(samples);
        report.time_ms(&format!("{name}_median"), median);
        report.time_ms(&format!("{name}_p95"), p95);
    }
    report.set("frames", frame);
    report.set("resizes", resizes);
    report.set("compute_image", [extent.width, extent.height]);

    // 11. Clean up, newest first, once both APIs are idle
    // ANCHOR: cleanup
    unsafe {
        gl.finish();
        device.device_wait_idle()?;
    }
    if let Some(target) = target {
        target.delete(gl);
    }
    unsafe {
        gl.delete_vertex_array(vertex_array);
        gl.delete_program(program);
    }
    image.destroy(&vk, &gl_context); // GL's texture and memory object, then view, memory, image
    unsafe {
        device.destroy_descriptor_pool(descriptor_pool, None); // and the set allocated from it
        device.destroy_pipeline(pipeline, None);
        device.destroy_pipeline_layout(pipeline_layout, None);
        device.destroy_descriptor_set_layout(set_layout, None);
    }
    vertices_gl.delete(&gl_context); // GL's buffer and memory object, then Vulkan's
    vertices_vk.destroy(&vk);
    if let Some(t) = timestamps {
        t.destroy(&vk);
    }
    commands.destroy(&vk);
    sync.destroy(&vk, &gl_context);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", open_fd_count()? == open_fds_before);
    Ok(())
}

// ANCHOR: record_compute
/// Takes the image from GL, runs the compute shader over it, and gives it back.
#[allow(clippy::too_many_arguments)]
fn record_compute(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    pipeline: vk::Pipeline,
    pipeline_layout: vk::PipelineLayout,
    set: vk::DescriptorSet,
    image: &SharedImage,
    image_is_new: bool,
    time: f32,
    timestamps: Option<&Timestamps>,
) {
    let (compute, none) = (vk::PipelineStageFlags::COMPUTE_SHADER, vk::DependencyFlags::empty());
    let (read_only, general) = (vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL, vk::ImageLayout::GENERAL);
    let device = &vk.device;
    let acquire = if image_is_new {
        // Nothing to take over: UNDEFINED says the old contents may go, and the shader writes
        // every pixel anyway. No ownership transfer: Vulkan's first use claims it.
        first_use(image.image, general, vk::AccessFlags::SHADER_WRITE)
    } else {
        // Acquire from GL: ownership moves from outside Vulkan (QUEUE_FAMILY_EXTERNAL) to our
        // queue family, and the image from the layout GL released it in to GENERAL, the layout
        // imageStore needs. No source access: GL only sampled it, and its semaphore (or glFinish)
        // already ordered that before us. Destination: the shader's writes.
        acquire_from_gl(vk, image, read_only, general, vk::AccessFlags::SHADER_WRITE)
    };
    let extent = image.extent;
    let push = Push { time };
    unsafe {
        // Source stage COMPUTE_SHADER: the stage the submission waits for GL at, so this barrier
        // (and its layout change) happens after GL's release. Destination: the dispatch below.
        device.cmd_pipeline_barrier(cb, compute, compute, none, &[], &[], &[acquire]);
        if let Some(t) = timestamps {
            t.start(vk, cb, compute); // after the wait for GL: time the dispatch, not the wait
        }
        device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, pipeline);
        device.cmd_bind_descriptor_sets(cb, vk::PipelineBindPoint::COMPUTE, pipeline_layout, 0, &[set], &[]);
        device.cmd_push_constants(
            cb,
            pipeline_layout,
            vk::ShaderStageFlags::COMPUTE,
            0,
            &push.time.to_ne_bytes(),
        );
        // One invocation per pixel, in whole 16x16 workgroups; the shader skips the overhang.
        device.cmd_dispatch(cb, extent.width.div_ceil(WORKGROUP), extent.height.div_ceil(WORKGROUP), 1);
        // Release to GL: make the shader's writes available (source COMPUTE_SHADER, SHADER_WRITE),
        // move to SHADER_READ_ONLY_OPTIMAL, the layout GL's acquire will name, and hand ownership
        // back outside Vulkan. Destination: nothing more in this submission (BOTTOM_OF_PIPE, no
        // access); the semaphore signal (or fence) that ends it carries the rest to GL.
        let release = release_to_gl(vk, image, general, read_only, vk::AccessFlags::SHADER_WRITE);
        device.cmd_pipeline_barrier(
            cb,
            compute,
            vk::PipelineStageFlags::BOTTOM_OF_PIPE,
            none,
            &[],
            &[],
            &[release],
        );
        if let Some(t) = timestamps {
            t.end(vk, cb);
        }
    }
}
// ANCHOR_END: record_compute

fn scale(extent: vk::Extent2D, side: impl Fn(u32) -> u32) -> vk::Extent2D {
    vk::Extent2D { width: side(extent.width), height: side(extent.height) }
}
