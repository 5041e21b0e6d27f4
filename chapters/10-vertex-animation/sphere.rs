//! Chapter 10's sphere: the mesh, the wave the compute shader moves it with (and the same wave
//! on the CPU, for the checks), the compute pipeline, and one frame's Vulkan work with its
//! barriers.

use anyhow::Result;
use ash::vk;
use common::VulkanContext;
use common::base::commands;
use common::base::owned::{Owned, create};
use common::clocks::timestamps::Timestamps;
use common::clocks::timing::PassTimes;
use common::interop::handoff::{Handoff, SharedSemaphore};
use common::rt::accel::{AccelerationStructure, BufferDesc, DeviceBuffer, GpuAllocator, InPlace, Refresh};
use common::scene::{Mesh, Vertex};
use common::{GlContext, base::commands::buffer_barrier};
use glam::Vec3;
use glow::HasContext;
use gpu_allocator::MemoryLocation;
use std::cell::Cell;
use std::f32::consts::PI;

const SHADER: &[u8] = include_bytes!("../../shaders/sphere_wave.comp.spv");
/// The shader's `local_size_x`.
pub const WORKGROUP: u32 = 64;

/// Each vertex's rest direction, for the compute shader to move it along from: 16 bytes a
/// direction (w unused), not 12. With a 12-byte stride, GPU-assisted validation on the NVIDIA
/// GPU reported the last direction's read as out of bounds of the buffer.
pub fn rest_directions(
    vk: &VulkanContext,
    allocator: &GpuAllocator,
    directions: &[Vec3],
) -> Result<DeviceBuffer> {
    let padded: Vec<[f32; 4]> = directions.iter().map(|d| d.extend(0.0).to_array()).collect();
    let bytes = (padded.len() * size_of::<[f32; 4]>()) as u64;
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let desc = BufferDesc { name: "rest directions", size: bytes, usage, location: MemoryLocation::CpuToGpu };
    let mut rest = DeviceBuffer::new(vk, allocator, desc)?;
    let mapped = rest.allocation.mapped_slice_mut().expect("CpuToGpu memory is mapped");
    mapped[..bytes as usize].copy_from_slice(bytemuck::cast_slice(&padded));
    Ok(rest)
}

/// A UV sphere of radius 1 with `rings` bands of latitude and `segments` of longitude. Each
/// vertex's normal is its direction from the centre, which the wave also moves it along.
pub fn uv_sphere(rings: u32, segments: u32) -> Mesh {
    let mut vertices = Vec::new();
    for ring in 0..=rings {
        let theta = PI * ring as f32 / rings as f32; // from the north pole
        for segment in 0..=segments {
            // The seam repeats the first column, so that each quad below has its own corners.
            let phi = 2.0 * PI * segment as f32 / segments as f32;
            let d = Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
            vertices.push(Vertex { position: d.into(), normal: d.into() });
        }
    }
    let mut indices = Vec::new();
    let row = segments + 1;
    for ring in 0..rings {
        for segment in 0..segments {
            let (a, b) = (ring * row + segment, (ring + 1) * row + segment);
            // Anticlockwise seen from outside; the triangles at the poles are degenerate on one
            // side and skipped.
            if ring != 0 {
                indices.extend([a, a + 1, b]);
            }
            if ring + 1 != rings {
                indices.extend([a + 1, b + 1, b]);
            }
        }
    }
    Mesh { name: "sphere".into(), vertices, indices }
}

// ANCHOR: wave
/// The compute shader's push constants (`Wave` in `shaders/sphere_wave.comp`, scalar layout).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Wave {
    /// Device addresses of the shared vertex buffer and of the rest directions.
    pub vertices: u64,
    pub directions: u64,
    pub axis: [f32; 3],
    pub count: u32,
    pub time: f32,
    pub amplitude: f32,
    pub frequency: f32,
    pub speed: f32,
}

impl Wave {
    /// Vertex `d` (a unit direction) at this wave's time, as the shader computes it.
    pub fn vertex(&self, d: Vec3) -> Vertex {
        let axis = Vec3::from(self.axis);
        let phase = self.frequency * d.dot(axis) + self.speed * self.time;
        let r = 1.0 + self.amplitude * phase.sin();
        let grad = self.amplitude * self.frequency * phase.cos() * (axis - d.dot(axis) * d);
        Vertex { position: (r * d).into(), normal: (d - grad / r).normalize().into() }
    }
}
// ANCHOR_END: wave

/// The compute pipeline: no descriptors, only push constants (the buffers by device address).
/// Destroyed when dropped too (the pipeline, then its layout), so that an early return from
/// `run` leaks nothing.
pub struct WavePipeline {
    pub pipeline: Owned<vk::Pipeline>,
    pub layout: Owned<vk::PipelineLayout>,
}

impl WavePipeline {
    pub fn new(vk: &VulkanContext) -> Result<Self> {
        // Each object is owned as it is made: a failure half-way destroys what was made.
        let module = common::base::pipeline::shader_module(vk, SHADER, "wave")?;
        let range = vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .size(size_of::<Wave>() as u32);
        let layout_info =
            vk::PipelineLayoutCreateInfo::default().push_constant_ranges(std::slice::from_ref(&range));
        let layout = create(&vk.device, "vkCreatePipelineLayout for the wave", || unsafe {
            vk.device.create_pipeline_layout(&layout_info, None)
        })?;
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(*module)
            .name(c"main");
        let info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(*layout);
        let pipeline = create(&vk.device, "vkCreateComputePipelines for the wave", || unsafe {
            let pipelines = vk.device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None);
            pipelines.map(|p| p[0]).map_err(|(_, e)| e)
        })?;
        Ok(WavePipeline { pipeline, layout }) // `module` is dropped: the pipeline keeps what it needs
    }

    /// Records the dispatch: one invocation per vertex, in workgroups of [`WORKGROUP`].
    pub fn record(&self, vk: &VulkanContext, cb: vk::CommandBuffer, wave: &Wave) {
        unsafe {
            vk.device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, *self.pipeline);
            let bytes = bytemuck::bytes_of(wave);
            vk.device.cmd_push_constants(cb, *self.layout, vk::ShaderStageFlags::COMPUTE, 0, bytes);
            vk.device.cmd_dispatch(cb, wave.count.div_ceil(WORKGROUP), 1, 1);
        }
    }
}

// ANCHOR: vertex_handoff
/// The vertex buffer's hand-overs, as the images have theirs: Vulkan's compute shader writes the
/// vertices, GL's vertex fetch reads them, and the buffer moves between the two APIs like an
/// image (a queue family ownership transfer to and from `VK_QUEUE_FAMILY_EXTERNAL`, with no
/// layout). With semaphores, `moved` carries it to GL and `drawn` back; without, the CPU waits.
pub struct VertexHandoff {
    semaphores: Option<[SharedSemaphore; 2]>,
    gl_buffer: glow::Buffer,
    /// GL has had the vertices since Vulkan last wrote them: Vulkan must take them back first.
    with_gl: Cell<bool>,
}

impl VertexHandoff {
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        handoff: &Handoff,
        gl_buffer: glow::Buffer,
    ) -> Result<Self> {
        let semaphores = match handoff {
            Handoff::Semaphores { .. } => {
                Some([SharedSemaphore::new(vk, gl)?, SharedSemaphore::new(vk, gl)?])
            }
            Handoff::Host { .. } => None,
        };
        Ok(VertexHandoff { semaphores, gl_buffer, with_gl: Cell::new(false) })
    }

    /// Whether Vulkan's next write must first acquire the buffer from GL.
    pub fn with_gl(&self) -> bool {
        self.with_gl.get()
    }

    /// Just before Vulkan's next write: GL releases the buffer after every draw it has queued
    /// (a signal that lists it), and the submission waits for that at the compute stage; the
    /// CPU waits for GL instead without semaphores. Nothing the first time: GL never had it.
    pub fn to_vulkan(&self, gl: &GlContext) -> Option<(vk::Semaphore, vk::PipelineStageFlags)> {
        if !self.with_gl.replace(false) {
            return None;
        }
        let Some([_, drawn]) = &self.semaphores else {
            unsafe { gl.gl.finish() };
            return None;
        };
        let ext = gl.semaphores.as_ref().expect("semaphores were shared");
        let buffers = [self.gl_buffer.0.get()];
        unsafe {
            (ext.SignalSemaphoreEXT)(drawn.gl.0, 1, buffers.as_ptr(), 0, std::ptr::null(), std::ptr::null());
            gl.gl.flush(); // a signal waits in GL's queue until flushed
        }
        Some((*drawn.vk, vk::PipelineStageFlags::COMPUTE_SHADER))
    }

    /// What Vulkan's submission signals once the vertices are written.
    pub fn vulkan_signals(&self) -> Option<vk::Semaphore> {
        self.semaphores.as_ref().map(|[moved, _]| *moved.vk)
    }

    /// After Vulkan's write: GL acquires the buffer (a wait that lists it), or the CPU waits for
    /// the submission's `fence`. GL's vertex fetch may read the vertices from here on.
    pub fn to_gl(&self, vk: &VulkanContext, gl: &GlContext, fence: vk::Fence) -> Result<()> {
        match &self.semaphores {
            Some([moved, _]) => unsafe {
                let ext = gl.semaphores.as_ref().expect("semaphores were shared");
                let buffers = [self.gl_buffer.0.get()];
                (ext.WaitSemaphoreEXT)(
                    moved.gl.0,
                    1,
                    buffers.as_ptr(),
                    0,
                    std::ptr::null(),
                    std::ptr::null(),
                );
            },
            None => commands::wait_for(vk, fence, "vkWaitForFences for the moved vertices")?,
        }
        self.with_gl.set(true);
        Ok(())
    }
}
// ANCHOR_END: vertex_handoff

/// What one frame's Vulkan animation work uses.
pub struct Animation<'a> {
    pub loader: &'a ash::khr::acceleration_structure::Device,
    /// The sphere's vertex buffer, and whether GL has it (to be acquired before the write).
    pub vertices: vk::Buffer,
    pub vertices_from_gl: bool,
    pub pipeline: &'a WavePipeline,
    pub wave: Wave,
    pub blases: &'a [(AccelerationStructure, InPlace)],
    pub tlas: &'a InPlace,
}

/// What a frame builds: the first builds everything (the ground's BLAS, the sphere's, the
/// TLAS); each later one refreshes the sphere's BLAS as the policy says and updates the TLAS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    First,
    Next(Refresh),
}

// ANCHOR: record
/// Compute moves the vertices -> barrier -> the sphere's BLAS refit (or rebuild) -> barrier ->
/// the TLAS update -> barrier -> the frame's rays; the vertex buffer taken from GL before the
/// write (after the first frame) and given back after the refit, its last reader here.
pub fn record_animation(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    parts: &Animation,
    step: Step,
    timer: Option<&Timestamps>,
) {
    let compute = vk::PipelineStageFlags::COMPUTE_SHADER;
    let build = vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR;
    let rays = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
    let none = vk::DependencyFlags::empty();
    let barrier = |src, dst| vk::MemoryBarrier::default().src_access_mask(src).dst_access_mask(dst);
    use vk::AccessFlags as A;
    let (as_read, as_write) = (A::ACCELERATION_STRUCTURE_READ_KHR, A::ACCELERATION_STRUCTURE_WRITE_KHR);
    unsafe {
        if let Some(t) = timer {
            t.reset(vk, cb);
        }
        // Before the compute shader overwrites the vertices, everything that read them last frame
        // must be done: the previous refit (build stage) and GL's vertex fetch, which this
        // submission waits for at the compute stage (or the CPU did). Reads only: no access to
        // make available. The buffer comes back from GL (from `VK_QUEUE_FAMILY_EXTERNAL`).
        let external = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
        let acquire = buffer_barrier(parts.vertices, (A::NONE, A::SHADER_WRITE), external);
        let acquire = if parts.vertices_from_gl { std::slice::from_ref(&acquire) } else { &[] };
        vk.device.cmd_pipeline_barrier(cb, build | rays | compute, compute, none, &[], acquire, &[]);
        if let Some(t) = timer {
            t.write(vk, cb, compute, 0);
        }
        parts.pipeline.record(vk, cb, &parts.wave);
        if let Some(t) = timer {
            t.write(vk, cb, compute, 1);
        }
        // The refit reads the vertices the shader wrote: build inputs are read at the build
        // stage as SHADER_READ. It also reads and writes the BLAS (src = dst) and the scratch,
        // which the previous frame's refit wrote.
        let moved = barrier(A::SHADER_WRITE | as_write, A::SHADER_READ | as_read | as_write);
        vk.device.cmd_pipeline_barrier(cb, compute | build, build, none, &[moved], &[], &[]);
        let (loader, sphere, ground) = (parts.loader, &parts.blases[1].1, &parts.blases[0].1);
        let (sphere_refresh, tlas_refresh) = match step {
            Step::First => (Refresh::Rebuild, Refresh::Rebuild),
            Step::Next(refresh) => (refresh, Refresh::Update),
        };
        if step == Step::First {
            ground.record(loader, cb, Refresh::Rebuild);
        }
        sphere.record(loader, cb, sphere_refresh);
        if let Some(t) = timer {
            t.write(vk, cb, build, 2);
        }
        // The TLAS update reads the BLASes' new bounds: a refitted BLAS under a TLAS that was not
        // updated leaves the TLAS's boxes around where the sphere was (rays miss what bulged out).
        let refitted = barrier(as_write, as_read | as_write);
        vk.device.cmd_pipeline_barrier(cb, build, build, none, &[refitted], &[], &[]);
        parts.tlas.record(loader, cb, tlas_refresh);
        if let Some(t) = timer {
            t.write(vk, cb, build, 3);
        }
        // The rays read the TLAS and, through it, the BLASes, in the next submission.
        let ready = barrier(as_write, as_read);
        vk.device.cmd_pipeline_barrier(cb, build, rays, none, &[ready], &[], &[]);
        // The vertices go to GL: the shader's writes made available, ownership to
        // `VK_QUEUE_FAMILY_EXTERNAL`, after the refit, the last command here that reads them.
        let to_gl = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
        let release = buffer_barrier(parts.vertices, (A::SHADER_WRITE, A::NONE), to_gl);
        let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
        vk.device.cmd_pipeline_barrier(cb, compute | build, bottom, none, &[], &[release], &[]);
    }
}
// ANCHOR_END: record

/// Adds one frame's animation GPU times (timestamps 0-3 of `record_animation`, read once its
/// fence has signalled): the compute pass, the BLAS refit or rebuild, and the TLAS update.
pub fn add_times(
    vk: &VulkanContext,
    timer: &Timestamps,
    refresh: Refresh,
    times: &mut PassTimes,
) -> Result<()> {
    let ms = |from, to| timer.between_ms(vk, from, to);
    times.add("compute", ms(0, 1)?);
    times.add(if refresh == Refresh::Update { "blas_refit" } else { "blas_rebuild" }, ms(1, 2)?);
    times.add("tlas_update", ms(2, 3)?);
    Ok(())
}

/// The rebuild policy, as the report names it.
pub fn policy(rebuild_every: u32) -> String {
    match rebuild_every {
        0 => "never: refit every frame after the first".to_owned(),
        k => format!("rebuild every {k} frames, refit in between"),
    }
}

/// Every vertex the GPU moved against the CPU's formula for the same wave: positions within
/// 1e-5, normals within 1e-3.
pub fn vertices_match(wave: &Wave, directions: &[Vec3], gpu: &[Vertex]) -> bool {
    let close =
        |a: [f32; 3], b: [f32; 3], tolerance: f32| (Vec3::from(a) - Vec3::from(b)).length() <= tolerance;
    directions.iter().zip(gpu).all(|(&d, v)| {
        let expected = wave.vertex(d);
        close(v.position, expected.position, 1e-5) && close(v.normal, expected.normal, 1e-3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wave_is_laid_out_as_the_shader_reads_it() {
        use common::base::shader_block::{assert_matches_spirv, rust_block};
        let rust = rust_block!(Wave { vertices, directions, axis, count, time, amplitude, frequency, speed });
        assert_matches_spirv(SHADER, "Wave", rust);
    }

    #[test]
    fn sphere_is_closed_and_faces_outwards() {
        let sphere = uv_sphere(8, 16);
        for t in sphere.indices.chunks_exact(3) {
            let [a, b, c] = [0, 1, 2].map(|k| Vec3::from(sphere.vertices[t[k] as usize].position));
            let normal = (b - a).cross(c - a);
            assert!(normal.length() > 0.0, "no degenerate triangles");
            assert!(normal.dot(a + b + c) > 0.0, "anticlockwise seen from outside");
        }
    }

    #[test]
    fn wave_normals_are_perpendicular_to_the_surface() {
        let wave = Wave {
            vertices: 0,
            directions: 0,
            axis: Vec3::new(0.3, 1.0, 0.2).normalize().into(),
            count: 0,
            time: 0.7,
            amplitude: 0.1,
            frequency: 9.0,
            speed: 2.0,
        };
        let d = Vec3::new(0.4, 0.5, 0.6).normalize();
        let v = wave.vertex(d);
        // Move d a little along two tangent directions: the surface's chords are perpendicular
        // to the normal (to first order).
        for t in [d.cross(Vec3::X).normalize(), d.cross(Vec3::Z).normalize()] {
            let moved = wave.vertex((d + 1e-3 * t).normalize());
            let chord = Vec3::from(moved.position) - Vec3::from(v.position);
            assert!(chord.normalize().dot(Vec3::from(v.normal)).abs() < 1e-2);
        }
    }
}
