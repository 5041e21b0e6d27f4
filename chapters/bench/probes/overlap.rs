//! Do GL and Vulkan work run at the same time on this driver (`bench --probe overlap`)? Frames
//! in flight (GL drawing the next frame's ids while Vulkan traces this one) pay only if they do.
//! The same work in two orders, timed on the CPU from the first GL call to both APIs being done:
//!
//! - *during*: GL draws the ids, hands them over, Vulkan's trace is submitted, and GL draws a
//!   second set of ids (other images, nothing Vulkan uses) before it is told to wait for Vulkan;
//! - *after*: the same, with the second set drawn after GL's wait for Vulkan.
//!
//! If the driver runs GL's work beside Vulkan's, *during* is shorter by up to the second pass's
//! time; if it runs one API's work at a time, the two take as long.

use super::Frame;
use anyhow::Result;
use common::clocks::timestamps::median_p95;
use common::interop::handoff::Apis;
use fast_frame::trace::traced;
use fast_frame::visibility::Targets;
use glow::HasContext;
use std::time::Instant;

/// Medians over `rounds` of each order, in milliseconds: (during, after, the second pass alone).
pub fn measure(apis: Apis, p: &mut Frame, rounds: u32) -> Result<(f64, f64, f64)> {
    let Apis { vk, gl, commands, .. } = apis;
    let spare = Targets::new(vk, gl, apis.handoff, p.targets.extent)?;
    let g = &gl.gl;
    let Frame { scene, ids, camera, rays, tracer, visibility, targets, .. } = p;
    let draw_spare = || visibility.draw(g, &spare.ids_target(), scene, ids, camera);
    let done = || -> Result<()> {
        unsafe { g.finish() };
        commands.wait(vk, "vkWaitForFences for an overlap sample")?;
        Ok(())
    };
    let (mut during, mut after, mut alone) = (Vec::new(), Vec::new(), Vec::new());
    done()?;
    for round in 0..2 * rounds + 2 {
        let gl_during = round % 2 == 0;
        let start = Instant::now();
        visibility.draw(g, &targets.ids_target(), scene, ids, camera);
        tracer.accumulated = 0;
        // ANCHOR: orders
        let between = || {
            if gl_during {
                draw_spare()
            }
        };
        // Chapter 12's hand-over, with `between` run once Vulkan's trace is submitted and before
        // GL is told to wait for it.
        let record = |cb| tracer.record(vk, cb, targets, camera, *rays);
        traced(targets, |images| common::rt::ao::hand_over_around(apis, images, None, between, record))?;
        targets.gl_has_surface.set(true);
        if !gl_during {
            draw_spare();
        }
        done()?;
        // ANCHOR_END: orders
        // The first round of each order warms up.
        if round >= 2 {
            if gl_during { &mut during } else { &mut after }.push(common::ms_since(start));
        }
        let start = Instant::now();
        draw_spare();
        done()?;
        alone.push(common::ms_since(start));
    }
    drop(spare);
    Ok((median_p95(&during).0, median_p95(&after).0, median_p95(&alone).0))
}
