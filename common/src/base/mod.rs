//! The base layer: what any chapter stands on, with nothing shared between the APIs yet. The
//! Vulkan and GL contexts, their owners, one-shot commands, the CLI and the window. What checks,
//! counts and reports them is the floor below (`instruments`); what times them, the layer above
//! (`clocks`).

pub mod chapter;
pub mod child;
pub mod cli;
pub mod commands;
pub mod compute;
pub mod gl;
pub mod image;
pub mod owned;
mod panel;
pub mod pipeline;
pub mod shader_block;
pub mod vulkan;
pub mod window;
