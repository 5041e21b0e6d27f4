//! Chapter 12's composite: chapter 08's blur and albedo x occlusion, as a GL compute shader
//! that reads the surface Vulkan wrote and writes the picture.

use super::visibility::Targets;
use anyhow::{Context as _, Result};
use glow::HasContext;
use std::rc::Rc;

/// GL's declarations (the surface sampled, the settings as uniforms), then, through `#include`
/// (resolved by `with_includes`), the tile and blur that Vulkan's compute shader includes too.
const COMPUTE_SHADER: &str = include_str!("../../shaders/gl/fast_composite.comp");
const INCLUDES: [(&str, &str); 3] = [
    ("composite_tile.glsl", include_str!("../../shaders/composite_tile.glsl")),
    ("sampling.glsl", include_str!("../../shaders/sampling.glsl")),
    common::scene::gbuffer::OCTAHEDRAL,
];

/// What the composite shows (its `view` uniform, in this order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum View {
    Final,
    Ao,
    Depth,
    Normal,
    Albedo,
}

impl View {
    pub const ALL: [View; 5] = [View::Final, View::Ao, View::Depth, View::Normal, View::Albedo];

    /// As `--view` spells it.
    pub fn name(self) -> &'static str {
        ["final", "ao", "depth", "normal", "albedo"][self as usize]
    }
}

/// The composite shader's uniforms: chapter 08's, over these views.
pub type Uniforms = common::frame::composite::Uniforms<View>;

/// Deleted when dropped (its program).
pub struct ComputeComposite {
    program: common::base::gl::Owned<glow::Program>,
}

impl ComputeComposite {
    pub fn new(gl: &Rc<glow::Context>) -> Result<Self> {
        let program = common::base::gl::compute_program(
            gl,
            &common::base::gl::with_includes(COMPUTE_SHADER, &INCLUDES)?,
        )
        .context("the composite's compute shader")?;
        Ok(ComputeComposite { program })
    }

    // ANCHOR: dispatch
    /// One thread per pixel, in 16x16 groups, then a barrier: the overlays are drawn into the
    /// picture next, and it is read back or shown after that.
    pub fn draw(&self, gl: &glow::Context, targets: &Targets, u: &Uniforms) {
        let (width, height) = (targets.extent.width, targets.extent.height);
        unsafe {
            gl.use_program(Some(*self.program));
            gl.bind_texture_unit(0, Some(*targets.surface.texture.texture));
            gl.bind_image_texture(0, Some(*targets.picture), 0, false, 0, glow::WRITE_ONLY, glow::RGBA8);
            u.set_blur(gl, *self.program);
            let view = gl.get_uniform_location(*self.program, "view");
            gl.uniform_1_i32(view.as_ref(), u.view as i32);
            gl.dispatch_compute(width.div_ceil(16), height.div_ceil(16), 1);
            // Image stores are not ordered with what follows until a barrier names its use:
            // drawing into the picture (the overlays), and reading or blitting it.
            gl.memory_barrier(glow::FRAMEBUFFER_BARRIER_BIT | glow::TEXTURE_UPDATE_BARRIER_BIT);
        }
    }
    // ANCHOR_END: dispatch
}
