//! Chapter 13's Vulkan side: the ray tracing pipeline that reuses the previous frame's
//! occlusion, the two history images it reads and writes in turn, the cameras and previous
//! transforms it reprojects with, and one frame's work between chapter 12's hand-overs.

use anyhow::{Context as _, Result};
use ash::vk;
use common::base::commands::{HostBuffer, copy_image_to_buffer, first_use, image_barrier, transfers_to_host};
use common::base::vulkan::VulkanContext;
use common::clocks::timestamps::Timestamps;
use common::interop::handoff::Apis;
use common::rt::RayTracedScene;
use common::rt::accel::{BufferDesc, DeviceBuffer, GpuAllocator};
use common::rt::raytrace::{RayPipeline, RayShaders, StorageImage};
use common::scene::Camera;
use fast_frame::trace::{hand_over_around, traced};
use fast_frame::visibility::Targets;
use gpu_allocator::MemoryLocation;

const RAYGEN: &[u8] = include_bytes!("../../shaders/temporal_ao.rgen.spv");
const MISS: &[u8] = include_bytes!("../../shaders/miss.rmiss.spv");
const HISTORY_FORMAT: vk::Format = vk::Format::R32G32B32A32_UINT;

// ANCHOR: push
/// The push constants of `shaders/temporal_ao.rgen` (std430, 112 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TemporalRays {
    pub cameras: u64,
    pub meshes: u64,
    pub instances: u64,
    pub previous_instances: u64,
    pub radius: f32,
    pub scene_scale: f32,
    pub mesh_count: u32,
    pub samples: u32,
    pub fresh: u32,
    pub cap: u32,
    pub settled_every: u32,
    pub frame: u32,
    pub accept: u32,
    pub plane_tolerance: f32,
    pub normal_tolerance: f32,
    pub per_pixel: u32,
    /// A sphere (centre, radius) holding what moved since the previous frame, grown by the
    /// occlusion radius; radius 0: nothing moved.
    pub moved: [f32; 4],
    pub near_motion_cap: u32,
    /// Which launch this is: `INLINE`, `LISTING` or `LISTED`.
    pub pass: u32,
    /// The device address of the list of fresh pixels.
    pub fresh_pixels: u64,
}

/// The shader's `Cameras` (std430, 256 bytes): this frame's and the previous frame's.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Cameras {
    inverse_view_projection: [f32; 16],
    previous_view_projection: [f32; 16],
    previous_inverse_view_projection: [f32; 16],
    eye: [f32; 4],
    forward: [f32; 4],
    previous_eye: [f32; 4],
    previous_forward: [f32; 4],
}
// ANCHOR_END: push

/// The shader's `pass`: the one launch of `--fresh-pass inline`, or the first or second of
/// `packed`.
const INLINE: u32 = 0;
const LISTING: u32 = 1;
const LISTED: u32 = 2;

/// The shader's `accept` bits (`HAS_HISTORY`, then one per test).
const HAS_HISTORY: u32 = 1;
pub fn accept_bits(accept: &[Accept]) -> u32 {
    accept.iter().fold(0, |bits, a| {
        bits | match a {
            Accept::Instance => 2,
            Accept::Plane => 4,
            Accept::Normal => 8,
            Accept::None => 0,
        }
    })
}

/// How many rays a pixel traces and remembers: the flags chapter 13 and `convergence temporal`
/// share.
#[derive(clap::Args, Clone, Debug)]
pub struct RayArgs {
    /// Rays per pixel per frame where the history is still filling (1-64).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(1..=64))]
    pub samples: u32,
    /// Rays for a pixel with no history: a surface just uncovered, every pixel after a cut (1-256).
    #[arg(long, default_value_t = 32, value_parser = common::base::cli::number::<u32>(1..=256))]
    pub fresh: u32,
    /// The most rays a pixel's mean weighs (1-4096): new rays always count at least
    /// samples / (cap + samples), so a change around the pixel fades in within about cap rays.
    #[arg(long, default_value_t = 128, value_parser = common::base::cli::number::<u32>(1..=4096))]
    pub cap: u32,
    /// A pixel whose history holds `cap` rays traces one frame in this many (0: never again).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=64))]
    pub settled_every: u32,
    /// The most rays a pixel remembers where something moved within the radius of it since the
    /// previous frame (its occlusion changed there, by how much no test can tell from a few new
    /// rays); 0: no limit, the cap alone.
    #[arg(long, default_value_t = 16, value_parser = common::base::cli::number::<u32>(0..=4096))]
    pub near_motion_cap: u32,
}

/// A test a remembered texel must pass to be reused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Accept {
    /// The texel saw the same instance.
    Instance,
    /// The point the texel saw lies on this point's plane.
    Plane,
    /// The texel's normal is this point's.
    Normal,
    /// No test: everything remembered is reused.
    None,
}

/// Where the rays of a pixel with nothing remembered are traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FreshPass {
    /// In a second launch, one ray per invocation, over the pixels the first listed.
    Packed,
    /// In the one launch, beside the pixels that trace a few.
    Inline,
}

/// What every frame's rays are asked to do, from the flags.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    pub samples: u32,
    pub fresh: u32,
    pub cap: u32,
    pub settled_every: u32,
    pub accept: u32,
    pub radius: f32,
    pub scene_scale: f32,
    /// Chapter 07's rotation per pixel instead of chapter 12's 4x4 blocks (a still camera then
    /// traces chapter 08's very rays; `convergence temporal --pattern`).
    pub per_pixel: bool,
    /// The most rays a pixel remembers near what moved (`--near-motion-cap`).
    pub near_motion_cap: u32,
    /// Where a pixel with nothing remembered traces (`convergence temporal --fresh-pass`).
    pub fresh_pass: FreshPass,
}

impl Budget {
    /// Chapter 13's budget: the rays `args` asks for, every test of a texel on, chapter 12's 4x4
    /// blocks, and the pixels with nothing remembered traced in a launch of their own. No rays
    /// at all where the occlusion radius is 0.
    pub fn new(args: &RayArgs, radius: f32, scene_scale: f32) -> Budget {
        let (samples, fresh) = if radius > 0.0 { (args.samples, args.fresh) } else { (0, 0) };
        let (cap, settled_every) = (args.cap, args.settled_every);
        let accept = accept_bits(&[Accept::Instance, Accept::Plane, Accept::Normal]);
        let (per_pixel, near_motion_cap, fresh_pass) = (false, args.near_motion_cap, FreshPass::Packed);
        Budget {
            samples,
            fresh,
            cap,
            settled_every,
            accept,
            radius,
            scene_scale,
            per_pixel,
            near_motion_cap,
            fresh_pass,
        }
    }
}

/// The pipeline, its two history images, the list of pixels with nothing remembered and the
/// buffers it reprojects with. Dropped, the pipeline goes first, then the images and buffers; the
/// GPU must be done with all of them.
pub struct TemporalTracer {
    pipeline: RayPipeline,
    history: [StorageImage; 2],
    /// The pixels with nothing remembered, listed by the first launch for the second to trace:
    /// a count, then room for every pixel of the picture. Made for `--fresh-pass packed` only.
    fresh_pixels: Option<DeviceBuffer>,
    cameras: DeviceBuffer,
    /// Three copies of the shared instance buffer, which only the rays read: frame k's rays take
    /// copy k % 3 as this frame's transforms and copy (k + 2) % 3 as the previous frame's. Three,
    /// so that the CPU can write frame k + 1's while frame k's rays still read the other two;
    /// the shared buffer itself is read only by GL's ids and the TLAS update.
    transforms: [DeviceBuffer; 3],
    /// Which history image this frame writes; the other holds the previous frame's.
    written: usize,
    /// Whether the image not written this frame holds a frame of this size and this camera's
    /// scene: false at first, after a resize and after `forget`.
    remembers: bool,
    /// Whether the history images have been used since they were made (undefined before).
    images_used: bool,
    previous_camera: Option<Camera>,
    /// Chapter 12's mesh table (address, meshes).
    meshes: (u64, u32),
}

impl TemporalTracer {
    pub fn new(
        vk: &VulkanContext,
        shared: &RayTracedScene,
        meshes: (u64, u32),
        targets: &Targets,
        fresh_pass: FreshPass,
    ) -> Result<Self> {
        // ANCHOR: bindings
        let binding = |binding, ty| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(binding)
                .descriptor_type(ty)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::RAYGEN_KHR)
        };
        let image = vk::DescriptorType::STORAGE_IMAGE;
        let bindings = [
            binding(0, vk::DescriptorType::ACCELERATION_STRUCTURE_KHR),
            binding(1, image), // the ids, from GL
            binding(2, image), // the surface, for GL's composite
            binding(3, image), // the history read: the previous frame's
            binding(4, image), // the history written: this frame's
        ];
        // ANCHOR_END: bindings
        let allocator = &shared.allocator;
        let shaders = RayShaders { raygen: RAYGEN, miss: MISS };
        let pipeline = RayPipeline::new(vk, allocator, shaders, &bindings, size_of::<TemporalRays>() as u32)?;
        pipeline.write_tlas(vk, 0, *shared.structures.tlas.handle);
        let history = Self::history_images(vk, allocator, targets.extent)?;
        let fresh_pixels = match fresh_pass {
            FreshPass::Packed => Some(Self::fresh_list(vk, allocator, targets.extent)?),
            FreshPass::Inline => None,
        };
        let host = |name, size| BufferDesc {
            name,
            size,
            usage: vk::BufferUsageFlags::STORAGE_BUFFER,
            location: MemoryLocation::CpuToGpu,
        };
        let cameras = DeviceBuffer::new(vk, allocator, host("cameras", size_of::<Cameras>() as u64))?;
        let shared_instances = &shared.buffers.instances.vk;
        // SAFETY: the shared buffer's mapping is `bytes` long and nothing writes it now.
        let now =
            unsafe { std::slice::from_raw_parts(shared_instances.mapped, shared_instances.bytes as usize) };
        // At first every copy holds the transforms as they are: nothing has moved yet.
        let copy = || -> Result<DeviceBuffer> {
            let mut copy = DeviceBuffer::new(vk, allocator, host("instance transforms", now.len() as u64))?;
            copy.allocation.mapped_slice_mut().context("instance transforms unmapped")?[..now.len()]
                .copy_from_slice(now);
            Ok(copy)
        };
        let transforms = [copy()?, copy()?, copy()?];
        let tracer = TemporalTracer {
            pipeline,
            history,
            fresh_pixels,
            cameras,
            transforms,
            written: 0,
            remembers: false,
            images_used: false,
            previous_camera: None,
            meshes,
        };
        tracer.point_at(vk, targets);
        Ok(tracer)
    }

    fn history_images(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        extent: vk::Extent2D,
    ) -> Result<[StorageImage; 2]> {
        let usage = vk::ImageUsageFlags::TRANSFER_SRC; // read back by the checks
        let first = StorageImage::new(vk, allocator, HISTORY_FORMAT, usage, extent)?;
        Ok([first, StorageImage::new(vk, allocator, HISTORY_FORMAT, usage, extent)?])
    }

    /// The list of fresh pixels for a picture of `extent`: a count (padded to 8 bytes), then
    /// room for every pixel (after a cut, every pixel that shows a surface is one), 8 bytes each:
    /// where it is and its tally. Only the ray generation shader reads and writes it, by its
    /// address, but for its count, which `vkCmdFillBuffer` (a transfer) sets to 0.
    fn fresh_list(
        vk: &VulkanContext,
        allocator: &GpuAllocator,
        extent: vk::Extent2D,
    ) -> Result<DeviceBuffer> {
        let size = 8 + 8 * extent.width as u64 * extent.height as u64;
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
        let location = MemoryLocation::GpuOnly;
        DeviceBuffer::new(vk, allocator, BufferDesc { name: "fresh pixels", size, usage, location })
    }

    /// The descriptors at this size's images, the history read and written as `written` says.
    fn point_at(&self, vk: &VulkanContext, targets: &Targets) {
        self.pipeline.write_storage_image(vk, 1, *targets.visibility.view);
        self.pipeline.write_storage_image(vk, 2, *targets.surface.view);
        self.pipeline.write_storage_image(vk, 3, *self.history[1 - self.written].view);
        self.pipeline.write_storage_image(vk, 4, *self.history[self.written].view);
    }

    /// New images and a new list of the new size: nothing is remembered. The GPU must be done
    /// with the old.
    pub fn resized(&mut self, vk: &VulkanContext, allocator: &GpuAllocator, targets: &Targets) -> Result<()> {
        self.history = Self::history_images(vk, allocator, targets.extent)?;
        if self.fresh_pixels.is_some() {
            self.fresh_pixels = Some(Self::fresh_list(vk, allocator, targets.extent)?);
        }
        (self.written, self.remembers, self.images_used) = (0, false, false);
        self.point_at(vk, targets);
        Ok(())
    }

    /// Frame `frame`'s copy of the instance buffer, which its rays read as this frame's
    /// transforms and the next frame's as the previous ones (`frame + 2`: the previous frame's).
    /// The traces that read it last, those of frames `frame - 3` and `frame - 2`, must be done.
    pub fn transforms(&mut self, frame: u32) -> Result<&mut [u8]> {
        self.transforms[frame as usize % 3]
            .allocation
            .mapped_slice_mut()
            .context("instance transforms unmapped")
    }

    /// The next frame starts with no history (a method switch, a new setting).
    pub fn forget(&mut self) {
        self.remembers = false;
    }

    // ANCHOR: frame
    /// One frame: the cameras written, then, between chapter 12's hand-overs, the history made
    /// visible to this frame's rays and the rays traced (in two launches with `--fresh-pass
    /// packed`, the pixels with nothing remembered in the second); then the two history images
    /// swap. The caller waits for the previous frame's Vulkan work first (`Passes::draw` does).
    pub fn trace(
        &mut self,
        apis: Apis,
        targets: &Targets,
        (camera, frame): (&Camera, u32),
        (budget, moved): (&Budget, Option<(glam::Vec3, f32)>),
        (timestamps, released): (Option<&Timestamps>, bool),
    ) -> Result<()> {
        // The previous frame's work is done (the caller waited for it, at the top of the frame):
        // its descriptors and cameras may change.
        let vk = apis.vk;
        self.point_at(vk, targets);
        let aspect = targets.extent.width as f32 / targets.extent.height as f32;
        let previous = self.previous_camera.unwrap_or(*camera);
        let (now, then) = (camera.view_projection(aspect), previous.view_projection(aspect));
        let forward = |c: &Camera| (c.target - c.eye).normalize().extend(0.0).to_array();
        let cameras = Cameras {
            inverse_view_projection: now.inverse().to_cols_array(),
            previous_view_projection: then.to_cols_array(),
            previous_inverse_view_projection: then.inverse().to_cols_array(),
            eye: camera.eye.extend(1.0).to_array(),
            forward: forward(camera),
            previous_eye: previous.eye.extend(1.0).to_array(),
            previous_forward: forward(&previous),
        };
        let mapped = self.cameras.allocation.mapped_slice_mut().context("cameras unmapped")?;
        mapped[..size_of::<Cameras>()].copy_from_slice(bytemuck::bytes_of(&cameras));
        let list = match (budget.fresh_pass, &self.fresh_pixels) {
            (FreshPass::Packed, Some(list)) => Some(list),
            (FreshPass::Packed, None) => {
                anyhow::bail!("--fresh-pass packed: the tracer was made without its list")
            }
            (FreshPass::Inline, _) => None,
        };
        let push = TemporalRays {
            cameras: self.cameras.address,
            meshes: self.meshes.0,
            instances: self.transforms[frame as usize % 3].address,
            previous_instances: self.transforms[(frame as usize + 2) % 3].address,
            radius: budget.radius,
            scene_scale: budget.scene_scale,
            mesh_count: self.meshes.1,
            samples: budget.samples,
            fresh: budget.fresh,
            cap: budget.cap,
            settled_every: budget.settled_every,
            frame,
            accept: budget.accept | if self.remembers { HAS_HISTORY } else { 0 },
            plane_tolerance: 0.01,
            normal_tolerance: 0.9,
            per_pixel: budget.per_pixel as u32,
            // Occlusion is the geometry within `radius` of a point: only there can it change.
            moved: moved.map_or([0.0; 4], |(centre, reach)| centre.extend(reach + budget.radius).to_array()),
            near_motion_cap: budget.near_motion_cap,
            pass: if list.is_some() { LISTING } else { INLINE },
            fresh_pixels: list.map_or(0, |list| list.address),
        };
        let history = self.history_barriers();
        let work = |cb| {
            let stage = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
            let none = vk::DependencyFlags::empty();
            // The previous frame wrote the image read now and read the image written now: its
            // writes must be visible, and its reads done, before these rays start.
            unsafe { vk.device.cmd_pipeline_barrier(cb, stage, stage, none, &history.0, &[], &history.1) };
            let Some(list) = list.map(|list| *list.buffer) else {
                self.pipeline.trace(vk, cb, bytemuck::bytes_of(&push), targets.extent);
                return;
            };
            // The list starts empty: its count (the first 4 bytes) set to 0 by a transfer.
            let (read, write) = (vk::AccessFlags::SHADER_READ, vk::AccessFlags::SHADER_WRITE);
            let (transfer, filled) = (vk::PipelineStageFlags::TRANSFER, vk::AccessFlags::TRANSFER_WRITE);
            let count = |from, to| {
                vk::BufferMemoryBarrier::default()
                    .src_access_mask(from)
                    .dst_access_mask(to)
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .buffer(list)
                    .size(4)
            };
            unsafe {
                // The previous frame's launches read the count and added to it: done, and their
                // writes out of the way, before the fill writes it.
                vk.device.cmd_pipeline_barrier(cb, stage, transfer, none, &[], &[count(write, filled)], &[]);
                vk.device.cmd_fill_buffer(cb, list, 0, 4, 0);
                // The 0 visible to the first launch, whose atomicAdd reads the count and writes it.
                let zeroed = count(filled, read | write);
                vk.device.cmd_pipeline_barrier(cb, transfer, stage, none, &[], &[zeroed], &[]);
            }
            self.pipeline.trace(vk, cb, bytemuck::bytes_of(&push), targets.extent);
            // The first launch's writes visible to the second: the list, its count and the
            // tallies at 0, which it reads and adds to. And the texels the first wrote finished
            // before the second writes others of the same two images: no texel is written twice,
            // but tools that check hazards track an image whole.
            let listed = vk::MemoryBarrier::default().src_access_mask(write).dst_access_mask(read | write);
            unsafe { vk.device.cmd_pipeline_barrier(cb, stage, stage, none, &[listed], &[], &[]) };
            // The first launch's size again, one ray per invocation: a size the device is known
            // to launch, and the picture's size, which the shader reads from the launch. Where
            // the listed pixels have more rays than that (after a cut, every pixel that shows a
            // surface is listed), each invocation steps on by the launch's size; where fewer,
            // the invocations past them return at once. vkCmdTraceRaysIndirectKHR could size the
            // launch from the count, but it needs a feature (rayTracingPipelineTraceRaysIndirect)
            // that not every device has.
            let second = TemporalRays { pass: LISTED, ..push };
            self.pipeline.trace(vk, cb, bytemuck::bytes_of(&second), targets.extent);
        };
        // `released`: GL handed this frame's ids over when it drew them, at the end of the
        // previous frame (`Passes::draw`).
        match released {
            true => hand_over_released(apis, targets, timestamps, work)?,
            false => hand_over_around(apis, targets, timestamps, work)?,
        }
        self.images_used = true;
        self.previous_camera = Some(*camera);
        self.remembers = true;
        self.written = 1 - self.written;
        Ok(())
    }
    // ANCHOR_END: frame

    /// Before a frame: the first time, both images from undefined; after, one global barrier.
    fn history_barriers(&self) -> (Vec<vk::MemoryBarrier<'static>>, Vec<vk::ImageMemoryBarrier<'static>>) {
        let (read, write) = (vk::AccessFlags::SHADER_READ, vk::AccessFlags::SHADER_WRITE);
        if self.images_used {
            let barrier = vk::MemoryBarrier::default().src_access_mask(write).dst_access_mask(read | write);
            (vec![barrier], vec![])
        } else {
            let general = vk::ImageLayout::GENERAL;
            (vec![], self.history.iter().map(|h| first_use(*h.image, general, read | write)).collect())
        }
    }

    /// The history the last frame wrote, read back (for the checks): per pixel the mean
    /// visibility, the rays it holds, and the instance + 1 (0: background).
    pub fn read_history(
        &self,
        vk: &VulkanContext,
        commands: &common::base::commands::Commands,
    ) -> Result<Vec<Texel>> {
        let last = &self.history[1 - self.written];
        let extent = last.extent;
        let bytes = extent.width as u64 * extent.height as u64 * 16;
        let host = HostBuffer::new(vk, bytes, vk::BufferUsageFlags::TRANSFER_DST)?;
        let stage = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
        let transfer = vk::PipelineStageFlags::TRANSFER;
        let none = vk::DependencyFlags::empty();
        let (general, source) = (vk::ImageLayout::GENERAL, vk::ImageLayout::TRANSFER_SRC_OPTIMAL);
        let ignored = vk::QUEUE_FAMILY_IGNORED;
        let (write, read) = (vk::AccessFlags::SHADER_WRITE, vk::AccessFlags::TRANSFER_READ);
        // To the copy's layout once the rays have written it, and back before the next frame's.
        let to_copy = image_barrier(*last.image, (general, source), (write, read), (ignored, ignored));
        let back = image_barrier(
            *last.image,
            (source, general),
            (vk::AccessFlags::NONE, vk::AccessFlags::NONE),
            (ignored, ignored),
        );
        commands.run_once(vk, |cb| unsafe {
            vk.device.cmd_pipeline_barrier(cb, stage, transfer, none, &[], &[], &[to_copy]);
            copy_image_to_buffer(vk, cb, *last.image, source, extent, *host.buffer);
            transfers_to_host(vk, cb);
            vk.device.cmd_pipeline_barrier(cb, transfer, stage, none, &[], &[], &[back]);
        })?;
        let word = |b: &[u8]| u32::from_ne_bytes(b.try_into().unwrap());
        Ok(host
            .bytes()
            .chunks_exact(16)
            .map(|t| {
                let x = word(&t[0..4]);
                Texel { mean: (x >> 16) as f32 / 65535.0, rays: x & 0xFFFF, instance: word(&t[12..16]) }
            })
            .collect())
    }
}

// ANCHOR: halves
/// GL's half of chapter 12's hand-over alone (`fast_frame::trace::hand_over_around`): the ids it
/// just drew, and the surface once it has had it, released to Vulkan, whose work comes later,
/// through [`hand_over_released`]: this chapter draws the next frame's ids before it waits for
/// this frame's trace.
pub fn release_to_vulkan(apis: Apis, targets: &Targets) {
    traced(targets, |images| common::rt::ao::release_to_vulkan(apis, images));
}

/// The rest of chapter 12's hand-over, once GL has released the images ([`release_to_vulkan`]).
fn hand_over_released(
    apis: Apis,
    targets: &Targets,
    timestamps: Option<&Timestamps>,
    work: impl FnOnce(vk::CommandBuffer),
) -> Result<()> {
    traced(targets, |images| common::rt::ao::hand_over_released(apis, images, timestamps, || {}, work))?;
    targets.gl_has_surface.set(true);
    Ok(())
}
// ANCHOR_END: halves

/// One pixel of the history, as [`TemporalTracer::read_history`] reads it.
#[derive(Clone, Copy, Debug)]
pub struct Texel {
    pub mean: f32,
    pub rays: u32,
    pub instance: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::base::shader_block::{assert_matches_spirv, rust_block};

    #[test]
    fn temporal_rays_match_the_glsl_block() {
        let rust = rust_block!(TemporalRays {
            cameras,
            meshes,
            instances,
            previous_instances,
            radius,
            scene_scale,
            mesh_count,
            samples,
            fresh,
            cap,
            settled_every,
            frame,
            accept,
            plane_tolerance,
            normal_tolerance,
            per_pixel,
            moved,
            near_motion_cap,
            pass,
            fresh_pixels,
        });
        assert_matches_spirv(RAYGEN, "TemporalRays", rust);
        let rust = rust_block!(Cameras {
            inverse_view_projection,
            previous_view_projection,
            previous_inverse_view_projection,
            eye,
            forward,
            previous_eye,
            previous_forward,
        });
        assert_matches_spirv(RAYGEN, "Cameras", rust);
    }
}
