//! Chapter 11: CUDA depth composite.
//!
//! A CUDA kernel ray-traces spheres on a ground square and writes, per pixel, a colour and the
//! ray's hit distance. GL turns the distance into the depth its rasteriser would have written
//! for the same point, then draws lines (an axis gizmo, bounding boxes, a ground grid) with the
//! depth test on: the ray-traced spheres hide them exactly as rasterised ones would. The
//! kernel's output reaches GL two ways, timed side by side: through a GL pixel buffer object
//! registered with CUDA (path 1, as first published), and through Vulkan memory that both CUDA
//! and GL import (path 2, zero-copy). Without CUDA the same tracer runs on the CPU.
//!
//! Run: `cargo run --release --bin 11-cuda-depth-composite -- --tracer auto --path both`

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::cli::Smallest;
use common::base::gl::GlContext;
use common::base::owned::create;
use common::instruments::fail;
use common::interop;
use common::interop::cuda::CudaDevice;
use common::interop::exportable::{self, Dedicated, HANDLE_TYPE};
use common::scene::Camera;
use common::{Flags, Report, Requirements, VulkanContext, ms_since};
use glow::HasContext;
use std::process::ExitCode;
use std::time::Instant;

mod check;
mod composite;
mod cuda;
mod scene;
use check::TracedBy;
use composite::{DepthComposite, DepthUniforms, PixelBuffer, Source, gl_time_ms, traced_bytes};
use cuda::{CudaTracer, ImportedMemory, RegisteredPbo, StreamDrained};

const CHAPTER: &str = "11-cuda-depth-composite";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 32,
    height: 32,
    why: "the overlay checks probe gizmo pixels with two pixels of room around them",
    shape: Some((
        f32::INFINITY,
        1.0,
        "framed taller than wide, the gizmo's axis behind the red sphere leaves the picture",
    )),
};

/// Chapter 11: a ray-traced image (CUDA, or the same tracer on the CPU) depth-composited with
/// GL-rasterised lines.
#[derive(clap::Parser)]
struct Args {
    /// Who traces: CUDA when it can run here (auto), CUDA or fail (cuda), the CPU (cpu).
    #[arg(long, value_enum, default_value = "auto")]
    tracer: TracerChoice,
    /// How the traced pixels reach GL: a pixel buffer object, Vulkan memory, or both in turn.
    #[arg(long, value_enum, default_value = "both")]
    path: PathChoice,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum TracerChoice {
    Auto,
    Cpu,
    Cuda,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum PathChoice {
    Pbo,
    ZeroCopy,
    Both,
}

/// The two ways from the tracer to GL.
#[derive(Clone, Copy, PartialEq, Debug)]
pub enum Path {
    Pbo,
    ZeroCopy,
}

impl Path {
    pub fn name(self) -> &'static str {
        match self {
            Path::Pbo => "pbo",
            Path::ZeroCopy => "zero_copy",
        }
    }
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let (width, height) = (args.common.size.width, args.common.size.height);
    let bytes = traced_bytes(width, height);
    let paths = match args.path {
        PathChoice::Pbo => vec![Path::Pbo],
        PathChoice::ZeroCopy => vec![Path::ZeroCopy],
        PathChoice::Both => vec![Path::Pbo, Path::ZeroCopy],
    };

    // 1. The scene and the camera
    let spheres = scene::spheres();
    let aspect = width as f32 / height as f32;
    let camera = Camera::framing(scene::bounds(&spheres), aspect);
    let params = scene::params(&camera, width, height, &spheres);
    let view_projection = camera.view_projection(aspect);
    let tan_half = (camera.fov_y / 2.0).tan();
    let depth = DepthUniforms { tan_half: (tan_half * aspect, tan_half), near: camera.near, far: camera.far };

    // 2. Vulkan and GL on one device
    let extensions = [ash::khr::external_memory_fd::NAME];
    let requirements = Requirements { extensions: &extensions, ..Default::default() };
    let (vk, gl_context) = common::contexts(CHAPTER, report, &requirements, args.common.size)?;
    // GL buffer sizes are 32-bit signed here (glow's glNamedBufferData): refuse what the chapter
    // cannot hold, before anything else exists.
    anyhow::ensure!(
        bytes <= i32::MAX as u64,
        "--size {width}x{height} is too large for {CHAPTER}: the traced colour and depth need {bytes} \
         bytes; a GL buffer here holds at most {} bytes (16383x16383 fits)",
        i32::MAX
    );
    report.sync = Some("host");

    // 3. CUDA on that device, or the CPU
    // ANCHOR: choose
    let tracer = match args.tracer {
        TracerChoice::Cpu => None,
        choice => match CudaDevice::open(&vk.info.device_uuid) {
            Ok(device) => Some(CudaTracer::new(device)?),
            Err(error) => match common::interop::cuda::unavailable(&error) {
                Some(why) if choice == TracerChoice::Auto => {
                    eprintln!("cuda: {why}: tracing on the CPU instead");
                    None
                }
                _ => return Err(error).context("--tracer cuda"),
            },
        },
    };
    // ANCHOR_END: choose
    report.set("tracer", if tracer.is_some() { "cuda" } else { "cpu" });
    if let Some(t) = &tracer {
        let (major, minor) = t.device.compute_capability;
        eprintln!("cuda: {} (compute capability {major}.{minor})", t.device.name);
        report.set("cuda_compute_capability", format!("{major}.{minor}"));
    }
    // After CUDA started: its driver keeps files of its own open (/dev/nvidia*) until the
    // process exits. The fds this chapter shares must all be closed again by step 8.
    let fds_before = common::instruments::resources::open_fds();

    // Steps 4 to 8: each object has its owner the moment it exists, so that an early return
    // frees what was made, newest first, as step 8 does.
    let setup = Setup {
        vk: &vk,
        gl: &gl_context,
        args,
        paths: &paths,
        spheres: &spheres,
        camera: &camera,
        params,
        depth,
        view_projection,
    };
    let drawn = draw_paths(&setup, tracer.as_ref(), report);
    let fds_after = common::instruments::resources::open_fds();
    // ANCHOR: release
    // CUDA's own objects last (draw_paths waited for its stream): the events, the stream, the
    // module, then the primary context.
    drop(tracer);
    // ANCHOR_END: release
    drawn?;
    gl_context.check_error("cleaning up")?;
    let live = common::instruments::resources::live();
    report.check("cuda_and_shared_resources_released", live.values().all(|&n| n == 0));
    let leaked: Vec<_> = fds_after.iter().filter(|fd| !fds_before.contains(fd)).collect();
    if !leaked.is_empty() {
        eprintln!("fds open after cleaning up that were not before step 4: {leaked:?}");
    }
    report.check("no_fd_leaked", leaked.is_empty() && fds_after.len() == fds_before.len());
    Ok(())
}

/// What steps 4 to 7 draw with, from steps 1 to 3.
struct Setup<'a> {
    vk: &'a VulkanContext,
    gl: &'a GlContext,
    args: &'a Flags<Args>,
    paths: &'a [Path],
    spheres: &'a [scene::Sphere],
    camera: &'a Camera,
    params: scene::TraceParams,
    depth: DepthUniforms,
    view_projection: glam::Mat4,
}

/// Steps 4 to 8: both paths made, drawn every frame, checked, and freed again.
fn draw_paths(s: &Setup, tracer: Option<&CudaTracer>, report: &mut Report) -> Result<()> {
    let (vk, gl_context, gl) = (s.vk, s.gl, &s.gl.gl);
    let (params, view_projection) = (s.params, s.view_projection);
    let (width, height) = (params.width, params.height);
    let bytes = traced_bytes(width, height);

    // 4. Path 1: a GL pixel buffer object, registered with CUDA
    // ANCHOR: path1
    let pbo = PixelBuffer::new(gl, width, height)?;
    let mut registered = match tracer {
        Some(t) => Some(RegisteredPbo::new(t, *pbo.pbo)?),
        None => None,
    };
    // ANCHOR_END: path1

    // 5. Path 2: Vulkan memory, imported by CUDA and by GL
    // ANCHOR: path2
    let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE_TYPE);
    let buffer_info = vk::BufferCreateInfo::default()
        .size(bytes)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER)
        .push_next(&mut external);
    let buffer = create(&vk.device, "vkCreateBuffer (exportable)", || unsafe {
        vk.device.create_buffer(&buffer_info, None)
    })?;
    let requirements = unsafe { vk.device.get_buffer_memory_requirements(*buffer) };
    // CUDA writes it from the GPU: device-local. The CPU tracer writes it through a mapping.
    let properties = match tracer {
        Some(_) => vk::MemoryPropertyFlags::DEVICE_LOCAL,
        None => vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
    };
    // Freed (and so unmapped, for the CPU tracer) when dropped, after the buffer.
    let memory = exportable::allocate(vk, &requirements, properties, Dedicated::No)?;
    fail::call("vkBindBufferMemory", || unsafe { vk.device.bind_buffer_memory(*buffer, *memory.memory, 0) })?;
    let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
    // One fd per importer: each import takes ownership of the fd it is given.
    let imported = match tracer {
        Some(_) => {
            Some(ImportedMemory::new(exportable::export_fd(&fd_loader, *memory.memory)?, memory.size, bytes)?)
        }
        None => None,
    };
    let fd = exportable::export_fd(&fd_loader, *memory.memory)?;
    let shared = interop::import_buffer(gl_context, &memory, fd, bytes)?;
    let mapped = match tracer {
        Some(_) => None,
        None => Some(fail::call("vkMapMemory", || unsafe {
            vk.device.map_memory(*memory.memory, 0, bytes, vk::MemoryMapFlags::empty())
        })?),
    };
    // ANCHOR_END: path2
    // Made after everything the kernel uses, so dropped first on an early return: it waits for
    // CUDA's stream before any of it goes, as `Commands` waits for Vulkan's fence.
    let drained = tracer.map(StreamDrained);

    // 6. Every frame: trace, hand the pixels to GL, composite, draw the lines
    let composite = DepthComposite::new(gl, width, height, s.spheres)?;
    let traced_by = if tracer.is_some() { TracedBy::Cuda } else { TracedBy::Cpu };
    let mut pictures = Vec::new();
    for &path in s.paths {
        let mut times: [Vec<f64>; 3] = Default::default(); // trace, upload, composite
        for _ in 0..s.args.common.headless_frames() {
            // ANCHOR: frame
            let started = Instant::now();
            match (path, &tracer) {
                (Path::Pbo, Some(t)) => {
                    registered.as_mut().expect("registered with CUDA").trace(t, &params, bytes)?;
                    times[0].push(t.kernel_ms()?);
                }
                (Path::Pbo, None) => {
                    pbo.write_with(gl, |traced| drop(scene::trace(&params, traced)));
                    times[0].push(ms_since(started));
                }
                (Path::ZeroCopy, Some(t)) => {
                    // No semaphores here: GL has finished reading the last frame before
                    // CUDA writes, and CUDA has finished writing before GL reads.
                    unsafe { gl.finish() };
                    t.launch(imported.as_ref().expect("imported by CUDA").pointer.0, &params)?;
                    times[0].push(t.kernel_ms()?);
                    t.synchronize()?;
                }
                (Path::ZeroCopy, None) => {
                    unsafe { gl.finish() };
                    // SAFETY: `mapped` is `bytes` bytes of host-coherent memory GL is not using now.
                    let mapped = mapped.expect("mapped for the CPU").cast::<u8>();
                    let traced = bytemuck::cast_slice_mut(unsafe {
                        std::slice::from_raw_parts_mut(mapped, bytes as usize)
                    });
                    scene::trace(&params, traced);
                    times[0].push(ms_since(started));
                }
            }
            let source = match path {
                Path::Pbo => {
                    times[1].push(gl_time_ms(gl, || pbo.upload(gl))?);
                    Source::Textures(&pbo)
                }
                Path::ZeroCopy => Source::Buffer(*shared.buffer),
            };
            times[2].push(gl_time_ms(gl, || {
                composite.draw_traced(gl, source, &s.depth);
                composite.draw_lines(gl, view_projection);
            })?);
            // ANCHOR_END: frame
        }
        check::report_times(report, path.name(), traced_by, &times);

        // 7. Check what this path drew
        let (source, buffer) = match path {
            Path::Pbo => (Source::Textures(&pbo), *pbo.pbo),
            Path::ZeroCopy => (Source::Buffer(*shared.buffer), *shared.buffer),
        };
        let traced = check::read_buffer(gl, buffer, bytes);
        let frame = check::Frame {
            gl,
            composite: &composite,
            source,
            depth: &s.depth,
            view_projection,
            camera: s.camera,
            traced_by,
        };
        pictures.push((path, frame.check(report, path.name(), &params, &traced)?));
    }
    if let [(_, a), (_, b)] = &pictures[..] {
        report.check("both_paths_show_the_same_picture", a == b);
    }
    let out_dir = s.args.common.out_dir(CHAPTER);
    for (path, picture) in &pictures {
        let name = match path {
            Path::Pbo => CHAPTER.to_owned(),
            Path::ZeroCopy => format!("{CHAPTER}-zero-copy"),
        };
        common::instruments::output::save_gl_rgba8(report, &out_dir, &name, (width, height), picture)?;
    }
    gl_context.check_error("the frames")?;

    // 8. Clean up, newest first, once every API is done (Vulkan submitted nothing)
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    if let Some(t) = tracer {
        t.synchronize()?;
    }
    drop(drained); // waits for nothing now
    drop(composite); // GL only
    // GL's import and CUDA's, before Vulkan frees the memory.
    drop(shared); // the GL buffer, then its memory object
    drop(imported); // CUDA's mapping, then its external memory
    drop(buffer); // the Vulkan buffer
    drop(memory); // its memory (unmapped with it)
    // CUDA's registration, before GL deletes the buffer it names.
    drop(registered);
    drop(pbo); // the textures, then the buffer
    // ANCHOR_END: cleanup
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, SMALLEST, run)
}
