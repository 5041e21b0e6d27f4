//! Chapter 10: vertex animation.
//!
//! A compute shader moves a finely tessellated sphere's vertices, and recomputes their normals,
//! in place in the vertex buffer GL draws and the BLAS is built from. Vulkan then refits the BLAS
//! around the moved triangles and updates the TLAS over it; GL rasterises the same buffer, and
//! the AO rays see the same surface. The report measures what refitting costs the rays.
//!
//! Run: `cargo run --release --bin 10-vertex-animation -- --frames 60`.

use anyhow::{Result, ensure};
use ash::vk;
use common::base::cli::AnimationArgs;
use common::base::cli::Smallest;
use common::base::commands::Commands;
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::{self, GlPassTimer, PassTimes};
use common::frame::{Composite, Uniforms};
use common::instruments::output;
use common::interop::handoff::Apis;
use common::rt::accel::{
    self, AccelerationStructure, BufferDesc, BuildInputs, DeviceBuffer, InPlace, Refresh,
};
use common::rt::ao::{AoArgs, AoRays, AoTracer};
use common::scene::gbuffer::{self, GBuffers, SceneBuffers};
use common::scene::{Camera, Instance, Scene, ground_plane};
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use glam::{Mat4, Vec3};
use glow::HasContext;
use gpu_allocator::MemoryLocation;
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
    ensure!(
        (0.0..=0.3).contains(&args.amplitude),
        "--amplitude {}: choose between 0 and 0.3",
        args.amplitude
    );

    // 1. Make the sphere, hovering over the ground
    let mesh = sphere::uv_sphere(args.rings, 2 * args.rings);
    let directions: Vec<Vec3> = mesh.vertices.iter().map(|v| Vec3::from(v.normal)).collect();
    let count = mesh.vertices.len() as u32;
    let ground = Instance::new(Mat4::from_scale(Vec3::new(0.2, 1.0, 0.2)), [200, 200, 200]);
    let lift = Mat4::from_translation(Vec3::new(0.0, 1.0 + args.amplitude + 0.1, 0.0));
    let instances = vec![ground, Instance::new(lift, [90, 150, 230])];
    let scene = Scene::new(vec![ground_plane(), mesh], instances, vec![0..1, 1..2])?;
    let camera = Camera::framing(scene.bounds, args.common.size.aspect());
    let radius = args.ao.radius_to_trace(&scene)?;
    report.set("vertices", count);
    report.set("triangles", scene.triangles());

    // 2. Both contexts; the scene shared with GL, and writable by compute
    let (vk, gl_context, handoff) =
        gbuffer::contexts(CHAPTER, report, &RAY_TRACED_INTEROP, args.common.size)?;
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
    // 16 bytes a direction (w unused), not 12: with a 12-byte stride, GPU-assisted validation on
    // the NVIDIA GPU reported the last direction's read as out of bounds of the buffer.
    let rest_directions: Vec<[f32; 4]> = directions.iter().map(|d| d.extend(0.0).to_array()).collect();
    let rest_bytes = (rest_directions.len() * size_of::<[f32; 4]>()) as u64;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let mut rest = DeviceBuffer::new(
        &vk,
        &allocator,
        BufferDesc {
            name: "rest directions",
            size: rest_bytes,
            usage: storage,
            location: MemoryLocation::CpuToGpu,
        },
    )?;
    let mapped = rest.allocation.mapped_slice_mut().expect("CpuToGpu memory is mapped");
    mapped[..rest_bytes as usize].copy_from_slice(bytemuck::cast_slice(&rest_directions));
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
    let extent = args.common.size.extent();
    let gbuffers = GBuffers::new(&vk, &gl_context, &handoff, &buffers, extent, vk::ImageUsageFlags::STORAGE)?;
    let mut tracer = AoTracer::new(&vk, &gl_context, &allocator, *tlas.handle, &gbuffers)?;
    let composite = Composite::new(gl, &gbuffers, scene.bounds)?;
    let uniforms = Uniforms::final_picture(args.ao.power, camera.far);
    let animation_timer = Timestamps::with_count(&vk, 4)?;
    let trace_timer = Timestamps::new(&vk)?;
    // Made after everything their submissions use: an early return drops them first, and each
    // one's Drop waits for its last submission before any of that is destroyed.
    let (commands, animation) = (Commands::new(&vk)?, Commands::new(&vk)?);
    let apis = Apis { vk: &vk, gl: &gl_context, handoff: &handoff, commands: &commands };

    // 5. Every frame: move the vertices, refit, update, draw, trace, composite
    let frames = args.common.headless_frames();
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
    for frame in 0..frames {
        // ANCHOR: frame
        wave.time = args.animation.at(frame);
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
        if args.animation.step > 0.0 {
            tracer.reset(); // the surface moved: the running mean is of a picture that is gone
        }
        let rays =
            AoRays { samples: args.ao.samples, accumulated: 0, radius, scene_scale: scene.size() / 2.0 };
        if std::mem::take(&mut traced) {
            timing::read_after(&vk, *commands.fence, trace_timer.as_ref(), "ao_trace", &mut times)?;
        }
        tracer.trace(apis, &gbuffers, rays, trace_timer.as_ref())?;
        gl_timer.time(gl, "composite", || composite.draw(gl, &gbuffers, &tracer, &uniforms))?;
        gl_timer.end_frame(gl, &mut times);
        times.frame_done();
        // ANCHOR_END: frame
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
        (animated, traced) = (refreshed, true);
        if frame == 0 || frame + 1 == frames || args.animation.every_frame {
            pictures.push((frame, output::flip_rows(&composite.read(gl), extent.width, extent.height)));
        }
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
    report.set("frames", frames);
    report.set("blas_refits", blas_refits);
    report.set("blas_rebuilds", blas_rebuilds);
    report.set("tlas_updates", frames - 1);
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
    let (w, h) = (extent.width, extent.height);
    common::rt::ao::check_occlusion(report, gl, &gbuffers, &tracer);
    let moved = frames > 1 && args.animation.step > 0.0; // then the frames must show it
    output::save_frames(report, &args.common.out_dir(CHAPTER), CHAPTER, (w, h), &pictures, moved)?;

    // 7. Measure: the same rays through the refitted BLAS, then through a rebuilt one
    // ANCHOR: measure
    let rays = AoRays { samples: args.ao.samples, accumulated: 0, radius, scene_scale: scene.size() / 2.0 };
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
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
