//! Chapter 16's checks and pictures: every level GL reads against Vulkan's own copy, byte for
//! byte; the composite against the CPU; the occlusion's range; the textures in the report.

use crate::textures::{Uploaded, gl_levels};
use anyhow::Result;
use common::Report;
use common::base::cli::{Size, check_covered};
use common::frame::{Composite, Pixels, Uniforms, View, matches_reference};
use common::instruments::output;
use common::rt::ao::{AoTracer, check_occlusion};
use common::scene::gbuffer::GBuffers;
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

/// Headless: the mean AO over the covered pixels, and a PNG of each of `views`.
pub fn write_pictures(
    report: &mut Report,
    (gl, gbuffers, tracer, composite): (&glow::Context, &GBuffers, &AoTracer, &Composite),
    uniforms: &Uniforms,
    (out_dir, prefix): (&Path, &str),
    views: &[View],
) -> Result<()> {
    let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
    composite.draw(gl, gbuffers, tracer, &Uniforms { view: View::Ao, ..*uniforms });
    let ao = composite.read(gl);
    let positions = output::read_texture_f32(gl, gbuffers.textures()[0], w, h, 4);
    let covered: Vec<usize> = (0..(w * h) as usize).filter(|&i| positions[i * 4 + 3] > 0.0).collect();
    check_covered("--size", crate::CHAPTER, Size { width: w, height: h }, covered.len() as u64)?;
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
