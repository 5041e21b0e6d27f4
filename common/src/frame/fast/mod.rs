//! Chapter 12's fast frame, which chapter 13 draws again: GL's ids (one 32-bit number per pixel
//! for every instanced triangle), the tracer that rebuilds each pixel's hit from its id and
//! traces the occlusion, the GL compute composite, and the checks that hold the frame to its
//! formula and to chapter 08's.

pub mod check;
pub mod composite;
pub mod trace;
pub mod visibility;
