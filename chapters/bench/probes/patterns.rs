//! Which rays: coherence against error (`bench --probe patterns`). Each sample pattern at each
//! ray count: the trace's median GPU time over the frames, and one frame's error against a
//! converged trace, before and after the blur (`fast_frame::check::ErrorAgainst`, as
//! chapter 12's `--error-against` measures it).

use super::Frame;
use anyhow::{Context as _, Result};
use common::clocks::timestamps::{Timestamps, median_p95};
use common::frame::Overlays;
use common::interop::handoff::Apis;
use fast_frame::check::{ErrorAgainst, LastFrame};
use fast_frame::composite::Uniforms;

/// One pattern at one ray count.
pub struct Measured {
    pub ao_ms: f64,
    pub error_raw: f64,
    pub error_blurred: f64,
}

/// `frames` frames of `frame`, each trace timed, then the last one's error against `reference`
/// rays per pixel.
pub fn measure(apis: Apis, frame: &mut Frame, u: &Uniforms, frames: u32, reference: u32) -> Result<Measured> {
    let Apis { vk, gl, commands, .. } = apis;
    let stamps = Timestamps::new(vk)?
        .with_context(|| format!("--probe patterns: {} writes no timestamps", vk.info.name))?;
    let mut times = Vec::new();
    for _ in 0..frames {
        frame.draw_timed(apis, u, Some(&stamps))?;
        commands.wait(vk, "vkWaitForFences before reading the trace's time")?;
        times.push(stamps.read_ms(vk)?);
    }
    // The checks' LastFrame, which the error reads the composite through (no overlays drawn).
    let overlays = Overlays::new(&gl.gl, frame.scene, 0)?;
    let Frame { targets, composite, camera, rays, tracer, .. } = frame;
    let last = LastFrame { gl: &gl.gl, targets, composite, overlays: &overlays, camera, uniforms: *u };
    let against = ErrorAgainst { last: &last, tracer, rays: *rays, reference };
    let (error_raw, error_blurred) = against.measure(apis)?;
    commands.wait(vk, "vkWaitForFences after the error's traces")?;
    drop(overlays);
    drop(stamps);
    Ok(Measured { ao_ms: median_p95(&times).0, error_raw, error_blurred })
}
