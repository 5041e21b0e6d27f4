//! Chapter 16's checks and pictures: every level GL reads against Vulkan's own copy, byte for
//! byte; the composite against the CPU; the occlusion's range; the textures in the report.

use crate::textures::{Uploaded, chain_bytes, gl_levels, level_size};
use anyhow::Result;
use common::Report;
use common::base::cli::{Size, check_covered};
use common::base::gl::{compute_program, create};
use common::frame::{Composite, Pixels, Uniforms, View, matches_reference};
use common::instruments::output;
use common::rt::ao::{AoTracer, check_occlusion};
use common::scene::gbuffer::GBuffers;
use glow::HasContext;
use std::path::Path;

/// The textures: how many, each one's size and levels, their bytes, and how the levels were made.
pub fn report_textures(report: &mut Report, uploaded: &Uploaded) {
    let textures = &uploaded.textures;
    report.set("textures", textures.len());
    if textures.is_empty() {
        return;
    }
    let sizes: Vec<String> =
        textures.iter().map(|t| format!("{}x{} ({} levels)", t.width, t.height, t.levels)).collect();
    report.set("texture_sizes", sizes);
    report.set("texture_bytes", textures.iter().map(|t| t.memory.size).sum::<u64>());
    report.set("texture_levels_made_by", if uploaded.blitted { "vkCmdBlitImage" } else { "the CPU" });
    // The GPU's time to make every level, against its time to copy the same texels back to
    // host memory: the rate of the upload beside a plain copy's, in one submission.
    if let Some((levels_ms, copy_back_ms)) = uploaded.gpu_ms {
        report.time_ms("texture_levels", levels_ms);
        report.time_ms("texture_copy_back", copy_back_ms);
        let texels: u64 = textures.iter().map(|t| chain_bytes(t.width, t.height, t.levels)).sum();
        let rate = |ms: f64| (texels as f64 / (ms / 1e3) / 1e6 * 10.0).round() / 10.0;
        let rates = [("levels", rate(levels_ms)), ("copy_back", rate(copy_back_ms))];
        report.set("texture_mb_per_s", std::collections::BTreeMap::from(rates));
    }
}

// ANCHOR: levels
/// Every level of every texture as GL reads it (`glGetTexImage`) equals Vulkan's copy of it
/// (`vkCmdCopyImageToBuffer`), byte for byte: GL sees the chain Vulkan made, level for level.
pub fn levels(report: &mut Report, gl: &glow::Context, uploaded: &Uploaded) {
    if uploaded.textures.is_empty() {
        return;
    }
    let mut differing = Vec::new();
    for (texture, vulkan) in uploaded.textures.iter().zip(&uploaded.vulkan_levels) {
        for (level, (gl_bytes, vk_bytes)) in gl_levels(gl, texture).iter().zip(vulkan).enumerate() {
            if gl_bytes != vk_bytes {
                differing.push(format!("{}x{} level {level}", texture.width, texture.height));
            }
        }
    }
    if !differing.is_empty() {
        eprintln!("textures: GL reads other bytes than Vulkan wrote in {}", differing.join(", "));
    }
    report.check("texture_levels_match_vulkan", differing.is_empty());
}
// ANCHOR_END: levels

const PROBE: &str = include_str!("../../shaders/gl/trilinear_probe.comp");
/// How far a GPU's trilinear sample may be from the exact one, per channel in linear light. It
/// blends with weights of a few fractional bits, which the device states
/// (`subTexelPrecisionBits` for the position between texels, `mipmapPrecisionBits` for the one
/// between levels): each weight may be off by one step of them, times the difference between
/// the texels it weighs. So the bound is the sample's own: 2 steps of the first across the texels
/// of each level, one of the second across the two levels, and [`ARITHMETIC_TOLERANCE`]. With 8
/// bits each, a checker of 0 and 1 allows up to 4.5/255; texels alike, 1.5/255.
pub struct Precision {
    between_texels: f32,
    between_levels: f32,
}

/// What the sRGB decode and the filter's arithmetic may add to any sample, which no limit states:
/// the H100 is 1.05/255 off on the default scene's pictures, where the texels are near alike.
const ARITHMETIC_TOLERANCE: f32 = 1.5 / 255.0;

impl Precision {
    pub fn of(vk: &common::VulkanContext) -> Precision {
        let limits = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }.limits;
        Precision {
            between_texels: (-(limits.sub_texel_precision_bits as f32)).exp2(),
            between_levels: (-(limits.mipmap_precision_bits as f32)).exp2(),
        }
    }
}

// ANCHOR: trilinear
/// GL's `textureLod` of every texture at 256 points (inside and past its edges, at levels of
/// detail from 0 to past the last level) equals a CPU model of trilinear filtering built from
/// Vulkan's own levels, within the bound the device's [`Precision`] sets for each sample: the
/// levels are where GL looks for them, and sRGB is decoded once, before filtering.
pub fn trilinear(
    report: &mut Report,
    gl: &std::rc::Rc<glow::Context>,
    uploaded: &Uploaded,
    precision: &Precision,
) -> Result<()> {
    if uploaded.textures.is_empty() {
        return Ok(());
    }
    let program = compute_program(gl, PROBE)?;
    let (mut worst, mut within) = (0.0f32, true);
    for (texture, levels) in uploaded.textures.iter().zip(&uploaded.vulkan_levels) {
        let points: Vec<[f32; 4]> = (0..256)
            .map(|i| {
                let f = i as f32;
                let lod = (i % 16) as f32 / 15.0 * (texture.levels as f32 + 0.5);
                [(f * 0.618_034).fract() * 2.0 - 0.5, (f * 0.414_213_57).fract() * 2.0 - 0.5, lod, 0.0]
            })
            .collect();
        let mut samples = vec![[0f32; 4]; points.len()];
        unsafe {
            let input = create(gl, "glCreateBuffers for the probe's points", |gl| gl.create_named_buffer())?;
            let output =
                create(gl, "glCreateBuffers for the probe's samples", |gl| gl.create_named_buffer())?;
            gl.named_buffer_data_u8_slice(*input, bytemuck::cast_slice(&points), glow::STATIC_DRAW);
            gl.named_buffer_data_u8_slice(*output, bytemuck::cast_slice(&samples), glow::STREAM_READ);
            gl.use_program(Some(*program));
            gl.bind_texture_unit(0, Some(*texture.gl.texture));
            gl.bind_buffer_base(glow::SHADER_STORAGE_BUFFER, 0, Some(*input));
            gl.bind_buffer_base(glow::SHADER_STORAGE_BUFFER, 1, Some(*output));
            gl.dispatch_compute(points.len().div_ceil(64) as u32, 1, 1);
            gl.memory_barrier(glow::BUFFER_UPDATE_BARRIER_BIT);
            gl.bind_buffer(glow::SHADER_STORAGE_BUFFER, Some(*output));
            gl.get_buffer_sub_data(glow::SHADER_STORAGE_BUFFER, 0, bytemuck::cast_slice_mut(&mut samples));
            gl.bind_buffer(glow::SHADER_STORAGE_BUFFER, None);
            gl.bind_texture_unit(0, None);
            gl.use_program(None);
        }
        for (point, sample) in points.iter().zip(&samples) {
            let (expected, bound) = cpu_trilinear(levels, (texture.width, texture.height), point, precision);
            for c in 0..4 {
                let error = (expected[c] - sample[c]).abs();
                worst = worst.max(error);
                within &= error <= bound[c];
            }
        }
    }
    report.set("trilinear_worst_error", (worst as f64 * 255.0 * 100.0).round() / 100.0); // in 1/255ths
    report.check("gl_samples_as_the_cpu_filters", within);
    Ok(())
}

/// GL's trilinear filtering (LINEAR_MIPMAP_LINEAR, REPEAT) of sRGB levels, on the CPU: the level
/// of detail clamped to the chain, the two levels around it each sampled bilinearly (texels
/// decoded to linear light first), and the two mixed by the fraction between them. Returns the
/// exact sample at `point` (u, v, level of detail) and, per channel, how far a GPU of
/// `precision` may be from it.
fn cpu_trilinear(
    levels: &[Vec<u8>],
    (width, height): (u32, u32),
    point: &[f32; 4],
    precision: &Precision,
) -> ([f32; 4], [f32; 4]) {
    let last = (levels.len() - 1) as f32;
    let lod = point[2].clamp(0.0, last);
    let (low, fraction) = (lod.floor(), lod.fract());
    let at = |level: usize| {
        bilinear(&levels[level], level_size(width, height, level as u32), (point[0], point[1]))
    };
    let texels = |spread: f32| 2.0 * precision.between_texels * spread + ARITHMETIC_TOLERANCE;
    let (a, spread_a) = at(low as usize);
    // A GPU may round a fraction of 0 up by one step, and so blend in the next level.
    let (b, spread_b) = at((low as usize + 1).min(last as usize));
    let value = if fraction == 0.0 || low >= last {
        a
    } else {
        std::array::from_fn(|c| a[c] * (1.0 - fraction) + b[c] * fraction)
    };
    let bound = std::array::from_fn(|c| {
        texels(spread_a[c].max(spread_b[c])) + precision.between_levels * (a[c] - b[c]).abs()
    });
    (value, bound)
}

/// The bilinear sample at (u, v) with `REPEAT`, and the spread (largest less smallest) of the
/// texels it weighs and their neighbours, per channel.
fn bilinear(texels: &[u8], (w, h): (u32, u32), (u, v): (f32, f32)) -> ([f32; 4], [f32; 4]) {
    let (x, y) = (u * w as f32 - 0.5, v * h as f32 - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let texel = |i: f32, j: f32| -> [f32; 4] {
        let (i, j) = ((i as i64).rem_euclid(w as i64) as u32, (j as i64).rem_euclid(h as i64) as u32);
        let p = &texels[4 * (j * w + i) as usize..][..4];
        let linear = |c: u8| {
            let c = c as f32 / 255.0;
            if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
        };
        [linear(p[0]), linear(p[1]), linear(p[2]), p[3] as f32 / 255.0]
    };
    let (t00, t10, t01, t11) =
        (texel(x0, y0), texel(x0 + 1.0, y0), texel(x0, y0 + 1.0), texel(x0 + 1.0, y0 + 1.0));
    let value = std::array::from_fn(|c| {
        let top = t00[c] * (1.0 - fx) + t10[c] * fx;
        let bottom = t01[c] * (1.0 - fx) + t11[c] * fx;
        top * (1.0 - fy) + bottom * fy
    });
    // Over the texels around the four too: a GPU that rounds a position across a texel's edge
    // weighs a neighbour (by at most one step) that the exact footprint leaves out.
    let around: Vec<[f32; 4]> = (-1..=2)
        .flat_map(|j| (-1..=2).map(move |i| (i as f32, j as f32)))
        .map(|(i, j)| texel(x0 + i, y0 + j))
        .collect();
    let spread = std::array::from_fn(|c| {
        let (low, high) = around.iter().fold((f32::MAX, f32::MIN), |(l, h), t| (l.min(t[c]), h.max(t[c])));
        high - low
    });
    (value, spread)
}
// ANCHOR_END: trilinear

/// The last frame: the occlusion in [0, 1] (1 on the background), and the composite against the
/// same formula computed on the CPU from the G-buffers.
pub fn frame(
    report: &mut Report,
    gl: &glow::Context,
    (gbuffers, tracer, composite): (&GBuffers, &AoTracer, &Composite),
    uniforms: &Uniforms,
) {
    check_occlusion(report, gl, gbuffers, tracer);
    let pixels = Pixels::read(gl, gbuffers, tracer);
    let plain = Uniforms { view: View::Final, ..*uniforms };
    composite.draw(gl, gbuffers, tracer, &plain);
    report.check("composite_matches_cpu_reference", matches_reference(&pixels, &composite.read(gl), &plain));
}

/// Headless: the mean AO over the covered pixels, and a PNG of each of `views`. `chapter` names
/// the chapter in the error for a size that covers no pixel.
pub fn write_pictures(
    report: &mut Report,
    (gl, gbuffers, tracer, composite): (&glow::Context, &GBuffers, &AoTracer, &Composite),
    uniforms: &Uniforms,
    (chapter, out_dir, prefix): (&str, &Path, &str),
    views: &[View],
) -> Result<()> {
    let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
    composite.draw(gl, gbuffers, tracer, &Uniforms { view: View::Ao, ..*uniforms });
    let ao = composite.read(gl);
    let positions = output::read_texture_f32(gl, gbuffers.textures()[0], w, h, 4);
    let covered: Vec<usize> = (0..(w * h) as usize).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
    check_covered("--size", chapter, Size { width: w, height: h }, covered.len() as u64)?;
    let mean = covered.iter().map(|&i| ao[i * 4] as f64 / 255.0).sum::<f64>() / covered.len() as f64;
    report.set("ao_mean", (mean * 1e3).round() / 1e3);
    for &view in views {
        composite.draw(gl, gbuffers, tracer, &Uniforms { view, ..*uniforms });
        let name = match view {
            View::Final => prefix.to_owned(),
            other => format!("{prefix}-{}", other.name()),
        };
        output::save_gl_rgba8(report, out_dir, &name, (w, h), &composite.read(gl))?;
    }
    Ok(())
}
