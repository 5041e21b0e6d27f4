//! Chapter 05: G-buffers.
//!
//! Vulkan allocates the scene's buffers and three G-buffer images; GL imports them all, draws the
//! scene into the images (one instanced draw per mesh), and hands them back. Vulkan then reads
//! what GL wrote, which is exactly what its ray tracer will read in chapter 07.
//!
//! Run: `cargo run --release --bin 05-g-buffers` (or `-- --scene assets/bunny.obj`).

use anyhow::Result;
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::{Commands, HostBuffer, copy_image_to_buffer, transfers_to_host};
use common::clocks::timing::{GlPassTimer, PassTimes, VkPassTimer};
use common::instruments::census::ResizeCensus;
use common::instruments::output;
use common::interop::{acquire_from_gl, release_to_gl};
use common::scene::gbuffer::{self, GBUFFERS, GBuffer, GBuffers, SceneBuffers};
use common::scene::{Camera, Scene, SceneArgs};
use common::{Flags, INTEROP, Report, ms_since, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;
use std::time::Instant;

const CHAPTER: &str = "05-g-buffers";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 8,
    height: 8,
    why: "the scene must cover part of the picture and leave part of it empty",
    shape: Some((16.0, 16.0, "framed wider or taller, the scene covers too little or all of the picture")),
};

/// Chapter 05: GL rasterises G-buffers into Vulkan-owned images.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    scene: SceneArgs,
    /// Then make the G-buffers anew this many times, at other sizes, as a window's resize
    /// would, and check that nothing is left behind.
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=1000))]
    resizes: u32,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    // 1. Load the scene
    // ANCHOR: load
    let scene = args.scene.load()?;
    let camera = Camera::framing(scene.bounds, args.common.size.aspect());
    // ANCHOR_END: load
    let (meshes, instances, triangles) = (scene.meshes.len(), scene.instances.len(), scene.triangles());
    eprintln!("scene: {meshes} meshes, {instances} instances, {triangles} triangles");

    // 2. Create both contexts, and the hand-off between them
    // A size the device cannot hold the G-buffers at is refused here, before anything is allocated.
    let (vk, gl_context, handoff) = gbuffer::contexts(CHAPTER, report, &INTEROP, args.common.size)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;

    // 3. Share the scene's buffers
    // ANCHOR: share
    // Vulkan does nothing with them itself until chapter 06: no usage of its own.
    let buffers = SceneBuffers::share(&vk, &gl_context, &scene, vk::BufferUsageFlags::empty())?;
    // ANCHOR_END: share

    // 4. Share the G-buffer images, and make them GL's render targets
    // ANCHOR: gbuffers
    let extent = args.common.size.extent();
    // TRANSFER_SRC: this chapter copies them out. STORAGE: chapter 07's ray tracer reads them.
    let usage = vk::ImageUsageFlags::TRANSFER_SRC | vk::ImageUsageFlags::STORAGE;
    let mut gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &buffers, extent, usage)?;
    // ANCHOR_END: gbuffers

    // 5. Rasterise: one instanced draw per mesh
    let started = Instant::now();
    // Each pass's GPU time (common::clocks::timing): GL's raster, Vulkan's copies.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    gl_timer.time(gl, "raster", || gbuffers.draw(gl, &scene, &camera))?;
    gl_context.check_error("drawing the G-buffers")?;

    // 6. Hand the G-buffers to Vulkan, which copies them out
    let mut readbacks = Vec::new();
    for GBuffer { format, .. } in GBUFFERS {
        let bytes = (extent.width * extent.height * format.bytes_per_pixel) as u64;
        readbacks.push(HostBuffer::new(&vk, bytes, vk::BufferUsageFlags::TRANSFER_DST)?);
    }
    let mut vk_timer = VkPassTimer::new(&vk, 1)?;
    // Made after everything its submission uses, so that an early return drops it first (its
    // Drop waits for that submission).
    let commands = Commands::new(&vk)?;
    // ANCHOR: handover
    let textures = gbuffers.textures();
    // GL puts them in TRANSFER_SRC for Vulkan's copies; Vulkan gives them back as attachments
    // (GENERAL both ways on the host path, where GL moves no layout).
    let layouts =
        handoff.hand_over(vk::ImageLayout::TRANSFER_SRC_OPTIMAL, vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL);
    let (signal_layout, wait_layout) = layouts.gl(); // as GL names them
    handoff.gl_release(&gl_context, &textures, &[signal_layout; 3]);
    let cb = commands.begin(&vk)?;
    if let Some(t) = vk_timer.as_mut() {
        t.reset(&vk, cb);
    }
    // Whatever the hand-over layout, the copies read in TRANSFER_SRC: the acquire moves them there.
    let transfer_src = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
    let (acquire, release): (Vec<_>, Vec<_>) = gbuffers
        .images
        .iter()
        .map(|image| {
            let read = vk::AccessFlags::TRANSFER_READ;
            let none = vk::AccessFlags::NONE; // reads only: nothing to make available to GL
            (
                acquire_from_gl(&vk, image, layouts.to_vulkan, transfer_src, read),
                release_to_gl(&vk, image, transfer_src, layouts.to_gl, none),
            )
        })
        .unzip();
    let (transfer, bottom) = (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::BOTTOM_OF_PIPE);
    let none = vk::DependencyFlags::empty();
    // From TRANSFER, the stage the submission waits for GL at: the acquire comes after GL's signal.
    unsafe { vk.device.cmd_pipeline_barrier(cb, transfer, transfer, none, &[], &[], &acquire) };
    if let Some(t) = vk_timer.as_mut() {
        t.begin(&vk, cb, "copies"); // after the acquire: waiting for GL is not the copies' time
    }
    for (image, readback) in gbuffers.images.iter().zip(&readbacks) {
        copy_image_to_buffer(&vk, cb, *image.image, transfer_src, extent, *readback.buffer);
    }
    unsafe { vk.device.cmd_pipeline_barrier(cb, transfer, bottom, none, &[], &[], &release) };
    if let Some(t) = vk_timer.as_mut() {
        t.end(&vk, cb);
    }
    transfers_to_host(&vk, cb);
    let wait = handoff.vulkan_waits_on().map(|s| (s, transfer));
    commands.submit(&vk, wait, handoff.vulkan_signals())?;
    handoff.gl_acquire(&vk, &gl_context, *commands.fence, &textures, &[wait_layout; 3])?;
    // The CPU reads the copies next: wait for them (on the host path gl_acquire already did).
    commands.wait(&vk, "vkWaitForFences for the copies")?;
    // ANCHOR_END: handover
    report.time_ms("raster_and_handover_cpu", ms_since(started));
    gl_timer.finish(gl, &mut times);
    if let Some(t) = &vk_timer {
        t.read(&vk, &mut times)?;
    }
    times.record(report);

    // 7. Check what Vulkan sees, and write it out
    let seen = GBufferPixels { position: readbacks[0].rgba32f(), normal: readbacks[1].rgba32f() };
    check_gbuffers(report, &seen, &camera, &scene);
    let out = args.common.out_dir(CHAPTER);
    // Pictures of a loaded model carry its name: 05-g-buffers-bunny-albedo.png.
    let prefix = args.scene.picture_name(CHAPTER);
    // The albedo's background has alpha 0: make it opaque black, as in the other two pictures.
    let albedo: Vec<u8> =
        readbacks[2].bytes().chunks_exact(4).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
    let pictures =
        [("position", seen.position_picture(&scene)), ("normal", seen.normal_picture()), ("albedo", albedo)];
    for (name, pixels) in pictures {
        // GL drew with its bottom row first in memory: saved upright.
        let size = (extent.width, extent.height);
        output::save_gl_rgba8(report, &out, &format!("{prefix}-{name}"), size, &pixels)?;
    }
    report.set("draw_calls", meshes);
    report.set("instances", instances);
    report.set("triangles", triangles);
    report.set("bytes_shared", buffers.bytes() + gbuffers.images.iter().map(|i| i.memory.size).sum::<u64>());

    // 8. Resize: every shared image made anew, its GL twin too
    // ANCHOR: resize
    let mut census = ResizeCensus::default();
    for i in 0..args.resizes {
        let quarters = [2, 3, 4][i as usize % 3];
        let size = vk::Extent2D {
            width: (extent.width * quarters / 4).max(8),
            height: (extent.height * quarters / 4).max(8),
        };
        // Nothing may still use the old images: GL finishes, and Vulkan's last copy has (fence above).
        unsafe { gl.finish() };
        let new = GBuffers::new(&vk, &gl_context, &handoff, &buffers, size, usage)?;
        drop(std::mem::replace(&mut gbuffers, new)); // GL's objects, then each image, GL's side first
        gbuffers.draw(gl, &scene, &camera);
        census.count(&gl_context)?; // what exists after one resize must exist after every later one
    }
    census.check(&gl_context, report)?;
    // ANCHOR_END: resize

    common::interop::report_handoff(report, &handoff);
    // 9. Clean up, newest first
    // ANCHOR: cleanup
    // The wait before teardown (the book's "Waiting before teardown"): GL, then Vulkan, once.
    unsafe { gl.finish() };
    vk.wait_idle()?;
    drop(commands);
    drop(vk_timer);
    drop(readbacks); // unmapped, freed, destroyed
    drop(gl_timer);
    drop(gbuffers); // GL's framebuffer and program, then each image, GL's side first
    drop(buffers); // each buffer's GL side, then Vulkan's
    drop(handoff); // the semaphores, if any
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    Ok(())
}

/// The G-buffers as Vulkan read them back, as floats.
struct GBufferPixels {
    position: Vec<[f32; 4]>,
    normal: Vec<[f32; 4]>,
}

impl GBufferPixels {
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

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
