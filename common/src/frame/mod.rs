//! The shared frame: what chapter 08 taught and chapters 09-11 and `bench` draw again, and
//! chapter 12's fast frame (`fast`), which chapter 13 draws again, and chapter 13's frame, which
//! keeps its occlusion from frame to frame (`temporal`). The
//! composite pass (albedo x occlusion into an offscreen target over the G-buffer pass's depth),
//! the overlay lines drawn into any target whose depth is the scene's, and the pixel probes and
//! CPU reference the checks compare them with, and a frame's input (`input`).

pub mod composite;
pub mod fast;
pub mod input;
pub mod overlay;
pub mod probe;
pub mod ring;
pub mod temporal;

pub use composite::{Composite, Uniforms, View};
pub use overlay::{HalfAxis, LineBuffer, LineVertex, Lines, Overlays, Probes, Target, gizmo};
pub use probe::{Pixels, matches_reference, shows_colour};
