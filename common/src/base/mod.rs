//! The base layer: what any chapter stands on, with nothing shared between the APIs yet. The
//! Vulkan and GL contexts, one-shot commands and timestamps, the report and CLI, the resource
//! counts, image output, pass timing, failure injection, the window.

pub mod chapter;
pub mod cli;
pub mod commands;
pub mod compute;
pub mod fail;
pub mod gl;
pub mod image;
pub mod output;
pub mod owned;
pub mod pipeline;
pub mod report;
pub mod resources;
pub mod timeline;
pub mod timestamps;
pub mod timing;
pub mod validation;

pub mod vulkan;
pub mod window;
