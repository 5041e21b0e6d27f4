//! The shared frame (taught in chapter 08): the composite pass, the overlay lines drawn over a
//! picture with the scene's depth, and the pixels the chapters' checks probe. Chapters 08-10 and
//! `bench` draw chapter 08's composite; chapters 08-12 draw the overlays.

mod composite;
mod overlay;

pub use composite::{Composite, Uniforms, View};
pub use overlay::{LineVertex, Overlays, Probes, shows_colour};

/// A framebuffer to draw the overlays into, whose depth attachment holds the scene's depth as GL
/// rasterised it (chapter 08: the G-buffer pass's; chapter 12: the visibility pass's).
#[derive(Clone, Copy)]
pub struct Target {
    pub framebuffer: glow::Framebuffer,
    pub width: u32,
    pub height: u32,
}
