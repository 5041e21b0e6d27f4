//! Chapter 16: textured scenes, one texture in both APIs.
//!
//! Chapter 08's frame, with what a real scene is made of: pictures. Vulkan owns every texture:
//! it uploads each picture into an exportable image with its whole mip chain, made on the GPU by
//! blits, and GL imports the memory with as many levels and samples it trilinearly into the
//! G-buffers. Where a material's alpha cuts holes (a fence, leaves), GL discards the fragments
//! and the AO rays pass through the same holes: an any-hit shader reads the alpha of the very
//! image GL sampled. A scene without pictures draws exactly what chapter 08 draws.
//!
//! Run: `cargo run --release -p chapter-16-textures --bin 16-textures` (keys: 1-6 views, +/- rays,
//! [/] radius, B blur, P power, Esc quits; drag to orbit, wheel to zoom).

use anyhow::Result;
use ash::vk;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{GlPassTimer, PassTimes, read_after};
use common::frame::input::{Settings, resize_every, window_input};
use common::frame::{Composite, View, panel};
use common::instruments::census::ResizeCensus;
use common::interop::handoff::Apis;
use common::interop::{BufferPair, share_buffer};
use common::rt::RayTracedScene;
use common::rt::accel::{BlasLayout, TlasFlags};
use common::rt::ao::{AoArgs, AoRays, AoTracer, rays_this_frame};
use common::scene::gbuffer::{self, GBuffers};
use common::scene::{Camera, Normals};
use common::{Flags, RAY_TRACED_INTEROP, Report, Requirements, open_fd_count};
use glow::HasContext;
use std::process::ExitCode;

mod check;
mod cut_outs;
mod pass;
mod scene;
mod textures;

const CHAPTER: &str = "16-textures";
const SMALLEST: Smallest = Smallest::ANY;

/// Chapter 16: textured scenes: Vulkan uploads each picture with its mip chain, GL samples it,
/// the rays see its cut-outs.
#[derive(clap::Parser)]
struct Args {
    /// A textured OBJ file (its .mtl's map_Kd and map_d pictures: PNG, JPEG or TGA) instead of
    /// the chapter's own scene.
    #[arg(long)]
    scene: Option<std::path::PathBuf>,
    /// Normals for an OBJ file that has none.
    #[arg(long, value_enum, default_value = "smooth")]
    normals: Normals,
    /// Tetrahedra in the chapter's own scene (0 to 10000).
    #[arg(long, default_value_t = 40, value_parser = common::base::cli::number::<u32>(0..=10_000))]
    instances: u32,
    #[command(flatten)]
    ao: AoArgs,
    /// Blur radius in pixels (0 skips the blur).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=8))]
    blur: u32,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    view: View,
    /// Start this many times closer to the scene's centre than the framing puts the camera (as
    /// the mouse wheel does).
    #[arg(long, default_value_t = 1.0, value_parser = common::scene::parse_zoom, allow_negative_numbers = true)]
    zoom: f32,
    /// Headless: also write every debug view.
    #[arg(long)]
    all_views: bool,
    /// Headless: make every shared image anew at another size every K frames, as a window's
    /// resize does (the leak test uses it).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    resize_every: Option<u32>,
    /// Draw the scene without its pictures: every material its plain colour, as chapter 08 does
    /// (to time the textures against).
    #[arg(long)]
    untextured: bool,
    /// Rays treat every surface as opaque, so cut-outs shadow as solid quads (to time the any-hit
    /// shader against).
    #[arg(long)]
    opaque_rays: bool,
}

// ANCHOR: requirements
/// Chapter 08's needs, and an array of textures for the any-hit shader.
const TEXTURED: Requirements<'static> = Requirements { texture_arrays: true, ..RAY_TRACED_INTEROP };
// ANCHOR_END: requirements

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let mut size = args.common.size;

    // 1. Load the scene and its pictures, and mark the instances the rays must test
    let mut textured = match &args.scene {
        Some(path) => scene::load(path, args.normals)?,
        None => scene::default_scene(args.instances)?,
    };
    if args.untextured {
        textured.drop_pictures();
    }
    if !args.opaque_rays {
        cut_outs::mark_cut_outs(&mut textured);
    }
    report.set("cut_outs", textured.surfaces.iter().flatten().filter(|s| s.cut_out).count());
    let scene = &textured.scene;
    let mut camera = Camera::framing(scene.bounds, size.aspect());
    camera.orbit(0.0, 0.0, args.zoom, scene.bounds); // as chapter 08 places it
    let radius = args.ao.radius(scene)?;
    let mut settings = Settings {
        samples: args.ao.samples,
        radius,
        power: args.ao.power,
        blur: args.blur,
        view: args.view,
        overlays: false,
    };

    // 2. Vulkan, then GL (as chapter 08); the texture array only for a scene with cut-outs
    // ANCHOR: choose
    let requirements = if textured.has_cut_outs() { &TEXTURED } else { &RAY_TRACED_INTEROP };
    // ANCHOR_END: choose
    let (vk, mut window, gl_context, handoff) =
        gbuffer::contexts_in_window(CHAPTER, report, requirements, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;

    // 3. Chapter 08's shared scene and structures, and each textured mesh's texture coordinates
    let shared =
        RayTracedScene::with_layout(&vk, &gl_context, scene, TlasFlags::STATIC, BlasLayout::PerMesh)?;
    // ANCHOR: uvs
    // Read by GL's vertex arrays and, through their device addresses, by the any-hit shader.
    let usage = vk::BufferUsageFlags::VERTEX_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
    let uvs: Vec<Option<BufferPair>> = textured
        .uvs
        .iter()
        .map(|uv| {
            (!uv.is_empty())
                .then(|| share_buffer(&vk, &gl_context, bytemuck::cast_slice(uv), usage))
                .transpose()
        })
        .collect::<Result<_>>()?;
    // ANCHOR_END: uvs

    // 4. Every picture uploaded by Vulkan with its mip chain, and imported by GL
    // A mesh without a picture, in a scene with some, samples one white texel.
    let white = textured.surfaces.iter().any(Option::is_none).then_some(textured.pictures.len());
    let mut pictures = std::mem::take(&mut textured.pictures);
    if white.is_some() && !pictures.is_empty() {
        pictures.push(scene::Picture { name: "white".into(), width: 1, height: 1, rgba: vec![255; 4] });
    }
    let white = white.filter(|_| !pictures.is_empty());
    let uploaded = textures::upload(&vk, &gl_context, &handoff, &pictures)?;
    check::report_textures(report, &uploaded);
    let textures = &uploaded.textures;

    // 5. The G-buffers and the tracer: chapter 08's where nothing is cut out
    let storage = vk::ImageUsageFlags::STORAGE;
    let mut gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, size.extent(), storage)?;
    let pass =
        if pictures.is_empty() { None } else { Some(pass::TexturedPass::new(gl, &shared.buffers, &uvs)?) };
    let tlas = *shared.structures.tlas.handle;
    let (mut tracer, cut_out_objects) = if textured.has_cut_outs() {
        let with = (&textured, textures.as_slice(), uvs.as_slice());
        let (tracer, objects) = cut_outs::tracer(&vk, (&gl_context, &handoff), &shared, with, &gbuffers)?;
        (tracer, Some(objects))
    } else {
        (AoTracer::new(&vk, &gl_context, &shared.allocator, tlas, &gbuffers)?, None)
    };
    let mut composite = Composite::new(gl, &gbuffers, scene.bounds)?;

    // 6. Every frame: input, G-buffers (textured), rays (through the cut-outs), composite
    let frame_limit =
        if window.is_some() { args.common.window_frames() } else { args.common.headless_frames() };
    let (mut frame, mut resizes, mut census) = (0, 0, ResizeCensus::default());
    // Each pass's GPU time, as chapter 08 takes it: GL's queries read when they arrive, the
    // trace's timestamps after the fence wait the next trace makes anyway.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let timestamps = Timestamps::new(&vk)?;
    let mut trace_pending = false;
    // Made after everything the traces use: an early return drops it first, and its Drop waits.
    let commands = Commands::new(&vk)?;
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };
    let mut skipped = None;
    let views = View::ALL.map(|v| (v, v.name()));
    loop {
        let new_size;
        if let Some(window) = window.as_mut() {
            let before = (settings, camera.eye);
            let apply_key = |key: &_| {
                settings.apply_key(key, &View::ALL);
            };
            let Some(resized) =
                window_input(window, &gl_context, (&mut camera, scene.bounds), (size, 1), apply_key)
            else {
                break; // Esc, or the window closed
            };
            new_size = resized;
            let accumulated = tracer.accumulated.to_string();
            window.panel(|ui| {
                panel::settings(ui, &mut settings, &views, radius / 8.0..=radius * 8.0, false);
                panel::values(ui, &[("sync", handoff.name().into()), ("rays a pixel", accumulated.clone())]);
                panel::pass_times(ui, &times);
            });
            settings.overlays = false; // this chapter draws none
            if settings.radius != before.0.radius || camera.eye != before.1 {
                tracer.reset();
            }
            if frame_limit > 0 && frame >= frame_limit {
                break;
            }
        } else if frame >= frame_limit {
            break;
        } else {
            new_size = resize_every(args.resize_every, frame, args.common.size, 8);
        }
        if let Some(new) = new_size {
            // As chapter 08: every shared image at the new size, once the GPU is done with the old.
            unsafe { gl.finish() };
            commands.wait(&vk, "vkWaitForFences before a resize")?;
            size = new;
            let fresh = GBuffers::new(&vk, &gl_context, &handoff, &shared.buffers, size.extent(), storage)?;
            let old = std::mem::replace(&mut gbuffers, fresh);
            tracer.resize(&vk, &gl_context, &gbuffers)?;
            composite.resize(gl, &gbuffers)?;
            drop(old);
            resizes += 1;
            census.count(&gl_context)?;
        }
        // ANCHOR: frame
        gl_timer.time(gl, "gbuffer", || match &pass {
            Some(pass) => pass.draw(gl, &gbuffers, (&textured, textures, white), &camera),
            None => gbuffers.draw(gl, scene, &camera), // no pictures: chapter 08's pass
        })?;
        if let Some(reason) = common::rt::ao::nothing_to_trace(settings.samples, settings.radius) {
            if skipped.replace(reason).is_none() {
                eprintln!("ao: {reason}: visibility is 1 everywhere; no rays traced");
            }
            tracer.fill_unoccluded(&vk, &gl_context, &handoff)?;
        } else if tracer.accumulated < args.ao.max_samples {
            let refine = window.is_some();
            let samples = rays_this_frame(settings.samples, tracer.accumulated, args.ao.max_samples, refine);
            let rays =
                AoRays { samples, accumulated: 0, radius: settings.radius, scene_scale: scene.size() / 2.0 };
            if std::mem::take(&mut trace_pending) {
                read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
            }
            tracer.trace(apis, &gbuffers, rays, timestamps.as_ref())?; // textures travel with the G-buffers
            trace_pending = timestamps.is_some();
        }
        let uniforms = settings.uniforms(camera.far);
        gl_timer.time(gl, "composite", || composite.draw(gl, &gbuffers, &tracer, &uniforms))?;
        gl_timer.end_frame(gl, &mut times);
        // ANCHOR_END: frame
        if let Some(window) = &mut window {
            composite.show(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        times.frame_done();
        frame += 1;
    }
    if trace_pending {
        read_after(&vk, *commands.fence, timestamps.as_ref(), "ao_trace", &mut times)?;
    }
    gl_timer.finish(gl, &mut times);
    times.record(report);
    if resizes > 0 {
        report.set("resizes", resizes);
    }
    census.check(&gl_context, report)?;
    gl_context.check_error("the frame loop")?;

    // 7. Check: GL's levels against Vulkan's, the composite against the CPU, the occlusion
    if frame > 0 {
        let uniforms = settings.uniforms(camera.far);
        check::levels(report, gl, &uploaded);
        check::trilinear(report, gl, &uploaded, &check::Precision::of(&vk))?;
        check::frame(report, gl, (&gbuffers, &tracer, &composite), &uniforms);
        report.set("samples_per_pixel", tracer.accumulated);
        report.set("radius", settings.radius);
        report.set("frames", frame);
        if let Some(reason) = skipped {
            report.set("ao_skipped", reason);
        }
        if window.is_none() {
            let out_dir = args.common.out_dir(CHAPTER);
            let prefix = match args.scene.as_ref().and_then(|p| p.file_stem()) {
                Some(stem) => format!("{CHAPTER}-{}", stem.to_string_lossy()),
                None => CHAPTER.to_owned(),
            };
            let views = if args.all_views { View::ALL.to_vec() } else { vec![uniforms.view] };
            check::write_pictures(
                report,
                (gl, &gbuffers, &tracer, &composite),
                &uniforms,
                (CHAPTER, &out_dir, &prefix),
                &views,
            )?;
        }
    }
    common::interop::report_handoff(report, &handoff);

    // 8. Clean up, newest first
    unsafe { gl.finish() };
    vk.wait_idle()?;
    drop(commands);
    drop(timestamps);
    drop(gl_timer);
    drop(composite); // GL only
    drop(tracer); // the AO image, then the pipeline (its descriptors name the table and sampler)
    drop(cut_out_objects); // the cut-out table and the sampler
    drop(pass); // GL only: the vertex arrays, the program
    drop(gbuffers);
    drop(uploaded); // each texture: GL's side, then Vulkan's
    drop(uvs); // each texture-coordinate buffer, GL's side first
    drop(shared); // the structures, then the scene's buffers
    drop(handoff);
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
