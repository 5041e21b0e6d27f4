//! The interop layer: memory Vulkan exports and GL imports, and how the two APIs take turns on
//! it (taught in chapters 01-04), plus CUDA's import of the same memory (chapter 11).

pub mod cuda;
pub mod exportable;
pub mod handoff;
mod import;

pub use import::*;
