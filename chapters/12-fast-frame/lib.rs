//! Chapter 12's lesson, the fast frame: GL's ids (one 32-bit number per pixel for every instanced
//! triangle, `visibility`), the tracer that rebuilds each pixel's hit from its id and traces the
//! occlusion (`trace`), the GL compute composite (`composite`), and the checks that hold the frame
//! to its formula and to chapter 08's (`check`). `main.rs` draws it.
//!
//! A library as well as a program: chapter 13 draws these passes again around its history, and
//! `bench` and `convergence` draw the same frame to measure it, so they depend on this chapter
//! (never the other way round) instead of keeping a copy.

pub mod check;
pub mod composite;
pub mod trace;
pub mod visibility;
