//! Chapter 16's lesson, Vulkan's half and GL's import: every picture becomes an exportable
//! image with its whole mip chain, filled from a staging buffer, its levels made on the GPU by
//! blits, and handed to GL, which imports the memory with the same number of levels.

use crate::scene::Picture;
use anyhow::Result;
use ash::vk;
use common::VulkanContext;
use common::base::commands::{Commands, HostBuffer, image_barrier};
use common::base::gl::{self, GlContext, OPTIMAL_TILING_EXT, TEXTURE_TILING_EXT};
use common::base::owned::{Owned, create};
use common::clocks::timestamps::Timestamps;
use common::instruments::fail;
use common::interop::exportable::{self, Dedicated, HANDLE_TYPE};
use common::interop::handoff::Handoff;
use common::interop::{SharedTexture, import_memory};
use common::rt::ao::{Sampled, sampled_layouts};
use glow::HasContext;

// ANCHOR: format
/// Colour as the files store it, sRGB-encoded: both APIs decode it to linear light when they
/// sample, before filtering. Alpha is linear in either. (GL's twin of the Vulkan format.)
pub const FORMAT: vk::Format = vk::Format::R8G8B8A8_SRGB;
pub const GL_FORMAT: u32 = glow::SRGB8_ALPHA8;
// ANCHOR_END: format

/// One level as the CPU holds it: width, height and texels (RGBA8, rows top first).
type Level = (u32, u32, Vec<u8>);

/// One picture in both APIs: GL's texture (dropped first), then Vulkan's view, image and memory.
pub struct Texture {
    pub gl: SharedTexture,
    pub view: Owned<vk::ImageView>,
    pub image: Owned<vk::Image>,
    pub memory: exportable::ExportableMemory,
    pub width: u32,
    pub height: u32,
    pub levels: u32,
}

impl Texture {
    /// Both names of the image, for the frames' hand-overs.
    pub fn sampled(&self) -> Sampled {
        Sampled { image: *self.image, texture: *self.gl.texture }
    }
}

// ANCHOR: levels
/// How many levels a full chain of a `width` x `height` image has: halving each side (rounding
/// down, never below 1) until both are 1. 37x23 has 6: 37x23, 18x11, 9x5, 4x2, 2x1, 1x1.
pub fn level_count(width: u32, height: u32) -> u32 {
    32 - width.max(height).leading_zeros()
}

/// Level `level`'s size.
pub fn level_size(width: u32, height: u32, level: u32) -> (u32, u32) {
    ((width >> level).max(1), (height >> level).max(1))
}
// ANCHOR_END: levels

/// What the upload made and how: the textures, Vulkan's own copy of every level (for the
/// chapter's check against GL's), and whether the levels were blitted on the GPU.
pub struct Uploaded {
    pub textures: Vec<Texture>,
    pub vulkan_levels: Vec<Vec<Vec<u8>>>,
    pub blitted: bool,
    /// GPU milliseconds to make every level (the copies from staging and the blits), and to
    /// copy every level back: the same bytes written each time. `None` without timestamps.
    pub gpu_ms: Option<(f64, f64)>,
}

/// Every picture as a [`Texture`], uploaded in one submission and handed to GL. A picture larger
/// than both APIs allow is halved until it fits, and said so.
pub fn upload(
    vk: &VulkanContext,
    gl: &GlContext,
    handoff: &Handoff,
    pictures: &[Picture],
) -> Result<Uploaded> {
    let largest = largest_side(vk, gl)?;
    let blit = can_blit(vk);
    if !blit {
        eprintln!(
            "textures: {} cannot blit {FORMAT:?} with linear filtering (its format features lack \
             BLIT_SRC, BLIT_DST or SAMPLED_IMAGE_FILTER_LINEAR): the levels are made on the CPU",
            vk.info.name
        );
    }
    let mut textures = Vec::new();
    let mut chains = Vec::new();
    for picture in pictures {
        let chain = chain_of(picture, largest, blit);
        let (width, height) = (chain[0].0, chain[0].1);
        textures.push(Texture::new(vk, gl, width, height, level_count(width, height))?);
        chains.push(chain);
    }
    // ANCHOR: staging
    // Every level the CPU has (level 0 alone when the GPU makes the rest), then room for
    // Vulkan's copy of every level back, in one host-visible buffer.
    let bytes = |chain: &[Level]| chain.iter().map(|l| l.2.len() as u64).sum::<u64>();
    let all_levels: u64 = textures.iter().map(|t| chain_bytes(t.width, t.height, t.levels)).sum();
    let upload: u64 = chains.iter().map(|c| bytes(c)).sum();
    let usage = vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST;
    let mut staging = HostBuffer::new(vk, (upload + all_levels).max(4), usage)?;
    let mut at = 0;
    for level in chains.iter().flatten() {
        staging.bytes_mut()[at..at + level.2.len()].copy_from_slice(&level.2);
        at += level.2.len();
    }
    // ANCHOR_END: staging
    let stamps = Timestamps::with_count(vk, 3)?;
    let commands = Commands::new(vk)?;
    // The semaphores' round trip, as for any image GL has not had yet: GL signals first (it has
    // used none of these), Vulkan's submission waits for that and signals back.
    handoff.gl_release(gl, &[], &[]);
    let cb = commands.begin(vk)?;
    let final_layout = sampled_layouts(handoff).to_gl;
    // Timestamps before, between and after the two halves: the levels made, then copied back.
    let stamp = |index| {
        if let Some(t) = &stamps {
            t.write(vk, cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, index);
        }
    };
    if let Some(t) = &stamps {
        t.reset(vk, cb);
    }
    stamp(0);
    let mut from = 0;
    for (texture, chain) in textures.iter().zip(&chains) {
        unsafe { record_levels(vk, cb, texture, *staging.buffer, (from, chain)) };
        from += bytes(chain);
    }
    stamp(1);
    let mut back = upload;
    for (texture, chain) in textures.iter().zip(&chains) {
        let made = chain.len() as u32;
        unsafe { record_copy_back(vk, cb, texture, (*staging.buffer, back), made, final_layout) };
        back += chain_bytes(texture.width, texture.height, texture.levels);
    }
    stamp(2);
    let all = vk::PipelineStageFlags::ALL_COMMANDS;
    commands.submit(vk, handoff.vulkan_waits_on().map(|s| (s, all)), handoff.vulkan_signals())?;
    commands.wait(vk, "vkWaitForFences after uploading the textures")?;
    // GL's half: its wait names every texture's layout, so that GL knows it before its first use.
    let names: Vec<glow::Texture> = textures.iter().map(|t| *t.gl.texture).collect();
    let layout = gl::layout::of(final_layout).expect("a layout GL names");
    handoff.gl_acquire(vk, gl, *commands.fence, &names, &vec![layout; names.len()])?;
    let mut vulkan_levels = Vec::new();
    let mut at = upload as usize;
    for t in &textures {
        let mut levels = Vec::new();
        for level in 0..t.levels {
            let (w, h) = level_size(t.width, t.height, level);
            levels.push(staging.bytes()[at..at + (w * h * 4) as usize].to_vec());
            at += (w * h * 4) as usize;
        }
        vulkan_levels.push(levels);
    }
    let gpu_ms = match &stamps {
        Some(t) => Some((t.between_ms(vk, 0, 1)?, t.between_ms(vk, 1, 2)?)),
        None => None,
    };
    Ok(Uploaded { textures, vulkan_levels, blitted: blit, gpu_ms })
}

impl Texture {
    // ANCHOR: texture_new
    /// An exportable image of `levels` levels and GL's texture over the same memory.
    fn new(vk: &VulkanContext, gl: &GlContext, width: u32, height: u32, levels: u32) -> Result<Self> {
        // Written by copies and blits, read by blits (a level is made from the one above it),
        // by the checks' copy back, and sampled by both APIs.
        let usage = vk::ImageUsageFlags::TRANSFER_SRC
            | vk::ImageUsageFlags::TRANSFER_DST
            | vk::ImageUsageFlags::SAMPLED;
        let mut external = vk::ExternalMemoryImageCreateInfo::default().handle_types(HANDLE_TYPE);
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(FORMAT)
            .extent(vk::Extent3D { width, height, depth: 1 })
            .mip_levels(levels) // the whole chain: GL must be told the same number
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL) // the driver's own layout: GL is told so too
            .usage(usage)
            .initial_layout(vk::ImageLayout::UNDEFINED)
            .flags(vk::ImageCreateFlags::MUTABLE_FORMAT) // as every shared image (chapter 01)
            .push_next(&mut external);
        let image = create(&vk.device, "vkCreateImage (a texture)", || unsafe {
            vk.device.create_image(&info, None)
        })?
        .counted("vk_image_exportable", 0);
        let requirements = unsafe { vk.device.get_image_memory_requirements(*image) };
        let properties = vk::MemoryPropertyFlags::DEVICE_LOCAL;
        let memory = exportable::allocate(vk, &requirements, properties, Dedicated::Image(*image))?;
        fail::call("vkBindImageMemory (a texture)", || unsafe {
            vk.device.bind_image_memory(*image, *memory.memory, 0)
        })?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(*image)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(FORMAT)
            .subresource_range(levels_range(0, levels)); // the any-hit shader's view: every level
        let view = create(&vk.device, "vkCreateImageView (a texture)", || unsafe {
            vk.device.create_image_view(&view_info, None)
        })?;
        let fd_loader = ash::khr::external_memory_fd::Device::new(&vk.instance, &vk.device);
        let fd = exportable::export_fd(&fd_loader, *memory.memory)?;
        // GL's side: the memory object, and a texture stored in it with as many levels.
        let memory_object = import_memory(gl, memory.terms(), fd)?;
        let texture = gl::create(&gl.gl, "glCreateTextures (a texture)", |gl| unsafe {
            gl.create_named_texture(glow::TEXTURE_2D)
        })?
        .counted("gl_texture_imported", 0);
        let ext = gl.memory_fns()?;
        fail::step("glTextureStorageMem2DEXT (a texture)")?;
        unsafe {
            gl.gl.texture_parameter_i32(*texture, TEXTURE_TILING_EXT, OPTIMAL_TILING_EXT as i32);
            // `levels`, not 1: with 1, GL would see level 0 alone, and sampling between levels
            // would read nothing (or, on drivers that guess, the wrong bytes).
            let (w, h) = (width as i32, height as i32);
            (ext.TextureStorageMem2DEXT)(texture.0.get(), levels as i32, GL_FORMAT, w, h, memory_object.0, 0);
        }
        gl.check_error("glTextureStorageMem2DEXT (a texture)")?;
        sampling(gl, *texture);
        let gl = SharedTexture::new(texture, memory_object);
        Ok(Texture { gl, view, image, memory, width, height, levels })
    }
    // ANCHOR_END: texture_new
}

// ANCHOR: sampling
/// How GL samples a texture: trilinear (the two nearest levels, four texels each), repeated past
/// its edges, and anisotropic where the driver has it (GL 4.6, or the EXT before it).
fn sampling(gl: &GlContext, texture: glow::Texture) {
    unsafe {
        let gl_ = &gl.gl;
        gl_.texture_parameter_i32(texture, glow::TEXTURE_MIN_FILTER, glow::LINEAR_MIPMAP_LINEAR as i32);
        gl_.texture_parameter_i32(texture, glow::TEXTURE_MAG_FILTER, glow::LINEAR as i32);
        gl_.texture_parameter_i32(texture, glow::TEXTURE_WRAP_S, glow::REPEAT as i32);
        gl_.texture_parameter_i32(texture, glow::TEXTURE_WRAP_T, glow::REPEAT as i32);
        if gl.has_extension("GL_EXT_texture_filter_anisotropic")
            || gl.has_extension("GL_ARB_texture_filter_anisotropic")
        {
            let most = gl_.get_parameter_f32(glow::MAX_TEXTURE_MAX_ANISOTROPY);
            gl_.texture_parameter_i32(texture, glow::TEXTURE_MAX_ANISOTROPY, (most as i32).min(8));
        }
    }
}
// ANCHOR_END: sampling

// ANCHOR: record_upload
/// Records one texture's levels: level 0 (or every level) from `staging`, each further level
/// blitted from the one above it. Every level is left TRANSFER_DST_OPTIMAL but those a blit
/// read, which are TRANSFER_SRC_OPTIMAL.
unsafe fn record_levels(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    texture: &Texture,
    staging: vk::Buffer,
    (from, chain): (u64, &[Level]),
) {
    use vk::AccessFlags as A;
    use vk::ImageLayout as L;
    let (device, image, levels) = (&vk.device, *texture.image, texture.levels);
    let barrier = |range, layouts, access| level_barrier(image, range, layouts, access);
    let transfer = vk::PipelineStageFlags::TRANSFER;
    let no = vk::DependencyFlags::empty();
    unsafe {
        // Every level from nothing to a copy's destination: the old contents may go.
        let to_dst = barrier(
            levels_range(0, levels),
            (L::UNDEFINED, L::TRANSFER_DST_OPTIMAL),
            (A::NONE, A::TRANSFER_WRITE),
        );
        device.cmd_pipeline_barrier(
            cb,
            vk::PipelineStageFlags::TOP_OF_PIPE,
            transfer,
            no,
            &[],
            &[],
            &[to_dst],
        );
        let mut offset = from;
        for (level, (w, h, bytes)) in chain.iter().enumerate() {
            let copy = vk::BufferImageCopy::default()
                .buffer_offset(offset)
                .image_subresource(level_layers(level as u32))
                .image_extent(vk::Extent3D { width: *w, height: *h, depth: 1 });
            device.cmd_copy_buffer_to_image(cb, staging, image, L::TRANSFER_DST_OPTIMAL, &[copy]);
            offset += bytes.len() as u64;
        }
        for level in chain.len() as u32..levels {
            // The level above, written by the copy or the last blit, becomes this blit's source.
            let above = barrier(
                levels_range(level - 1, 1),
                (L::TRANSFER_DST_OPTIMAL, L::TRANSFER_SRC_OPTIMAL),
                (A::TRANSFER_WRITE, A::TRANSFER_READ),
            );
            device.cmd_pipeline_barrier(cb, transfer, transfer, no, &[], &[], &[above]);
            let (sw, sh) = level_size(texture.width, texture.height, level - 1);
            let (dw, dh) = level_size(texture.width, texture.height, level);
            let corner =
                |w: u32, h: u32| [vk::Offset3D::default(), vk::Offset3D { x: w as i32, y: h as i32, z: 1 }];
            let blit = vk::ImageBlit::default()
                .src_subresource(level_layers(level - 1))
                .src_offsets(corner(sw, sh))
                .dst_subresource(level_layers(level))
                .dst_offsets(corner(dw, dh));
            // LINEAR: each texel of the level the mean of the (about) four above it. On an sRGB
            // format the blit filters in linear light, as sampling does.
            let (src, dst) = (L::TRANSFER_SRC_OPTIMAL, L::TRANSFER_DST_OPTIMAL);
            device.cmd_blit_image(cb, image, src, image, dst, &[blit], vk::Filter::LINEAR);
        }
    }
}

/// Records one texture's copy of every level back to `back`, for the check, then the whole
/// image released to GL in `final_layout`. `made` is how many levels came from `staging` (the
/// rest were blitted).
unsafe fn record_copy_back(
    vk: &VulkanContext,
    cb: vk::CommandBuffer,
    texture: &Texture,
    (staging, back): (vk::Buffer, u64),
    made: u32,
    final_layout: vk::ImageLayout,
) {
    use vk::AccessFlags as A;
    use vk::ImageLayout as L;
    let (device, image, levels) = (&vk.device, *texture.image, texture.levels);
    let transfer = vk::PipelineStageFlags::TRANSFER;
    let no = vk::DependencyFlags::empty();
    unsafe {
        // Every level a copy's source now: the last one written by a blit or copy, the others
        // already (when blitted) or from the copies.
        let mut to_src = Vec::new();
        let blitted_from = if made == levels { 0 } else { levels - 1 };
        for level in 0..levels {
            let old = if level < blitted_from { L::TRANSFER_SRC_OPTIMAL } else { L::TRANSFER_DST_OPTIMAL };
            let access = if level < blitted_from { A::TRANSFER_READ } else { A::TRANSFER_WRITE };
            to_src.push(level_barrier(
                image,
                levels_range(level, 1),
                (old, L::TRANSFER_SRC_OPTIMAL),
                (access, A::TRANSFER_READ),
            ));
        }
        device.cmd_pipeline_barrier(cb, transfer, transfer, no, &[], &[], &to_src);
        // Vulkan's own copy of every level, for the check against what GL reads.
        let mut offset = back;
        for level in 0..levels {
            let (w, h) = level_size(texture.width, texture.height, level);
            let copy = vk::BufferImageCopy::default()
                .buffer_offset(offset)
                .image_subresource(level_layers(level))
                .image_extent(vk::Extent3D { width: w, height: h, depth: 1 });
            device.cmd_copy_image_to_buffer(cb, image, L::TRANSFER_SRC_OPTIMAL, staging, &[copy]);
            offset += (w * h * 4) as u64;
        }
        // Released to GL (VK_QUEUE_FAMILY_EXTERNAL) in the layout GL's wait will name, the
        // writes made available. To BOTTOM_OF_PIPE: nothing after it here uses the image.
        let families = (vk.queue_family_index, vk::QUEUE_FAMILY_EXTERNAL);
        let mut release = image_barrier(
            image,
            (L::TRANSFER_SRC_OPTIMAL, final_layout),
            (A::TRANSFER_WRITE, A::NONE),
            families,
        );
        release.subresource_range = levels_range(0, levels);
        // The copy back must see the blits: host reads are made visible by the fence wait.
        let host = vk::BufferMemoryBarrier::default()
            .buffer(staging)
            .size(vk::WHOLE_SIZE)
            .src_access_mask(A::TRANSFER_WRITE)
            .dst_access_mask(A::HOST_READ)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED);
        let stages = vk::PipelineStageFlags::BOTTOM_OF_PIPE | vk::PipelineStageFlags::HOST;
        device.cmd_pipeline_barrier(cb, transfer, stages, no, &[], &[host], &[release]);
    }
}
// ANCHOR_END: record_upload

/// A barrier on `range` of `image`'s levels, in one queue family.
fn level_barrier(
    image: vk::Image,
    range: vk::ImageSubresourceRange,
    layouts: (vk::ImageLayout, vk::ImageLayout),
    access: (vk::AccessFlags, vk::AccessFlags),
) -> vk::ImageMemoryBarrier<'static> {
    let same = (vk::QUEUE_FAMILY_IGNORED, vk::QUEUE_FAMILY_IGNORED);
    vk::ImageMemoryBarrier { subresource_range: range, ..image_barrier(image, layouts, access, same) }
}

/// `count` levels from `first`, the one layer.
fn levels_range(first: u32, count: u32) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: first,
        level_count: count,
        base_array_layer: 0,
        layer_count: 1,
    }
}

fn level_layers(level: u32) -> vk::ImageSubresourceLayers {
    vk::ImageSubresourceLayers {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        mip_level: level,
        base_array_layer: 0,
        layer_count: 1,
    }
}

/// Bytes of a whole chain.
pub fn chain_bytes(width: u32, height: u32, levels: u32) -> u64 {
    (0..levels).map(|l| level_size(width, height, l)).map(|(w, h)| w as u64 * h as u64 * 4).sum()
}

/// Does the format allow what the GPU's levels need: blits from and to it, filtered linearly?
fn can_blit(vk: &VulkanContext) -> bool {
    let properties = unsafe { vk.instance.get_physical_device_format_properties(vk.physical_device, FORMAT) };
    let f = vk::FormatFeatureFlags::BLIT_SRC
        | vk::FormatFeatureFlags::BLIT_DST
        | vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR;
    let hidden = std::env::var("VKGL_HIDE_FEATURES").unwrap_or_default();
    properties.optimal_tiling_features.contains(f) && !hidden.split(',').any(|h| h.trim() == "blit")
}

/// The largest side both APIs allow for this format, exported.
fn largest_side(vk: &VulkanContext, gl: &GlContext) -> Result<u32> {
    let mut external_query = vk::PhysicalDeviceExternalImageFormatInfo::default().handle_type(HANDLE_TYPE);
    let usage =
        vk::ImageUsageFlags::TRANSFER_SRC | vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::SAMPLED;
    let query = vk::PhysicalDeviceImageFormatInfo2::default()
        .format(FORMAT)
        .ty(vk::ImageType::TYPE_2D)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(usage)
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT)
        .push_next(&mut external_query);
    let mut external = vk::ExternalImageFormatProperties::default();
    let mut properties = vk::ImageFormatProperties2::default().push_next(&mut external);
    fail::call("vkGetPhysicalDeviceImageFormatProperties2 (textures)", || unsafe {
        vk.instance.get_physical_device_image_format_properties2(vk.physical_device, &query, &mut properties)
    })?;
    let max = properties.image_format_properties.max_extent;
    let gl_max = unsafe { gl.gl.get_parameter_i32(glow::MAX_TEXTURE_SIZE) } as u32;
    anyhow::ensure!(
        external
            .external_memory_properties
            .external_memory_features
            .contains(vk::ExternalMemoryFeatureFlags::EXPORTABLE),
        "{} cannot export a {FORMAT:?} image as an fd",
        vk.info.name
    );
    Ok(max.width.min(max.height).min(gl_max))
}

/// A picture's levels as the CPU gives them: level 0 alone for the GPU to blit the rest, or every
/// level (each texel the mean of the texels above it, in linear light) when it cannot. A picture
/// larger than `largest` on a side is halved until it fits, and said so.
fn chain_of(picture: &Picture, largest: u32, blit: bool) -> Vec<Level> {
    let mut level = (picture.width, picture.height, picture.rgba.clone());
    while level.0 > largest || level.1 > largest {
        level = half(&level);
    }
    if (level.0, level.1) != (picture.width, picture.height) {
        eprintln!(
            "textures: {} is {}x{}, larger than the {largest} a side both APIs allow here: halved to {}x{}",
            picture.name, picture.width, picture.height, level.0, level.1
        );
    }
    let mut chain = vec![level];
    while !blit && chain.len() < level_count(chain[0].0, chain[0].1) as usize {
        let next = half(chain.last().expect("one level"));
        chain.push(next);
    }
    chain
}

/// The next level down: each texel the mean of the 2x2 (or, at an odd edge, fewer) above it,
/// colour averaged in linear light and encoded again.
fn half((w, h, rgba): &Level) -> Level {
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let to_linear = |c: u8| {
        let c = c as f32 / 255.0;
        if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
    };
    let to_srgb = |l: f32| {
        let c = if l <= 0.0031308 { l * 12.92 } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 };
        (c * 255.0).round().clamp(0.0, 255.0) as u8
    };
    let mut out = vec![0u8; (nw * nh * 4) as usize];
    for y in 0..nh {
        for x in 0..nw {
            let mut sum = [0.0f32; 4];
            let mut n = 0.0;
            for (sx, sy) in [(2 * x, 2 * y), (2 * x + 1, 2 * y), (2 * x, 2 * y + 1), (2 * x + 1, 2 * y + 1)] {
                if sx < *w && sy < *h {
                    let p = &rgba[4 * (sy * w + sx) as usize..][..4];
                    for c in 0..3 {
                        sum[c] += to_linear(p[c]);
                    }
                    sum[3] += p[3] as f32 / 255.0;
                    n += 1.0;
                }
            }
            let o = &mut out[4 * (y * nw + x) as usize..][..4];
            for c in 0..3 {
                o[c] = to_srgb(sum[c] / n);
            }
            o[3] = (sum[3] / n * 255.0).round() as u8;
        }
    }
    (nw, nh, out)
}

/// GL's bytes of every level of `texture`, read with `glGetTexImage`.
pub fn gl_levels(gl: &glow::Context, texture: &Texture) -> Vec<Vec<u8>> {
    (0..texture.levels)
        .map(|level| {
            let (w, h) = level_size(texture.width, texture.height, level);
            let mut bytes = vec![0u8; (w * h * 4) as usize];
            unsafe {
                gl.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
                gl.bind_texture(glow::TEXTURE_2D, Some(*texture.gl.texture));
                let data = glow::PixelPackData::Slice(Some(&mut bytes));
                gl.get_tex_image(glow::TEXTURE_2D, level as i32, glow::RGBA, glow::UNSIGNED_BYTE, data);
                gl.bind_texture(glow::TEXTURE_2D, None);
            }
            bytes
        })
        .collect()
}
