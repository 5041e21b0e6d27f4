//! Chapter 13: temporal reuse.
//!
//! Chapter 12's frame traces 16 new occlusion rays per pixel every frame and forgets them. Here
//! each pixel finds where the previous frame saw the same point (the previous camera, the moving
//! instance's previous transform), keeps that frame's occlusion if it saw the same surface, and
//! adds one or two new rays to it; a pixel just uncovered traces more, and a pixel whose history
//! is full traces less. The camera orbits, cuts to another view once, and one instance runs in a
//! circle. The frame is this folder's library (lib.rs); `convergence temporal` measures it.
//!
//! Run: `cargo run --release --bin 13-temporal-reuse` (keys: H chapter 12's frame and back, Esc quits).

use anyhow::Result;
use common::base::cli::{Size, Smallest};
use common::base::window::{Key, NamedKey, Window};
use common::frame::input::resize_every;
use common::instruments::census::ResizeCensus;
use common::scene::gbuffer::contexts_in_window;
use common::{Flags, RAY_TRACED_INTEROP, Report, open_fd_count};
use fast_frame::composite::{Uniforms, View};
use glow::HasContext;
use std::process::ExitCode;
use temporal_reuse::{Budget, Checks, Clock, Drawn, Objects, PATH_FRAMES, Passes, Sized, TemporalArgs};
use temporal_reuse::{check, frames_help};

const CHAPTER: &str = "13-temporal-reuse";
/// The smallest picture this chapter can check, and why (the largest is the device's).
const SMALLEST: Smallest = Smallest {
    width: 24,
    height: 24,
    why: "one compute group, and chapter 12's overlay checks need a pixel of the gizmo, with 2 pixels of room \
          around it, behind a surface and another in the open",
    shape: Some((
        4.0,
        2.0,
        "framed taller, the gizmo's axes leave the picture; wider, the overlay checks find no pixel to probe",
    )),
};
/// Chapter 13: chapter 12's frame, its ambient occlusion reused from frame to frame.
#[derive(clap::Parser)]
#[command(mut_arg("frames", frames_help))]
struct Args {
    #[command(flatten)]
    temporal: TemporalArgs,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    view: View,
    /// Headless: make the images of one size anew every K frames, as a window's resize does
    /// (the history starts again).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    resize_every: Option<u32>,
}

fn run(args: &Flags<Args>, report: &mut Report) -> Result<()> {
    let size = args.common.size;

    // 1. The scene, the path the camera and one instance follow, and the rays' budget
    let stage = args.temporal.stage(size.aspect(), report)?;

    // 2. Vulkan, then GL: in a window when there is a display, headless otherwise
    let (vk, mut window, gl_context, handoff) =
        contexts_in_window(CHAPTER, report, &RAY_TRACED_INTEROP, &args.common)?;
    let gl = &gl_context.gl;
    let open_fds_before = open_fd_count()?;
    let apis = (&vk, &gl_context, &handoff);

    // 3. The shared scene and its structures; a TLAS that can be updated where an instance moves
    // 4. Chapter 12's images and passes, the history, and the command buffers
    let mut objects = Objects::new(apis, &stage, args.temporal.blas, size.extent())?;
    let uniforms = Uniforms::new(args.temporal.blur, args.temporal.power, args.view, stage.start.far);
    // The next frame's ids are drawn before the CPU waits (step 5).
    let (passes, sized) = objects.passes(apis, &stage, uniforms, true);

    // 5. The frames: in a window until it closes, else the whole path, checked as it goes
    match window.as_mut() {
        Some(window) => in_window(&passes, sized, window, stage.budget, args.common.window_frames(), report)?,
        None => headless(&passes, sized, stage.budget, args, report)?,
    }
    gl_context.check_error("the frames")?;
    common::interop::report_handoff(report, &handoff);

    // 6. Clean up, newest first
    // ANCHOR: cleanup
    unsafe { gl.finish() };
    vk.wait_idle()?; // once: no guard below waits
    drop(objects); // its fields in the order written: the command buffers first, the shared scene last
    drop(handoff);
    // ANCHOR_END: cleanup
    gl_context.check_error("cleaning up")?;
    report.check("no_fd_leaked", common::settled_fd_count(open_fds_before)? == open_fds_before);
    drop(window);
    Ok(())
}

// ANCHOR: headless
/// The whole path headless, each frame checked as it passes (`Checks`: the cut, the last frame);
/// with `--resize-every K`, new images every K frames, as a window's resize makes them.
fn headless(
    p: &Passes,
    sized: &mut Sized,
    budget: Budget,
    args: &Flags<Args>,
    report: &mut Report,
) -> Result<()> {
    let frames = args.common.frames.unwrap_or(PATH_FRAMES).max(1);
    let (out, prefix) = (args.common.out_dir(CHAPTER), args.temporal.scene.picture_name(CHAPTER));
    let mut checks = Checks { chapter: CHAPTER, frames, out, prefix, before_cut: None };
    let mut clock = Clock::new(&p.apis.gl.gl, None)?;
    let drawn = Drawn::Temporal(budget);
    // Three quarters, whole, half, as chapter 08's `--resize-every`.
    let new_size = |frame| resize_every(args.resize_every, frame, args.common.size, SMALLEST.width);
    let (mut resizes, mut census) = (0, ResizeCensus::default());
    for frame in 0..frames {
        if let Some(size) = new_size(frame) {
            p.resize(sized, size)?;
            resizes += 1;
            census.count(p.apis.gl)?; // what exists after one resize must exist after every later one
        }
        // The next frame's ids are drawn at the end of this one, before the CPU waits for its
        // trace, unless the checks read this frame back or the next has images of another size.
        let next = frame + 1 < frames && new_size(frame + 1).is_none() && !checks.reads_back(p.path, frame);
        let camera = p.draw(sized, drawn, frame, &mut clock, next)?;
        checks.after(p, sized, (drawn, &camera, frame), report)?;
    }
    census.check(p.apis.gl, report)?;
    if resizes > 0 {
        report.set("resizes", resizes);
    }
    clock.finish(p)?;
    clock.times.record(report);
    report.set("frames_with_ids_drawn_ahead", clock.frames_drawn_ahead);
    report.set("frames", frames);
    eprintln!("walk: {frames} frames done ({})", drawn.described());
    Ok(())
}
// ANCHOR_END: headless

/// Frames in a window until it closes (or `frames`, if not 0): the path plays on, H switches
/// between this chapter's frame and chapter 12's, and a new window size remakes the images.
fn in_window(
    p: &Passes,
    sized: &mut Sized,
    window: &mut Window,
    budget: Budget,
    frames: u32,
    report: &mut Report,
) -> Result<()> {
    let mut clock = Clock::new(&p.apis.gl.gl, None)?;
    let (ours, chapter_12) = (Drawn::Temporal(budget), Drawn::Fresh(16));
    let mut drawn = ours;
    let (mut frame, mut camera, mut resizes, mut census) = (0, None, 0, ResizeCensus::default());
    while frames == 0 || frame < frames {
        let keys: Vec<Key> = window.poll(p.apis.gl).collect();
        if keys.contains(&Key::Named(NamedKey::Escape)) || window.close_requested() {
            break;
        }
        if keys.iter().any(|k| matches!(k.as_ref(), Key::Character("h" | "H"))) {
            drawn = if drawn == ours { chapter_12 } else { ours };
            sized.temporal.forget();
            eprintln!("window: {}", drawn.described());
        }
        let (width, height) = window.size();
        if (width, height) != (sized.targets.extent.width, sized.targets.extent.height)
            && width >= SMALLEST.width
            && height >= SMALLEST.height
        {
            p.resize(sized, Size { width, height })?;
            resizes += 1;
            census.count(p.apis.gl)?;
        }
        // A window may change size before any frame: each frame draws its own ids.
        camera = Some(p.draw(sized, drawn, frame, &mut clock, false)?);
        window.show_times(|| clock.times.line());
        sized.targets.show(&p.apis.gl.gl, window.size());
        window.swap_buffers(p.apis.gl)?;
        frame += 1;
    }
    clock.finish(p)?;
    clock.times.record(report);
    report.set("frames", frame);
    report.set("resizes", resizes);
    census.check(p.apis.gl, report)?;
    if let Some(camera) = camera {
        check::chapter_12_checks(p, sized, &camera, CHAPTER, report)?;
    }
    Ok(())
}

fn main() -> ExitCode {
    common::run_chapter_in_window(CHAPTER, SMALLEST, run)
}
