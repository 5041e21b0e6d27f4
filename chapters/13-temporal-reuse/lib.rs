//! Chapter 13's lesson: chapter 12's passes (the `fast_frame` library), with the occlusion each
//! pixel traced kept from frame to frame. The path the camera and one instance follow (`path`), the tracer that reprojects
//! and reuses its history (`tracer`), one frame between GL's ids and its composite (`frame`),
//! the chapter's checks (`check`), and the flags and setup both programs share (`setup`).
//! `main.rs` draws it; `convergence temporal` depends on this library to walk the same frame with
//! its choices varied, measuring error against time.

pub mod check;
pub mod frame;
pub mod path;
pub mod setup;
pub mod tracer;

pub use check::Checks;
pub use frame::{Clock, Drawn, Motion, Passes, Sized};
pub use path::{Mover, PATH_FRAMES, Path, PathArgs, PathKind, frames_help};
pub use setup::{Objects, Stage, TemporalArgs};
pub use tracer::{Accept, Budget, FreshPass, RayArgs, TemporalTracer, Texel};
