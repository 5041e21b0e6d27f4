//! Ray-traced ambient occlusion from GL's G-buffers, accumulated over frames (taught in chapter
//! 07; chapter 08 composites with it).

use crate::base::commands::{first_use, image_barrier};
use crate::base::gl::GlContext;
use crate::base::vulkan::VulkanContext;
use crate::clocks::timestamps::{Timestamps, timed};
use crate::instruments::report::Report;
use crate::interop::handoff::{Apis, HandOver, Handoff};
use crate::interop::{SharedFormat, SharedImage, acquire_from_gl, release_to_gl};
use crate::rt::accel::GpuAllocator;
use crate::rt::raytrace::{RayPipeline, RayShaders, raygen_bindings};
use crate::scene::gbuffer::GBuffers;
use anyhow::Result;
use ash::vk;
use glow::HasContext;

const RAYGEN: &[u8] = include_bytes!("../../../shaders/ao.rgen.spv");
const MISS: &[u8] = include_bytes!("../../../shaders/miss.rmiss.spv");
/// The AO pipeline's two shaders (chapter 16 adds an any-hit shader to them).
pub const AO_SHADERS: RayShaders<'static> = RayShaders { raygen: RAYGEN, miss: MISS };

/// The ambient-occlusion flags (chapters 07 and 08).
#[derive(clap::Args, Debug, Clone)]
pub struct AoArgs {
    /// AO rays per pixel per frame, 0-256 (0: no rays, visibility 1 everywhere).
    #[arg(long, default_value_t = 16, value_parser = crate::base::cli::number::<u32>(0..=256))]
    pub samples: u32,
    /// How far an occluder counts, in world units, 0 to 1000000 [default: 5% of the scene's
    /// diagonal] (0: nothing can occlude, no rays).
    #[arg(long, value_parser = crate::base::cli::number::<f32>(0.0..=1e6), allow_negative_numbers = true)]
    pub radius: Option<f32>,
    /// Contrast: the picture shows visibility to this power (1-3).
    #[arg(long, default_value_t = 2.0, value_parser = crate::base::cli::number::<f32>(1.0..=3.0), allow_negative_numbers = true)]
    pub power: f32,
    /// Stop accumulating once a pixel has this many rays (1 to 2^30).
    #[arg(long, default_value_t = 4096, value_parser = crate::base::cli::number::<u32>(1..=1 << 30))]
    pub max_samples: u32,
}

impl AoArgs {
    // ANCHOR: radius
    /// The occlusion radius: `--radius`, or 5% of the scene's diagonal. A fixed default suits
    /// one scene only: the bunny is 0.15 units tall, the default scene 20 wide.
    pub fn radius(&self, scene: &crate::scene::Scene) -> Result<f32> {
        let radius = self.radius.unwrap_or(0.05 * scene.size());
        anyhow::ensure!(
            radius >= 0.0 && radius.is_finite(),
            "--radius {radius}: must be a distance of 0 or more, in world units (the scene is {} across)",
            scene.size()
        );
        anyhow::ensure!((1.0..=3.0).contains(&self.power), "--power {}: choose between 1 and 3", self.power);
        Ok(radius)
    }
    // ANCHOR_END: radius

    /// [`AoArgs::radius`], for a chapter that traces occlusion every frame (09, 10): refused
    /// where it would leave nothing to trace ([`nothing_to_trace`]).
    pub fn radius_to_trace(&self, scene: &crate::scene::Scene) -> Result<f32> {
        let radius = self.radius(scene)?;
        if let Some(reason) = nothing_to_trace(self.samples, radius) {
            anyhow::bail!("{reason}: this chapter traces occlusion every frame; give it rays and a radius");
        }
        Ok(radius)
    }
}

/// The checks every chapter that traces makes of the AO image as GL holds it: every value a
/// fraction of rays, in [0, 1], and background pixels (position w = 0) exactly 1.
pub fn check_occlusion(
    report: &mut crate::instruments::report::Report,
    gl: &glow::Context,
    gbuffers: &GBuffers,
    tracer: &AoTracer,
) {
    let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
    let positions = crate::instruments::output::read_texture_f32(gl, gbuffers.textures()[0], w, h, 4);
    let visibility = crate::instruments::output::read_texture_f32(gl, *tracer.image.texture.texture, w, h, 1);
    report.check("ao_within_0_and_1", visibility.iter().all(|v| (0.0..=1.0).contains(v)));
    let mut background = (0..visibility.len()).filter(|&i| positions[i * 4 + 3] <= 0.0);
    report.check("background_unoccluded", background.all(|i| visibility[i] == 1.0));
}

/// Why no ray needs tracing, if none does: 0 samples asks for none, and within a radius of 0
/// nothing can occlude. Visibility is then exactly 1 everywhere, without a ray.
pub fn nothing_to_trace(samples: u32, radius: f32) -> Option<&'static str> {
    match (samples, radius) {
        (0, _) => Some("--samples 0"),
        (_, 0.0) => Some("--radius 0"),
        _ => None,
    }
}

// ANCHOR: rays_this_frame
/// Rays a pixel to trace this frame: `per_frame` (`--samples`), and no more than `max` in all.
/// A window refines instead (`refine`): the first frame after a change traces one ray a pixel, and
/// each frame after it as many as all the frames before, up to `per_frame` (1, 1, 2, 4, 8, 16,
/// 16, ...). Its first picture then costs one ray a pixel, not `per_frame`, and the running mean
/// passes through the same rays in the same order: only their grouping into frames differs.
pub fn rays_this_frame(per_frame: u32, accumulated: u32, max: u32, refine: bool) -> u32 {
    let this_frame = if refine { per_frame.min(accumulated.max(1)) } else { per_frame };
    this_frame.min(max.saturating_sub(accumulated))
}
// ANCHOR_END: rays_this_frame

/// The AO pipeline, the shared R32F image it accumulates into, and how far it has got. Dropped,
/// the image goes first (GL's side, then Vulkan's), then the pipeline; the GPU must be done
/// with both.
pub struct AoTracer {
    /// The running mean of visibility: Vulkan writes it, GL samples it.
    pub image: SharedImage,
    pub pipeline: RayPipeline,
    /// Rays per pixel already in the running mean; 0 starts it again.
    pub accumulated: u32,
    /// Has GL had the image yet? A new one starts undefined, never handed over.
    gl_has_image: bool,
    /// Filled with 1 by GL instead of traced (`fill_unoccluded`).
    unoccluded: bool,
    /// Images the rays sample (chapter 16's textures), handed over with every trace.
    pub sampled: Vec<Sampled>,
}

impl AoTracer {
    pub fn new(
        vk: &VulkanContext,
        gl: &GlContext,
        allocator: &GpuAllocator,
        tlas: vk::AccelerationStructureKHR,
        gbuffers: &GBuffers,
    ) -> Result<Self> {
        // ANCHOR: pipeline
        // Bindings 0-3, as chapter 06's: the TLAS, positions, normals, and the AO image.
        let image = vk::DescriptorType::STORAGE_IMAGE;
        let bindings =
            raygen_bindings(&[vk::DescriptorType::ACCELERATION_STRUCTURE_KHR, image, image, image]);
        let pipeline = RayPipeline::new(vk, allocator, AO_SHADERS, &bindings, size_of::<AoRays>() as u32)?;
        pipeline.write_tlas(vk, 0, tlas);
        // ANCHOR_END: pipeline
        Self::with_pipeline(vk, gl, pipeline, gbuffers)
    }

    /// The bindings [`AoTracer::new`]'s pipeline has (0-3), for a pipeline that adds to them.
    pub fn bindings() -> Vec<vk::DescriptorSetLayoutBinding<'static>> {
        let image = vk::DescriptorType::STORAGE_IMAGE;
        raygen_bindings(&[vk::DescriptorType::ACCELERATION_STRUCTURE_KHR, image, image, image])
    }

    /// A tracer on a pipeline made elsewhere (chapter 16's, with an any-hit shader), whose
    /// bindings 0-3 are [`AoTracer::bindings`], its TLAS already written.
    pub fn with_pipeline(
        vk: &VulkanContext,
        gl: &GlContext,
        pipeline: RayPipeline,
        gbuffers: &GBuffers,
    ) -> Result<Self> {
        let image = Self::image(vk, gl, &pipeline, gbuffers)?; // on failure `pipeline` is dropped
        let (accumulated, gl_has_image, unoccluded, sampled) = (0, false, false, Vec::new());
        Ok(AoTracer { image, pipeline, accumulated, gl_has_image, unoccluded, sampled })
    }

    // ANCHOR: image
    /// The AO image, as large as the G-buffers, and the descriptors that point at all three.
    fn image(
        vk: &VulkanContext,
        gl: &GlContext,
        pipeline: &RayPipeline,
        gbuffers: &GBuffers,
    ) -> Result<SharedImage> {
        // One float per pixel. Vulkan writes it (STORAGE), GL samples it (SAMPLED).
        let usage = vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::SAMPLED;
        let image = SharedImage::new(vk, gl, SharedFormat::R32F, usage, gbuffers.extent)?;
        pipeline.write_storage_image(vk, 1, *gbuffers.images[0].view);
        pipeline.write_storage_image(vk, 2, *gbuffers.images[1].view);
        pipeline.write_storage_image(vk, 3, *image.view);
        Ok(image)
    }
    // ANCHOR_END: image

    /// Visibility 1 everywhere without tracing (see [`nothing_to_trace`]): GL clears the AO
    /// image to 1 through a framebuffer of its own, once per image. GL uses the image first, so
    /// Vulkan hands it over (in GENERAL) before, as it does the G-buffers; it stays GL's until a
    /// trace takes it.
    pub fn fill_unoccluded(&mut self, vk: &VulkanContext, gl: &GlContext, handoff: &Handoff) -> Result<()> {
        if self.unoccluded {
            return Ok(());
        }
        anyhow::ensure!(!self.gl_has_image, "fill_unoccluded: the AO image was already traced into");
        let new = [(*self.image.image, *self.image.texture.texture)];
        crate::interop::hand_new_images_to_gl(vk, gl, handoff, &new)?;
        let framebuffer =
            crate::base::gl::create(&gl.gl, "glCreateFramebuffers to fill the AO image", |gl| unsafe {
                gl.create_named_framebuffer()
            })?;
        unsafe {
            let gl = &gl.gl;
            gl.named_framebuffer_texture(
                Some(*framebuffer),
                glow::COLOR_ATTACHMENT0,
                Some(*self.image.texture.texture),
                0,
            );
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*framebuffer));
            gl.clear_buffer_f32_slice(glow::COLOR, 0, &[1.0, 0.0, 0.0, 0.0]);
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
        }
        drop(framebuffer); // filled: the image keeps the value
        self.gl_has_image = true;
        self.unoccluded = true;
        Ok(())
    }

    /// Starts the running mean again: the camera moved or a parameter changed, so the old mean no
    /// longer describes the picture. The next frame's samples get weight 1.
    pub fn reset(&mut self) {
        self.accumulated = 0;
    }

    /// The running mean restarted and one frame of `rays` traced and waited for, for measuring
    /// (chapters 09 and 10 trace the same rays through two structures): the visibility GL reads
    /// back, in memory order, and the trace's GPU time when there are `timestamps`.
    pub fn trace_once(
        &mut self,
        apis: Apis,
        gbuffers: &GBuffers,
        rays: AoRays,
        timestamps: Option<&Timestamps>,
    ) -> Result<(Vec<f32>, Option<f64>)> {
        self.reset();
        self.trace(apis, gbuffers, rays, timestamps)?;
        let vk = apis.vk;
        apis.commands.wait(vk, "vkWaitForFences after a measured trace")?;
        let ms = timestamps.map(|t| t.read_ms(vk)).transpose()?;
        let extent = gbuffers.extent;
        let texture = *self.image.texture.texture;
        Ok((
            crate::instruments::output::read_texture_f32(
                &apis.gl.gl,
                texture,
                extent.width,
                extent.height,
                1,
            ),
            ms,
        ))
    }

    /// The GPU times of [`trace_once`](Self::trace_once)'s two traces in chapters 09 and 10, when
    /// there are timestamps: through the structure as the frames kept it (`trace_after_<kept>`)
    /// and through a rebuilt one (`trace_after_rebuild`), reported, and said on stderr with their
    /// ratio, each named as `said` names it.
    pub fn report_traces(report: &mut Report, kept: &str, said: [&str; 2], ms: (Option<f64>, Option<f64>)) {
        if let (Some(kept_ms), Some(rebuilt_ms)) = ms {
            report.time_ms(&format!("trace_after_{kept}"), kept_ms);
            report.time_ms("trace_after_rebuild", rebuilt_ms);
            let ratio = kept_ms / rebuilt_ms;
            eprintln!("{} {kept_ms:.3} ms, {} {rebuilt_ms:.3} ms ({ratio:.2}x)", said[0], said[1]);
        }
    }

    /// After the G-buffers were made anew (a resize): a new AO image of their size, the
    /// descriptors pointed at the new images, and accumulation from scratch. The GPU must be
    /// done with the old images.
    pub fn resize(&mut self, vk: &VulkanContext, gl: &GlContext, gbuffers: &GBuffers) -> Result<()> {
        let image = Self::image(vk, gl, &self.pipeline, gbuffers)?;
        drop(std::mem::replace(&mut self.image, image));
        self.gl_has_image = false;
        self.unoccluded = false;
        self.accumulated = 0;
        Ok(())
    }

    // ANCHOR: frame
    /// One frame: GL hands over the G-buffers it just drew (and the AO image), Vulkan adds
    /// `rays.samples` rays per pixel to the running mean and hands everything back, and GL is
    /// told to wait for that before it samples the AO. `rays.accumulated` is filled in here.
    pub fn trace(
        &mut self,
        apis: Apis,
        gbuffers: &GBuffers,
        mut rays: AoRays,
        timestamps: Option<&Timestamps>,
    ) -> Result<()> {
        rays.accumulated = self.accumulated;
        // Positions and normals in (the albedo stays GL's: Vulkan does not use it), the AO out.
        let images = Traced {
            inputs: &[&gbuffers.images[0], &gbuffers.images[1]],
            output: &self.image,
            gl_has_output: self.gl_has_image,
            sampled: &self.sampled,
        };
        let (vk, pipeline, extent) = (apis.vk, &self.pipeline, gbuffers.extent);
        hand_over_around(
            apis,
            &images,
            timestamps,
            || {},
            |cb| pipeline.trace(vk, cb, bytemuck::bytes_of(&rays), extent),
        )?;
        self.gl_has_image = true;
        self.accumulated += rays.samples;
        Ok(())
    }
    // ANCHOR_END: frame
}

// ANCHOR: record
/// The shared images of one frame's Vulkan work between GL's passes: `inputs` GL has just drawn
/// and Vulkan only reads (chapter 07's positions and normals, chapter 12's ids), and `output`,
/// the running mean Vulkan reads and updates and GL samples (the AO image, chapter 12's surface).
pub struct Traced<'a> {
    pub inputs: &'a [&'a SharedImage],
    pub output: &'a SharedImage,
    /// Has GL had `output` yet? A new one starts undefined, never handed over.
    pub gl_has_output: bool,
    /// Images both sides only sample, every level (chapter 16's textures): they travel with the
    /// rest so that Vulkan owns them while its rays read them, and GL while it draws.
    pub sampled: &'a [Sampled],
}

/// A shared image with a mip chain that both APIs only read (chapter 16's textures).
#[derive(Clone, Copy, Debug)]
pub struct Sampled {
    pub image: vk::Image,
    pub texture: glow::Texture,
}

/// The layouts a [`Sampled`] image travels in: read-only both ways (GENERAL on the host path, as
/// every hand-over there). Its upload leaves it in `.to_gl`; Vulkan's descriptors name `.to_vulkan`.
pub fn sampled_layouts(handoff: &Handoff) -> HandOver {
    let read_only = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL;
    handoff.hand_over(read_only, read_only)
}

/// One frame of Vulkan work between GL's passes: GL hands over the inputs it just drew (and the
/// output, once it has had it), Vulkan records `work` between the barriers that take them from
/// GL and give them back, and GL is told to wait for that before it samples the output.
/// `between` runs once Vulkan's work is submitted and before GL is told to wait (chapter 12's
/// `bench --probe overlap`). Chapter 07's tracer and chapter 12's both hand over through it.
pub fn hand_over_around(
    apis: Apis,
    images: &Traced,
    timestamps: Option<&Timestamps>,
    between: impl FnOnce(),
    work: impl FnOnce(vk::CommandBuffer),
) -> Result<()> {
    release_to_vulkan(apis, images);
    hand_over_released(apis, images, timestamps, between, work)
}

/// The layouts the images travel in: the inputs come to Vulkan in GENERAL, the layout storage
/// images need, and go back as attachments for GL's next draw; the output is sampled by GL. On
/// the host path `hand_over` makes all of them GENERAL both ways (GL moves no layout there).
fn layouts(handoff: &Handoff) -> (HandOver, HandOver) {
    let attachment = vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL;
    let read_only = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL;
    (handoff.hand_over(vk::ImageLayout::GENERAL, attachment), handoff.hand_over(read_only, read_only))
}

/// GL's textures of `images`, the inputs first, then the output (when `with_output`), then the
/// sampled ones, and each one's layout as GL names it: the first for Vulkan, the second for GL.
fn textures(
    images: &Traced,
    (inputs, output): (HandOver, HandOver),
    sampled: HandOver,
    with_output: bool,
) -> (Vec<glow::Texture>, [Vec<u32>; 2]) {
    let mut textures: Vec<glow::Texture> = images.inputs.iter().map(|i| *i.texture.texture).collect();
    let mut layouts = vec![inputs.gl(); images.inputs.len()];
    if with_output {
        textures.push(*images.output.texture.texture);
        layouts.push(output.gl());
    }
    textures.extend(images.sampled.iter().map(|s| s.texture));
    layouts.extend(images.sampled.iter().map(|_| sampled.gl()));
    let (to_vulkan, to_gl) = layouts.into_iter().unzip();
    (textures, [to_vulkan, to_gl])
}

/// GL's half of the hand-over alone: the inputs it just drew (and the output, once it has had
/// it) released to Vulkan, whose work may be recorded later, by [`hand_over_released`].
pub fn release_to_vulkan(apis: Apis, images: &Traced) {
    let sampled = sampled_layouts(apis.handoff);
    // The output only once GL has had it.
    let (textures, [to_vulkan, _]) = textures(images, layouts(apis.handoff), sampled, images.gl_has_output);
    apis.handoff.gl_release(apis.gl, &textures, &to_vulkan);
}

/// The rest of [`hand_over_around`], once GL has released the images ([`release_to_vulkan`]).
pub fn hand_over_released(
    apis: Apis,
    images: &Traced,
    timestamps: Option<&Timestamps>,
    between: impl FnOnce(),
    work: impl FnOnce(vk::CommandBuffer),
) -> Result<()> {
    let Apis { vk, gl, handoff, commands } = apis;
    let (layouts, sampled) = (layouts(handoff), sampled_layouts(handoff));
    let (textures, [_, to_gl]) = textures(images, layouts, sampled, true);
    let cb = commands.begin(vk)?;
    unsafe { record(vk, cb, images, (layouts, sampled), timestamps, work) };
    let stage = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
    commands.submit(vk, handoff.vulkan_waits_on().map(|s| (s, stage)), handoff.vulkan_signals())?;
    between();
    handoff.gl_acquire(vk, gl, *commands.fence, &textures, &to_gl)
}

/// Take the inputs and the output from GL, record `work`, give them back.
unsafe fn record(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    images: &Traced,
    ((input_layouts, output_layouts), sampled): ((HandOver, HandOver), HandOver),
    timestamps: Option<&Timestamps>,
    work: impl FnOnce(vk::CommandBuffer),
) {
    let general = vk::ImageLayout::GENERAL;
    let (read, write) = (vk::AccessFlags::SHADER_READ, vk::AccessFlags::SHADER_WRITE);
    let output = if images.gl_has_output {
        // Its contents are the running mean so far, which the shader reads and updates.
        acquire_from_gl(vk, images.output, output_layouts.to_vulkan, general, read | write)
    } else {
        // Never GL's yet: undefined contents, which the first frame overwrites (weight 1).
        first_use(*images.output.image, general, read | write)
    };
    let inputs = images.inputs.iter();
    let mut acquire: Vec<_> =
        inputs.clone().map(|i| acquire_from_gl(vk, i, input_layouts.to_vulkan, general, read)).collect();
    acquire.push(output);
    // Every level of each sampled image, read by the rays; no layout changes hands.
    let families = (vk::QUEUE_FAMILY_EXTERNAL, vk.queue_family_index);
    let all_levels = |mut barrier: vk::ImageMemoryBarrier<'static>| {
        barrier.subresource_range.level_count = vk::REMAINING_MIP_LEVELS;
        barrier
    };
    let (to_vulkan, to_gl) = (sampled.to_vulkan, sampled.to_gl);
    for s in images.sampled {
        let barrier = image_barrier(s.image, (to_vulkan, to_vulkan), (vk::AccessFlags::NONE, read), families);
        acquire.push(all_levels(barrier));
    }
    // Back to GL: the inputs for the next frame's draw (nothing written here), the output to
    // sample, its writes made available.
    let none = vk::AccessFlags::NONE;
    let mut release: Vec<_> =
        inputs.map(|i| release_to_gl(vk, i, general, input_layouts.to_gl, none)).collect();
    release.push(release_to_gl(vk, images.output, general, output_layouts.to_gl, write));
    let families = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
    for s in images.sampled {
        release.push(all_levels(image_barrier(s.image, (to_vulkan, to_gl), (none, none), families)));
    }
    let stage = vk::PipelineStageFlags::RAY_TRACING_SHADER_KHR;
    let none = vk::DependencyFlags::empty();
    unsafe {
        // From the stage the submission waits for GL at: the acquire must follow GL's signal.
        vk.device.cmd_pipeline_barrier(cb, stage, stage, none, &[], &[], &acquire);
        timed(vk, cb, timestamps, stage, || work(cb));
        let bottom = vk::PipelineStageFlags::BOTTOM_OF_PIPE;
        vk.device.cmd_pipeline_barrier(cb, stage, bottom, none, &[], &[], &release);
    }
}
// ANCHOR_END: record

// ANCHOR: ao_rays
/// The push constants of `shaders/ao.rgen` (std430: four 4-byte members, 16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AoRays {
    /// Rays per pixel this frame.
    pub samples: u32,
    /// Rays per pixel already in the running mean (filled in by `AoTracer::trace`).
    pub accumulated: u32,
    /// How far an occluder counts, in world units.
    pub radius: f32,
    /// The largest coordinate of the re-centred scene, half its diagonal: the ray offset scales
    /// with it (`Scene::size() / 2`).
    pub scene_scale: f32,
}
// ANCHOR_END: ao_rays

#[cfg(test)]
mod rays_tests {
    use super::*;

    #[test]
    fn ao_rays_match_the_glsl_block() {
        use crate::base::shader_block::{assert_matches_spirv, rust_block};
        assert_matches_spirv(
            RAYGEN,
            "AoRays",
            rust_block!(AoRays { samples, accumulated, radius, scene_scale }),
        );
    }

    /// The rays of each frame, with the running total after it, until `max` is reached.
    fn frames(per_frame: u32, max: u32, refine: bool) -> Vec<(u32, u32)> {
        let (mut accumulated, mut frames) = (0, Vec::new());
        while accumulated < max && frames.len() < 12 {
            let rays = rays_this_frame(per_frame, accumulated, max, refine);
            accumulated += rays;
            frames.push((rays, accumulated));
        }
        frames
    }

    #[test]
    fn a_window_refines_from_one_ray() {
        let totals = |frames: Vec<(u32, u32)>| frames.iter().map(|f| f.1).collect::<Vec<_>>();
        // Each frame doubles the total until a frame holds --samples.
        assert_eq!(totals(frames(16, 64, true)), [1, 2, 4, 8, 16, 32, 48, 64]);
        // Headless, every frame traces --samples; both stop at --max-samples exactly.
        assert_eq!(totals(frames(16, 40, false)), [16, 32, 40]);
        assert_eq!(totals(frames(16, 20, true)), [1, 2, 4, 8, 16, 20]);
        assert_eq!(totals(frames(1, 3, true)), [1, 2, 3]);
        assert_eq!(totals(frames(3, 12, true)), [1, 2, 4, 7, 10, 12]);
        // --samples 0 traces nothing, refining or not.
        assert_eq!(rays_this_frame(0, 0, 64, true), 0);
        assert_eq!(rays_this_frame(0, 0, 64, false), 0);
    }
}
