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
use common::base::fail;
use common::base::gl::{GlContext, MEMORY_EXTENSIONS};
use common::interop::cuda::CudaDevice;
use common::interop::exportable::{self, Dedicated, ExportableMemory, HANDLE_TYPE};
use common::interop::{self, SharedBuffer};
use common::scene::Camera;
use common::{CommonArgs, Report, Requirements, VulkanContext, ms_since};
use glow::HasContext;
use std::process::ExitCode;
use std::time::Instant;

mod check;
mod composite;
mod cuda;
mod scene;
use composite::{DepthComposite, DepthUniforms, PixelBuffer, Source, gl_time_ms, traced_bytes};
use cuda::{CudaTracer, ImportedMemory, RegisteredPbo};

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
    #[command(flatten)]
    common: CommonArgs,
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

fn main() -> ExitCode {
    common::run_chapter(CHAPTER, |args: &Args| &args.common, run)
}

fn run(args: &Args, report: &mut Report) -> Result<()> {
    SMALLEST.check(CHAPTER, args.common.size)?;
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
    let vk = VulkanContext::new(&Requirements { extensions: &extensions, ..Default::default() })?;
    let gl_context = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    let gl = &gl_context.gl;
    common::connect(report, &vk, &gl_context)?;
    common::largest_size(&vk, &gl_context).check(CHAPTER, args.common.size)?;
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
    let fds_before = common::base::resources::open_fds();

    // Steps 4 to 7 put what they make in `made`; step 8 frees whatever is there, after success
    // or failure alike (CUDA must let go of GL's and Vulkan's memory before they free it).
    let mut made = Made::default();
    let outcome = (|| -> Result<()> {
        // 4. Path 1: a GL pixel buffer object, registered with CUDA
        // ANCHOR: path1
        let pbo = made.pbo.insert(PixelBuffer::new(gl, width, height)?);
        if let Some(t) = &tracer {
            made.registered = Some(RegisteredPbo::new(t, *pbo.pbo)?);
        }
        // ANCHOR_END: path1

        // 5. Path 2: Vulkan memory, imported by CUDA and by GL
        // ANCHOR: path2
        let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(HANDLE_TYPE);
        let buffer_info = vk::BufferCreateInfo::default()
            .size(bytes)
            .usage(vk::BufferUsageFlags::STORAGE_BUFFER)
            .push_next(&mut external);
        let buffer = *made.buffer.insert(fail::call("vkCreateBuffer (exportable)", || unsafe {
            vk.device.create_buffer(&buffer_info, None)
        })?);
        let requirements = unsafe { vk.device.get_buffer_memory_requirements(buffer) };
        // CUDA writes it from the GPU: device-local. The CPU tracer writes it through a mapping.
        let properties = match tracer {
            Some(_) => vk::MemoryPropertyFlags::DEVICE_LOCAL,
            None => vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT,
        };
        let memory = made.memory.insert(exportable::allocate(&vk, &requirements, properties, Dedicated::No)?);
        unsafe { vk.device.bind_buffer_memory(buffer, memory.memory, 0) }.context("vkBindBufferMemory")?;
        let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
        // One fd per importer: each import takes ownership of the fd it is given.
        if tracer.is_some() {
            let fd = exportable::export_fd(&fd_loader, memory.memory)?;
            made.imported = Some(ImportedMemory::new(fd, memory.size, bytes)?);
        }
        let fd = exportable::export_fd(&fd_loader, memory.memory)?;
        let shared = made.shared.insert(interop::import_buffer(&gl_context, memory, fd, bytes)?);
        if tracer.is_none() {
            let flags = vk::MemoryMapFlags::empty();
            made.mapped = Some(fail::call("vkMapMemory", || unsafe {
                vk.device.map_memory(memory.memory, 0, bytes, flags)
            })?);
        }
        // ANCHOR_END: path2

        // 6. Every frame: trace, hand the pixels to GL, composite, draw the lines
        let composite = made.composite.insert(DepthComposite::new(gl, width, height, &spheres)?);
        let mut pictures = Vec::new();
        for &path in &paths {
            let mut times: [Vec<f64>; 3] = Default::default(); // trace, upload, composite
            for _ in 0..args.common.frame_count(false) {
                // ANCHOR: frame
                let started = Instant::now();
                match (path, &tracer) {
                    (Path::Pbo, Some(t)) => {
                        made.registered.as_mut().unwrap().trace(t, &params, bytes)?;
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
                        t.launch(made.imported.as_ref().unwrap().pointer, &params)?;
                        times[0].push(t.kernel_ms()?);
                        t.synchronize()?;
                    }
                    (Path::ZeroCopy, None) => {
                        unsafe { gl.finish() };
                        let words = bytes as usize / 4;
                        // SAFETY: `mapped` is `bytes` bytes of host-coherent memory GL is not using now.
                        let traced =
                            unsafe { std::slice::from_raw_parts_mut(made.mapped.unwrap().cast(), words) };
                        scene::trace(&params, traced);
                        times[0].push(ms_since(started));
                    }
                }
                let source = match path {
                    Path::Pbo => {
                        times[1].push(gl_time_ms(gl, || pbo.upload(gl))?);
                        Source::Textures(pbo)
                    }
                    Path::ZeroCopy => Source::Buffer(shared.buffer),
                };
                times[2].push(gl_time_ms(gl, || {
                    composite.draw_traced(gl, source, &depth);
                    composite.draw_lines(gl, view_projection);
                })?);
                // ANCHOR_END: frame
            }
            check::report_times(report, path, tracer.is_some(), &times);

            // 7. Check what this path drew
            let (source, buffer) = match path {
                Path::Pbo => (Source::Textures(pbo), *pbo.pbo),
                Path::ZeroCopy => (Source::Buffer(shared.buffer), shared.buffer),
            };
            let traced = check::read_buffer(gl, buffer, bytes);
            let frame =
                check::Frame { gl, composite, source, depth: &depth, view_projection, camera: &camera };
            pictures.push((path, frame.check(report, path, &params, &traced, tracer.is_some())?));
        }
        if let [(_, a), (_, b)] = &pictures[..] {
            report.check("both_paths_show_the_same_picture", a == b);
        }
        let out_dir = args.common.out_dir(CHAPTER);
        for (path, picture) in &pictures {
            let name = match path {
                Path::Pbo => CHAPTER.to_owned(),
                Path::ZeroCopy => format!("{CHAPTER}-zero-copy"),
            };
            let upright = common::base::output::flip_rows(picture, width, height);
            common::base::output::save_rgba8(report, &out_dir, &name, width, height, &upright)?;
        }
        gl_context.check_error("the frames")
    })();

    // 8. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    let cleaned = made.destroy(&vk, tracer.as_ref());
    let fds_after = common::base::resources::open_fds();
    let released = tracer.map_or(Ok(()), CudaTracer::destroy);
    // ANCHOR_END: cleanup
    outcome?;
    cleaned?;
    released?;
    gl_context.check_error("cleaning up")?;
    let live = common::base::resources::live();
    report.check("cuda_and_shared_resources_released", live.values().all(|&n| n == 0));
    let leaked: Vec<_> = fds_after.iter().filter(|fd| !fds_before.contains(fd)).collect();
    if !leaked.is_empty() {
        eprintln!("fds open after cleaning up that were not before step 4: {leaked:?}");
    }
    report.check("no_fd_leaked", leaked.is_empty() && fds_after.len() == fds_before.len());
    Ok(())
}

// ANCHOR: made
/// What steps 4 to 7 made, each `None` until made.
#[derive(Default)]
struct Made {
    pbo: Option<PixelBuffer>,
    registered: Option<RegisteredPbo>,
    buffer: Option<vk::Buffer>,
    memory: Option<ExportableMemory>,
    imported: Option<ImportedMemory>,
    shared: Option<SharedBuffer>,
    mapped: Option<*mut std::ffi::c_void>,
    composite: Option<DepthComposite>,
}

impl Made {
    /// Frees what exists, newest first, once CUDA and GL are idle; every step runs even after
    /// one fails, and the first failure is returned.
    fn destroy(self, vk: &VulkanContext, tracer: Option<&CudaTracer>) -> Result<()> {
        let mut first_error = tracer.map_or(Ok(()), CudaTracer::synchronize);
        let mut keep = |result: Result<()>| {
            if let (Ok(()), Err(error)) = (&first_error, result) {
                first_error = Err(error);
            }
        };
        drop(self.composite); // GL only
        if let (Some(memory), Some(_)) = (&self.memory, self.mapped) {
            unsafe { vk.device.unmap_memory(memory.memory) };
        }
        // GL's import and CUDA's, before Vulkan frees the memory under them.
        drop(self.shared); // the GL buffer, then its memory object
        if let Some(imported) = self.imported {
            keep(imported.destroy());
        }
        if let Some(buffer) = self.buffer {
            unsafe { vk.device.destroy_buffer(buffer, None) };
        }
        if let Some(memory) = self.memory {
            unsafe { vk.device.free_memory(memory.memory, None) }; // and (dropped) its count
        }
        // CUDA's registration, before GL deletes the buffer it names.
        if let Some(registered) = self.registered {
            keep(registered.destroy());
        }
        drop(self.pbo); // the textures, then the buffer
        first_error
    }
}
// ANCHOR_END: made
