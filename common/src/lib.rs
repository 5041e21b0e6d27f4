//! What every chapter of the tutorial shares.
//!
//! Each item here was first taught, in the open, by one chapter (the book's introduction lists
//! which); later chapters call it by name. Doc comments here say *what*; the book says *why*.
//!
//! The modules stand in layers, each using only its own layer and those below it
//! (`common/tests/layers.rs` fails on any module that reaches up, and on any circle of modules
//! that use each other):
//!
//! ```text
//! frame    composite pass, overlay lines, pixel probes             (chapter 08)
//!   ^
//! rt       acceleration structures, ray pipelines, AO              (chapters 06, 07, 09, 10)
//!   ^
//! scene    meshes, instances, camera; G-buffers GL rasterises      (chapter 05)
//!   ^
//! interop  exportable memory, GL's import, the hand-off, CUDA      (chapters 01-04, 11)
//!   ^
//! clocks   GPU timestamps, pass timers, both APIs on one timeline  (chapters 03, 08, 12)
//!   ^
//! base     Vulkan and GL contexts, owners, commands, CLI, window   (chapters 01-02)
//!   ^
//! instruments  the report and its checks, counts of what is alive, failure injection,
//!          validation's messages, images and plots written        (every chapter)
//! ```
//!
//! `base` and the layers above it are what the chapters teach; `instruments` and `clocks` are
//! how the tutorial watches them, kept apart so that the teaching layers stay small.
//!
//! The crate root only declares the layers and re-exports what nearly every chapter names.
//!
//! One teardown rule holds in every layer (the book's appendix states it, "Owners"):
//!
//! - every object is owned from the moment it exists (`base::owned::Owned` for Vulkan's and
//!   CUDA's, `base::gl::Owned` for GL's), so that an early return destroys what was made, newest
//!   first; a struct holds one owner per object, its fields in the order they must be dropped
//!   (GL's import before Vulkan's memory), and a constructor builds it from owned locals at the
//!   end, so one that fails half-way drops what it made;
//! - only the owner of a queue of work waits, for its own last submission, when dropped
//!   (`base::commands::Commands`): a chapter makes it after everything its submissions use, so it
//!   is dropped first. No other `Drop` waits or idles the device; a chapter waits once (`glFinish`,
//!   then `VulkanContext::wait_idle`) before its list of `drop(x)` in reverse order;
//! - gpu-allocator memory is freed by its owner (`rt::accel::Memory`), through a shared
//!   `GpuAllocator` handle; the allocator goes with its last handle;
//! - every fallible step goes through `instruments::fail` (`VKGL_FAIL_AT`), and every count of
//!   what is alive (resources, GL objects, fds) lives in `instruments::resources`.

pub mod base;
pub mod clocks;
pub mod frame;
pub mod instruments;
pub mod interop;
pub mod rt;
pub mod scene;

pub use base::chapter::{
    Flags, connect, contexts, contexts_in_window, finish, gl_in_window, largest_size, ms_since, run_chapter,
    run_chapter_in_window,
};
pub use base::cli::CommonArgs;
pub use base::gl::GlContext;
pub use base::vulkan::{INTEROP, RAY_TRACED_INTEROP, RAY_TRACING_EXTENSIONS, Requirements, VulkanContext};
pub use instruments::report::{Print, Report};
pub use instruments::resources::{open_fd_count, settled_fd_count};
