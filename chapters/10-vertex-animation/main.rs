//! Chapter 10: vertex animation.
//!
//! A compute shader moves a finely tessellated sphere's vertices, and recomputes their normals,
//! in place in the vertex buffer GL draws and the BLAS is built from. Vulkan then refits the BLAS
//! around the moved triangles and updates the TLAS over it; GL rasterises the same buffer, and
//! the AO rays see the same surface. The report measures what refitting costs the rays. In a
//! window the wave runs on the wall clock; headless, at `--time` + frame x `--step`.
//!
//! Run: `cargo run --release --bin 10-vertex-animation` (keys: Space stops and starts the wave,
//! +/- rays, F10 the panel, Esc quits; drag to orbit, wheel to zoom).

use anyhow::Result;
use ash::vk;
use common::base::cli::AnimationArgs;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::base::window::Key;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{self, GlPassTimer, PassTimes};
use common::frame::input::window_input;
use common::frame::panel;
use common::frame::playback::{self, Playback};
use common::frame::{Composite, Uniforms};
use common::instruments::output;
use common::interop::handoff::Apis;
use common::rt::accel::{self, AccelerationStructure, BuildInputs, InPlace, Refresh};
use common::rt::ao::{AoArgs, AoRays, AoTracer, rays_this_frame};
use common::scene::gbuffer::{self, GBuffers, SceneBuffers};
use common::scene::{Camera, Instance, Scene, ground_plane};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glam::{Mat4, Vec3};
use glow::HasContext;
use std::process::ExitCode;

mod sphere;
use sphere::{Animation, Step, VertexHandoff, Wave, WavePipeline, record_animation};

const CHAPTER: &str = "10-vertex-animation";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 48,
    height: 48,
    why: "1% of the pixels must change between the first and the last frame: the wave must cover enough of \
          them",
    shape: Some((
        1.5,
        2.0,
        "framed wider or taller, the sphere covers too few pixels for 1% of the picture to change",
    )),
};

/// Chapter 10: a compute shader moves vertices; the BLAS is refitted, the TLAS updated.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    ao: AoArgs,
    /// Bands of latitude of the sphere (twice as many of longitude).
    #[arg(long, default_value_t = 128, value_parser = common::base::cli::number::<u32>(4..=2048))]
    rings: u32,
    /// The wave's height, as a fraction of the sphere's radius (0 to 0.3).
    #[arg(long, default_value_t = 0.06, value_parser = common::base::cli::number::<f32>(0.0..=0.3), allow_negative_numbers = true)]
    amplitude: f32,
    #[command(flatten)]
    animation: AnimationArgs,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    // 1. Make the sphere, hovering over the ground
    let mesh = sphere::uv_sphere(args.rings, 2 * args.rings);
    let directions: Vec<Vec3> = mesh.vertices.iter().map(|v| Vec3::from(v.normal)).collect();
    let count = mesh.vertices.len() as u32;
    let ground = Instance::new(Mat4::from_scale(Vec3::new(0.2, 1.0, 0.2)), [200, 200, 200]);
    let lift = Mat4::from_translation(Vec3::new(0.0, 1.0 + args.amplitude + 0.1, 0.0));
    let instances = vec![ground, Instance::new(lift, [90, 150, 230])];
    let scene = Scene::new(vec![ground_plane(), mesh], instances, vec![0..1, 1..2])?;
    let mut size = args.common.size;
    let mut camera = Camera::framing(scene.bounds, size.aspect());
    let radius = args.ao.radius_to_trace(&scene)?;
    report.set("vertices", count);
    report.set("triangles", scene.triangles());

    // 2. Both contexts (GL in a window when there is a display); the scene shared with GL, and
    // writable by compute
    let (vk, mut window, gl_context, handoff) =
        gbuffer::contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    // ANCHOR: share
    // STORAGE_BUFFER: the compute shader writes the vertices in place.
    let usage = vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
        | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS
        | vk::BufferUsageFlags::STORAGE_BUFFER;
    let buffers = SceneBuffers::share(&vk, &gl_context, &scene, usage)?;
    // The sphere's vertex buffer goes from Vulkan's compute shader to GL's vertex fetch and
    // back every frame, with semaphores of its own where the images have theirs.
    let vertices = VertexHandoff::new(&vk, &gl_context, &handoff, *buffers.meshes[1][0].gl.buffer)?;
    // ANCHOR_END: share

    // 3. The structures: the ground's BLAS, the sphere's refittable one, an updatable TLAS
    accel::check_limits(&vk, &scene)?;
    let allocator = accel::allocator(&vk)?;
    let loader = ash::khr::acceleration_structure::Device::new(&vk.instance, &vk.device);
    // ANCHOR: structures
    use vk::BuildAccelerationStructureFlagsKHR as Flags;
    let bottom = vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL;
    // The ground never changes: built once, for tracing. The sphere changes every frame: built
    // for a fast build (and refit), with ALLOW_UPDATE.
    let blas_flags = [Flags::PREFER_FAST_TRACE, Flags::PREFER_FAST_BUILD | Flags::ALLOW_UPDATE];
    let mut blases = Vec::new();
    for ((mesh, [vertices, indices]), flags) in scene.meshes.iter().zip(&buffers.meshes).zip(blas_flags) {
        let geometry = accel::triangles_geometry(&vk, mesh, &vertices.vk, &indices.vk);
        let triangles = mesh.indices.len() as u32 / 3;
        let bytes = accel::structure_size(&loader, bottom, flags, &geometry, triangles);
        let blas = AccelerationStructure::new(&vk, &allocator, bottom, flags, bytes)?;
        let inputs = BuildInputs { handle: *blas.handle, ty: bottom, flags, geometry, primitives: triangles };
        let in_place = InPlace::new(&vk, &allocator, &loader, inputs)?;
        accel::set_blas_address(&buffers.instances.vk, blases.len(), blas.address);
        blases.push((blas, in_place));
    }
    let top = vk::AccelerationStructureTypeKHR::TOP_LEVEL;
    let tlas_flags = accel::TlasFlags::UPDATABLE.0;
    let geometry = accel::instances_geometry(&vk, &buffers.instances.vk);
    let bytes = accel::structure_size(&loader, top, tlas_flags, &geometry, 2);
    let tlas = AccelerationStructure::new(&vk, &allocator, top, tlas_flags, bytes)?;
    let inputs = BuildInputs { handle: *tlas.handle, ty: top, flags: tlas_flags, geometry, primitives: 2 };
    let tlas_in_place = InPlace::new(&vk, &allocator, &loader, inputs)?;
    // ANCHOR_END: structures

    // 4. The compute pipeline, the rest directions, the G-buffers, the tracer, the composite
    let pipeline = WavePipeline::new(&vk)?;
    let rest = sphere::rest_directions(&vk, &allocator, &directions)?;
    let mut wave = Wave {
        vertices: buffers.meshes[1][0].vk.device_address(&vk),
        directions: rest.address,
        axis: Vec3::new(0.3, 1.0, 0.2).normalize().into(),
        count,
        time: args.animation.time,
        amplitude: args.amplitude,
        frequency: 14.0,
        speed: 4.0,
    };
    let storage = vk::ImageUsageFlags::STORAGE;
    let mut gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &buffers, size.extent(), storage)?;
    let mut tracer = AoTracer::new(&vk, &gl_context, &allocator, *tlas.handle, &gbuffers)?;
    let mut composite = Composite::new(gl, &gbuffers, scene.bounds)?;
    let uniforms = Uniforms::final_picture(args.ao.power, camera.far);
    let animation_timer = Timestamps::with_count(&vk, 4)?;
    let trace_timer = Timestamps::new(&vk)?;
    // Made after everything their submissions use: an early return drops them first, and each
    // one's Drop waits for its last submission before any of that is destroyed.
    let (commands, animation) = (Commands::new(&vk)?, Commands::new(&vk)?);
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };

    // 5. Every frame: the window's input, move the vertices, refit, update, draw, trace, composite
    let frame_limit =
        if window.is_some() { args.common.window_frames() } else { args.common.headless_frames() };
    let scene_scale = scene.size() / 2.0;
    // Each pass's GPU time (common::clocks::timing), read once its fence has signalled for the next
    // frame's submission on it, which waits anyway: timing adds no wait.
    let (mut gl_timer, mut times) = (GlPassTimer::new(gl)?, PassTimes::new());
    let (mut animated, mut traced) = (None, false);
    let (mut blas_refits, mut blas_rebuilds) = (0u32, 0u32);
    let mut pictures = Vec::new();
    let vertex_buffer = *buffers.meshes[1][0].vk.buffer;
    // What a frame's animation work uses; the wave is the frame's, and GL may have the vertices.
    let parts = |wave| Animation {
        loader: &loader,
        vertices: vertex_buffer,
        vertices_from_gl: vertices.with_gl(),
        pipeline: &pipeline,
        wave,
        blases: &blases,
        tlas: &tlas_in_place,
    };
    // In a window the wave runs on the wall clock, unless Space (or `--step 0`) stopped it.
    let mut playback = Playback::new(args.animation.step, args.ao.samples);
    let (mut traced_at, mut frame) = (None, 0);
    loop {
        if let Some(window) = window.as_mut() {
            let eye = camera.eye;
            let keys = |key: &Key| playback.key(key);
            let Some(resized) =
                window_input(window, &gl_context, (&mut camera, scene.bounds), (size, 1), keys)
            else {
                break; // Esc, or the window closed
            };
            let values = [
                ("sync", handoff.name().to_owned()),
                ("vertices", count.to_string()),
                ("time", format!("{:.2} s", wave.time)),
                ("BLAS refits", blas_refits.to_string()),
                ("rays a pixel", tracer.accumulated.to_string()),
            ];
            window.panel(|ui| {
                playback.controls(ui, []);
                panel::values(ui, &values);
                panel::pass_times(ui, &times);
            });
            if frame_limit > 0 && frame >= frame_limit {
                break;
            }
            playback.advance(&mut wave.time);
            if camera.eye != eye {
                tracer.reset(); // the mean is of what the pixels showed from where the camera was
            }
            if let Some(new) = resized {
                size = new; // every image anew, as chapter 08 resizes
                let frame_parts = (&mut gbuffers, &mut tracer, &mut composite);
                playback::resize(apis, (&buffers, storage), frame_parts, size)?;
            }
        } else if frame >= frame_limit {
            break;
        } else {
            wave.time = args.animation.at(frame);
        }
        // ANCHOR: frame
        // The first frame builds everything; later ones refit (or rebuild, by the policy).
        let step = match (frame, args.animation.rebuild_every) {
            (0, _) => Step::First,
            (f, k) if k > 0 && f % k == 0 => Step::Next(Refresh::Rebuild),
            _ => Step::Next(Refresh::Update),
        };
        let cb = animation.begin(&vk)?;
        if let (Some(done), Some(timer)) = (animated.take(), &animation_timer) {
            sphere::add_times(&vk, timer, done, &mut times)?;
        }
        record_animation(&vk, cb, &parts(wave), step, animation_timer.as_ref());
        // Vulkan writes the vertices once GL's last draw has fetched them; GL fetches them again
        // once they are written.
        animation.submit(&vk, vertices.to_vulkan(&gl_context), vertices.vulkan_signals())?;
        vertices.to_gl(&vk, &gl_context, *animation.fence)?;
        gl_timer.time(gl, "gbuffer", || gbuffers.draw(gl, &scene, &camera))?;
        if traced_at.replace(wave.time).is_some_and(|before| before != wave.time) {
            tracer.reset(); // the surface moved: the running mean is of a picture that is gone
        }
        if std::mem::take(&mut traced) {
            timing::read_after(&vk, *commands.fence, trace_timer.as_ref(), "ao_trace", &mut times)?;
        }
        // A window refines: one ray a pixel while the wave runs, more once it stands still (and
        // none once a still wave has `--max-samples`).
        let samples =
            rays_this_frame(playback.samples, tracer.accumulated, args.ao.max_samples, window.is_some());
        if samples > 0 {
            let rays = AoRays { samples, accumulated: 0, radius, scene_scale };
            tracer.trace(apis, &gbuffers, rays, trace_timer.as_ref())?;
        }
        gl_timer.time(gl, "composite", || composite.draw(gl, &gbuffers, &tracer, &uniforms))?;
        gl_timer.end_frame(gl, &mut times);
        // ANCHOR_END: frame
        if let Some(window) = &mut window {
            window.show_times(|| times.line());
            composite.show(gl, window.size());
            window.swap_buffers(&gl_context)?;
        }
        times.frame_done();
        // Frame 0 builds everything: its time is not a refresh.
        let refreshed = match step {
            Step::First => None,
            Step::Next(refresh) => Some(refresh),
        };
        match refreshed {
            Some(Refresh::Update) => blas_refits += 1,
            Some(Refresh::Rebuild) => blas_rebuilds += 1,
            None => {}
        }
        (animated, traced) = (refreshed, samples > 0);
        if window.is_none() && (frame == 0 || frame + 1 == frame_limit || args.animation.every_frame) {
            pictures.push((frame, output::flip_rows(&composite.read(gl), size.width, size.height)));
        }
        frame += 1;
    }
    animation.wait(&vk, "vkWaitForFences for the last animation")?;
    if let (Some(done), Some(timer)) = (animated, &animation_timer) {
        sphere::add_times(&vk, timer, done, &mut times)?;
    }
    if traced {
        timing::read_after(&vk, *commands.fence, trace_timer.as_ref(), "ao_trace", &mut times)?;
    }
    gl_timer.finish(gl, &mut times);
    gl_context.check_error("the frame loop")?;
    report.set("frames", frame);
    report.set("samples_per_pixel", tracer.accumulated);
    report.set("blas_refits", blas_refits);
    report.set("blas_rebuilds", blas_rebuilds);
    report.set("tlas_updates", frame.saturating_sub(1));
    report.set("rebuild_policy", sphere::policy(args.animation.rebuild_every));
    report.set("workgroup_size", sphere::WORKGROUP);

    // 6. Check the vertices, the occlusion, the motion; write the frames
    commands.wait(&vk, "vkWaitForFences before the checks")?;
    let moved = &buffers.meshes[1][0].vk;
    // SAFETY: `count` vertices of the coherent mapping; the GPU is done with them (fence above).
    let bytes = count as usize * size_of::<common::scene::Vertex>();
    let gpu: &[common::scene::Vertex] =
        bytemuck::cast_slice(unsafe { std::slice::from_raw_parts(moved.mapped, bytes) });
    report.check("vertices_match_cpu_reference", sphere::vertices_match(&wave, &directions, gpu));
    let (w, h) = (size.width, size.height);
    common::rt::ao::check_occlusion(report, gl, &gbuffers, &tracer);
    if window.is_some() {
        playback.report(report); // the motion not judged, the rays a frame the keys left
    } else {
        let moved = frame > 1 && args.animation.step > 0.0; // then the frames must show it
        output::save_frames(report, &args.common.out_dir(CHAPTER), CHAPTER, (w, h), &pictures, moved)?;
    }

    // 7. Measure: the same rays through the refitted BLAS, then through a rebuilt one
    // ANCHOR: measure
    let rays = AoRays { samples: args.ao.samples, accumulated: 0, radius, scene_scale };
    gbuffers.draw(gl, &scene, &camera);
    let (after_refits, refitted_ms) = tracer.trace_once(apis, &gbuffers, rays, trace_timer.as_ref())?;
    // The same time again (the vertices do not move), with the BLAS rebuilt.
    let cb = animation.begin(&vk)?;
    record_animation(&vk, cb, &parts(wave), Step::Next(Refresh::Rebuild), animation_timer.as_ref());
    animation.submit(&vk, vertices.to_vulkan(&gl_context), vertices.vulkan_signals())?;
    vertices.to_gl(&vk, &gl_context, *animation.fence)?;
    gbuffers.draw(gl, &scene, &camera);
    let (after_rebuild, rebuilt_ms) = tracer.trace_once(apis, &gbuffers, rays, trace_timer.as_ref())?;
    let differing = after_refits.iter().zip(&after_rebuild).filter(|(a, b)| a != b).count();
    report.set("pixels_differing_refitted_vs_rebuilt", differing);
    report.check("refitted_blas_traces_like_a_rebuilt_one", differing * 1000 <= (w * h) as usize);
    // ANCHOR_END: measure
    if let Some(a) = &animation_timer {
        sphere::add_times(&vk, a, Refresh::Rebuild, &mut times)?;
    }
    times.record(report);
    let said = ["trace after refits", "after a rebuild"];
    AoTracer::report_traces(report, "refits", said, (refitted_ms, rebuilt_ms));

    common::interop::report_handoff(report, &handoff);
    // 8. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once, for the animation and the traces
    drop((animation, commands));
    drop(gl_timer);
    drop((trace_timer, animation_timer));
    drop(composite);
    drop(tracer); // the AO image (GL's side, then Vulkan's), then the pipeline
    drop(gbuffers);
    drop(rest); // the buffer, then its memory, back to the allocator
    drop(pipeline);
    drop(tlas_in_place); // its scratch buffer
    drop(tlas); // before the BLASes it refers to
    drop(blases); // each BLAS, then its scratch buffer
    // (Each allocation held a handle to `allocator`, which frees its memory blocks with the
    // last one, at the end of `run`: before the device, never by hand.)
    drop(vertices); // its two semaphores, if any: GL's side first
    drop(buffers); // each GL side, then Vulkan's
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    if let Some(window) = &window {
        window.report_panel(report);
    }
    drop(window);
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
