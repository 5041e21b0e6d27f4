//! Chapter 04: compute triangle.
//!
//! NVIDIA's gl_vk_simple_interop, in Rust. Every frame a Vulkan compute shader writes an animated
//! image and OpenGL draws a triangle textured with it. Both the image and the triangle's vertex
//! buffer are Vulkan memory that GL imported; the CPU moves the triangle by writing through
//! Vulkan's mapping, and chapter 03's `Handoff` orders the two APIs. In a window, `+` and `-` double
//! and halve the image, which recreates it (and leaks nothing); Esc quits.
//!
//! Run: `cargo run --bin 04-compute-triangle` (a window; `--headless` writes out/04-compute-triangle/*.png).

mod check;
mod compute;

use anyhow::{Result, bail};
use ash::vk;
use check::Checks;
use common::base::cli::{Size, Smallest};
use common::base::commands::Commands;
use common::base::gl::{GlContext, MEMORY_EXTENSIONS, RenderTarget, layout};
use common::base::window::{self, Key, NamedKey, Window};
use common::clocks::timestamps::Timestamps;
use common::instruments::output;
use common::interop;
use common::interop::handoff::Handoff;
use common::{Flags, INTEROP, Report, VulkanContext, ms_since, open_fd_count};
use compute::{ComputePipeline, Previous, share_image};
use glow::HasContext;
use std::f32::consts::{FRAC_PI_2, TAU};
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "04-compute-triangle";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 16,
    height: 16,
    why: "it compares the pixels at the triangle's centre and halfway to each corner with the computed \
          image, and needs 1% of the pixels to change between frames",
    shape: None,
};
const VERTEX_SHADER: &str = include_str!("../../shaders/gl/textured_triangle.vert");
const FRAGMENT_SHADER: &str = include_str!("../../shaders/gl/textured_triangle.frag");
const CLEAR: [f32; 4] = [0.1, 0.1, 0.12, 1.0];

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
    /// Animation time of the first frame, in seconds (frame k shows T + k/60) [default: real
    /// time in a window; 0 headless, where frames may come far faster than 60 a second].
    #[arg(long, value_name = "T", value_parser = common::base::cli::number::<f32>(-1e5..=1e5), allow_negative_numbers = true)]
    time: Option<f32>,
    /// Every K frames, make the compute image anew at full, half, then quarter size (a leak test).
    #[arg(long, value_name = "K", value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    resize_every: Option<u32>,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let size = args.common.size;
    let windowed = !args.common.headless && window::display_available();
    if !args.common.headless && !windowed {
        eprintln!("no display (DISPLAY and WAYLAND_DISPLAY are unset): running headless");
    }
    // 0 frames: until the window is closed.
    let frames = if windowed { args.common.window_frames() } else { args.common.headless_frames() };
    if let Some(k) = args.resize_every
        && frames != 0
        && frames <= 3 * k
    {
        bail!("--resize-every {k} needs more than {} --frames: one whole cycle of sizes", 3 * k);
    }

    // 1. Create both contexts, in a window or headless
    // ANCHOR: contexts
    // Chapter 03's: memory fds, and semaphore fds where there are (without them, the host waits).
    let vk = VulkanContext::new(&INTEROP)?;
    let (mut window, gl_context) = match windowed {
        true => Window::open(CHAPTER, size, &MEMORY_EXTENSIONS).map(|(w, gl)| (Some(w), gl))?,
        false => (None, GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?),
    };
    let gl = &gl_context.gl;
    // ANCHOR_END: contexts
    common::connect(report, &vk, &gl_context)?;
    common::largest_size(&vk, &gl_context).check(CHAPTER, args.common.size)?;
    report.set("window", windowed);
    let open_fds_before = open_fd_count()?;
    let handoff = Handoff::new(&vk, &gl_context)?;
    let timestamps = Timestamps::new(&vk)?;

    // 2. Share the vertex buffer
    // ANCHOR: vertex_buffer
    // Chapter 02's buffer, SLOTS triangles long. Its contents are written before each use.
    let zeros = [0; (SLOTS * TRIANGLE_BYTES) as usize];
    let usage = vk::BufferUsageFlags::VERTEX_BUFFER;
    let interop::BufferPair { gl: vertices_gl, vk: vertices_vk } =
        interop::share_buffer(&vk, &gl_context, &zeros, usage)?;
    // Vulkan's mapping: the CPU writes the triangle here, GL draws from the same bytes.
    let mapped = vertices_vk.mapped.cast::<Triangle>();
    // ANCHOR_END: vertex_buffer

    // 3. Build the compute pipeline
    let compute = ComputePipeline::new(&vk)?;

    // 4. Share the image it writes
    let mut extent = vk::Extent2D { width: size.width, height: size.height };
    let mut image = share_image(&vk, &gl_context, compute.set, extent)?;
    // A new image has never been GL's: there is nothing to hand over yet (step 8).
    let mut previous = Previous::Nobody;
    let largest = common::largest_size(&vk, &gl_context);
    let largest = largest.width.min(largest.height); // where '+' stops

    // 5. Prepare GL's draw
    let program = common::base::gl::program(gl, VERTEX_SHADER, FRAGMENT_SHADER)?;
    let vertex_array =
        common::base::gl::create(gl, "glCreateVertexArrays", |gl| unsafe { gl.create_named_vertex_array() })?;
    for (location, offset) in [(0, 0), (1, 8)] {
        unsafe {
            gl.enable_vertex_array_attrib(*vertex_array, location);
            gl.vertex_array_attrib_format_f32(*vertex_array, location, 2, glow::FLOAT, false, offset);
            gl.vertex_array_attrib_binding_f32(*vertex_array, location, 0);
        }
    }
    let target = match window {
        Some(_) => None, // the window's own back buffer
        None => Some(RenderTarget::new(gl, size.width, size.height)?),
    };

    let out_dir = args.common.out_dir(CHAPTER);
    let started = Instant::now();
    let (mut checks, mut gl_timer) = (Checks::new(CLEAR), common::clocks::timing::GlPassTimer::new(gl)?);
    // Made after everything its submissions use: an early return drops it first, and its Drop
    // waits for the last submission before the image or the pipeline it used is destroyed.
    let commands = Commands::new(&vk)?;
    let mut resizes = 0;
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
                commands.wait(&vk, "vkWaitForFences before a resize")?;
            }
            // The new image first: if the device cannot make it, a window keeps the old one
            // (share_image points the descriptor at an image only once it exists).
            match share_image(&vk, &gl_context, compute.set, wanted) {
                Ok(new) => drop(std::mem::replace(&mut image, new)), // GL's side, then Vulkan's
                Err(error) if window.is_some() => {
                    eprintln!(
                        "compute image: cannot make {}x{} ({error:#}); keeping",
                        wanted.width, wanted.height
                    );
                    wanted = extent;
                }
                Err(error) => return Err(error),
            }
            if wanted != extent {
                (extent, previous, resizes) = (wanted, Previous::Nobody, resizes + 1);
                eprintln!("compute image: {}x{}", extent.width, extent.height);
            }
            if resizes == 3 && args.resize_every.is_some() {
                checks.census.count(&gl_context)?; // back at full size, after a whole cycle
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
            checks.times.add("compute_gpu", t.read_ms(&vk)?);
        }
        let slot = frame as u64 % SLOTS;
        let triangle = triangle_at(time);
        // SAFETY: slot < SLOTS copies are mapped, and neither API reads this one now (above).
        unsafe { mapped.add(slot as usize).write(triangle) };
        // ANCHOR_END: animate

        // 8. GL hands the image to Vulkan, which computes
        // ANCHOR: compute
        let texture = [*image.texture.texture];
        // GL names the layout its release leaves the image in; Vulkan's barrier starts from the same.
        let handed = if previous == Previous::Gl { 1 } else { 0 };
        handoff.gl_release(&gl_context, &texture[..handed], &[layout::SHADER_READ_ONLY][..handed]);
        if let Some(t) = &timestamps {
            t.reset(&vk, cb);
        }
        compute.record(&vk, cb, (&image, previous), time, timestamps.as_ref());
        // Wait for GL at the compute stage: nothing before the dispatch touches the image.
        let wait = handoff.vulkan_waits_on().map(|s| (s, vk::PipelineStageFlags::COMPUTE_SHADER));
        commands.submit(&vk, wait, handoff.vulkan_signals())?;
        // ANCHOR_END: compute

        // 9. Vulkan hands the image back; GL draws
        // ANCHOR: draw
        // SHADER_READ_ONLY: where Vulkan's release barrier left it. GL must be told the same.
        handoff.gl_acquire(&vk, &gl_context, *commands.fence, &texture, &[layout::SHADER_READ_ONLY])?;
        previous = Previous::Gl;
        let (width, height) = window.as_ref().map_or((size.width, size.height), |w| w.size());
        gl_timer.time(gl, "gl_draw", || unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, target.as_ref().map(|t| *t.framebuffer));
            gl.viewport(0, 0, width as i32, height as i32);
            gl.clear_color(CLEAR[0], CLEAR[1], CLEAR[2], CLEAR[3]);
            gl.clear(glow::COLOR_BUFFER_BIT);
            gl.use_program(Some(*program));
            // This frame's copy of the triangle: an offset inside GL's buffer, not the memory object.
            let offset = (slot * TRIANGLE_BYTES) as i32;
            gl.vertex_array_vertex_buffer(*vertex_array, 0, Some(*vertices_gl.buffer), offset, STRIDE);
            gl.bind_vertex_array(Some(*vertex_array));
            gl.bind_texture_unit(0, Some(*image.texture.texture)); // `binding = 0` in the shader
            gl.draw_arrays(glow::TRIANGLES, 0, 3);
        })?;
        gl_timer.end_frame(gl, &mut checks.times);
        // ANCHOR_END: draw
        gl_context.check_error("drawing the triangle")?;

        // 10. Check the frame (a window's before it is shown)
        let last = frames != 0 && frame + 1 == frames;
        if (window.is_none() || frame == 0 || last) && width > 0 && height > 0 {
            let pixels = output::read_gl_rgba8(gl, width, height);
            let name = if frames == 1 { CHAPTER.to_owned() } else { format!("{CHAPTER}-frame{frame}") };
            output::save_rgba8(report, &out_dir, &name, (width, height), &pixels)?;
            let unfit = SMALLEST.unfit(Size { width, height }); // a window's may be any size
            checks.frame(pixels, (width, height), &triangle, extent, (time, unfit));
        }
        if let Some(window) = &mut window {
            window.show_times(|| checks.times.line());
            window.swap_buffers(&gl_context)?;
        }
        checks.times.add("frame_cpu", ms_since(frame_started));
        frame += 1;
    }
    commands.wait(&vk, "vkWaitForFences after the last frame")?;
    if frame > 0
        && let Some(t) = &timestamps
    {
        checks.times.add("compute_gpu", t.read_ms(&vk)?); // the last frame's
    }
    gl_timer.finish(gl, &mut checks.times);
    checks.report(report, &gl_context)?;
    report.set("frames", frame);
    report.set("resizes", resizes);
    report.set("compute_image", [extent.width, extent.height]);

    common::interop::report_handoff(report, &handoff);
    // 11. Clean up, newest first, once both APIs are idle
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once, as the book's "Waiting before teardown" says
    drop(commands); // the fence, the command pool (and its buffer)
    drop(gl_timer);
    drop(target);
    drop(vertex_array);
    drop(program);
    drop(image); // GL's texture and memory object, then view, image, memory
    drop(compute); // the descriptor pool (and its set), the pipeline, its layouts
    drop(vertices_gl); // GL's buffer and memory object
    drop(vertices_vk); // then Vulkan's buffer and memory
    drop(timestamps);
    drop(handoff); // the semaphores, GL's side first
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

fn scale(extent: vk::Extent2D, side: impl Fn(u32) -> u32) -> vk::Extent2D {
    vk::Extent2D { width: side(extent.width), height: side(extent.height) }
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
