//! The shared frame: what chapter 08 taught and chapters 09-16 and `bench` draw again (chapters 12
//! and 13 keep their own frames in their folders). The composite pass (albedo x occlusion into an offscreen target over the G-buffer pass's depth),
//! the overlay lines drawn into any target whose depth is the scene's, and the pixel probes and
//! CPU reference the checks compare them with, a frame's input (`input`), a window's panel
//! (`panel`) and an animation played in a window (`playback`).

pub mod composite;
pub mod input;
pub mod overlay;
pub mod panel;
pub mod playback;
pub mod probe;
pub mod ring;

pub use composite::{Composite, Uniforms, View};
pub use overlay::{HalfAxis, LineBuffer, LineVertex, Lines, Overlays, Probes, Target, gizmo};
pub use probe::{Pixels, matches_reference, shows_colour};
