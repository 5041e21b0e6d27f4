//! Chapter 13's frame loops: headless along the path (each method of a comparison in turn, its
//! error measured where asked, the checks on the chosen method's walk), or in a window.

use crate::frame::{Clock, Drawn, Passes, Sized};
use crate::history_check::{self, Seen};
use crate::measure::{ErrorProbe, Flips, FrameRecord, References, Walk, measured};
use crate::path::PathKind;
use crate::settings::{Args, PATH_FRAMES};
use crate::temporal::Budget;
use anyhow::Result;
use common::base::cli::Size;
use common::base::window::{Key, NamedKey, Window};
use common::clocks::timeline::Timeline;
use common::frame::fast::check::{self, LastFrame, Surface};
use common::frame::fast::composite::View;
use common::frame::fast::trace::{Pattern, Rays};
use common::scene::Camera;
use common::{Flags, Report};

/// The methods `--compare` walks: chapter 12's frame at 16, 8 and 4 rays, then this chapter's
/// at 1, 2 and 4 (and the one the flags chose, if it is none of those).
fn compared(chosen: Drawn, budget: Budget) -> Vec<Drawn> {
    let mut methods: Vec<Drawn> = [16, 8, 4].map(Drawn::Fresh).into();
    methods.extend([1, 2, 4].map(|samples| Drawn::Temporal(Budget { samples, ..budget })));
    if !methods.contains(&chosen) {
        methods.push(chosen);
    }
    methods
}

/// Every walk along the path headless, and the checks of the chosen method's.
pub fn headless(
    p: &Passes,
    sized: &mut Sized,
    chosen: Drawn,
    args: &Flags<Args>,
    report: &mut Report,
) -> Result<Vec<Walk>> {
    let frames = args.common.frames.unwrap_or(PATH_FRAMES).max(1);
    let budget = match chosen {
        Drawn::Temporal(budget) => budget,
        Drawn::Fresh(_) => crate::temporal::Budget::new(args, p.radius, p.scene.size() / 2.0),
    };
    let table = if args.compare { compared(chosen, budget) } else { vec![chosen] };
    // The chosen method walks last (a stable sort: the others keep their order). Its checks read
    // the history and the surface back at the cut and at the end, and with `--fresh-pass packed`
    // the walk after them ran 2 to 3 times slower for its first tens of frames on the H100 (the
    // deeper page). The table keeps the order of `table`.
    let mut methods = table.clone();
    methods.sort_by_key(|&m| m == chosen);
    let probe = ErrorProbe {
        composite: p.composite,
        uniforms: p.uniforms,
        reference: args.error_against,
        radius: p.radius,
        scene_scale: p.scene.size() / 2.0,
    };
    let mut references = References::default();
    let mut walks = Vec::new();
    let mut checked = false;
    for drawn in methods {
        let checking = drawn == chosen && !checked;
        sized.temporal.forget();
        let timeline = match (args.timeline, checking, p.timestamps) {
            (0, _, _) | (_, false, _) => None,
            (last, true, Some(_)) => {
                Some((Timeline::new(&p.apis.gl.gl, last.min(frames), ["ids", "composite"])?, frames))
            }
            (_, true, None) => {
                anyhow::bail!("--timeline: {} writes no timestamps on this queue", p.apis.vk.info.name)
            }
        };
        let mut clock = Clock::new(&p.apis.gl.gl, timeline)?;
        let (mut records, mut before_cut, mut flips) = (Vec::new(), None, Flips::default());
        let (mut resizes, mut after_first_resize) = (0, None);
        for frame in 0..frames {
            if let Some(every) = args.resize_every.filter(|&k| checking && frame > 0 && frame % k == 0) {
                // Three quarters, whole, half, as chapter 12's `--resize-every`.
                let smallest = crate::SMALLEST.width;
                let scale = |side: u32| (side * [2, 3, 4][(frame / every) as usize % 3] / 4).max(smallest);
                let (w, h) = (args.common.size.width, args.common.size.height);
                crate::resize(p, sized, Size { width: scale(w), height: scale(h) })?;
                resizes += 1;
                if after_first_resize.is_none() {
                    after_first_resize = Some(alive(p)?);
                }
            }
            // The next frame's ids may be drawn at the end of this one unless something reads
            // this frame's back first (the cut's checks, the last frame's, the error) or the
            // next frame has images of another size.
            let cut = p.path.cut();
            let resized_next = args.resize_every.is_some_and(|k| checking && (frame + 1) % k == 0);
            let read_back = (checking && cut.is_some_and(|c| frame + 1 == c || frame == c))
                || (args.error_against > 0 && measured(frame, args.error_every, cut));
            let next = frame + 1 < frames && !resized_next && !read_back;
            let camera = p.draw(sized, drawn, frame, &mut clock, next)?;
            if checking {
                if let Drawn::Temporal(budget) = drawn {
                    before_cut = watch_the_cut(p, sized, (&camera, frame), before_cut, (budget, report))?;
                }
                if frame + 1 == frames {
                    check_last_frame(p, sized, &camera, (drawn, args), report)?;
                }
            }
            let (rmse, flip) = match args.error_against {
                0 => (None, None),
                _ if !measured(frame, args.error_every, p.path.cut()) => (None, None),
                _ => {
                    let sized = (&sized.targets, &mut sized.fresh);
                    let (rmse, flip) = probe.measure(p.apis, sized, (&camera, frame), &mut references)?;
                    (Some(rmse), flip)
                }
            };
            records.push(FrameRecord { frame, wall_ms: None, gpu_ms: None, ao_ms: None, rmse, flip: None });
            flips.add(flip, records.len() - 1, &mut records)?;
        }
        flips.finish(&mut records)?;
        // Before the walk's own timers and timeline go: they were there at the first resize too.
        if let Some(first) = after_first_resize {
            report.check("nothing_grows_across_resizes", alive(p)? == first);
            report.set("resizes", resizes);
        }
        clock.finish(p)?;
        if let Some(timeline) =
            clock.finish_timeline(p, &args.common.out_dir(crate::CHAPTER).join("timeline"))?
        {
            report.set("timeline", timeline);
        }
        // The passes' GPU times, frame by frame where every frame has one of each, and the wall
        // clock's, where no read-back for the error slowed the frames.
        let times = &clock.times;
        let per_frame = |pass: &str| Some(times.samples(pass)).filter(|s| s.len() == records.len());
        let ao = per_frame("ao_trace");
        let wall = per_frame("frame_wall").filter(|_| args.error_against == 0);
        let gl: Vec<_> =
            ["visibility", "composite", "overlays"].iter().map(|&pass| per_frame(pass)).collect();
        for (i, record) in records.iter_mut().enumerate() {
            record.ao_ms = ao.map(|a| a[i]);
            record.wall_ms = wall.map(|w| w[i]);
            // A pass with no time in any frame (llvmpipe's overlays) counts nothing.
            let gl_ms: f64 = gl.iter().flatten().map(|s| s[i]).sum();
            record.gpu_ms = record.ao_ms.map(|a| a + gl_ms);
        }
        if checking {
            times.record(report);
            report.set("frames_with_ids_drawn_ahead", clock.frames_drawn_ahead);
            checked = true;
        }
        eprintln!("walk: {} done ({frames} frames)", drawn.name());
        walks.push(Walk::new(drawn.name(), records, p.path.cut(), args.error_every));
    }
    report.set("frames", frames);
    walks.sort_by_key(|w: &Walk| table.iter().position(|m| m.name() == w.method));
    Ok(walks)
}

/// The frames around the cut, read back for the cut check: the one before it kept, the one at
/// it checked against it.
fn watch_the_cut(
    p: &Passes,
    sized: &Sized,
    (camera, frame): (&Camera, u32),
    before: Option<Seen>,
    (budget, report): (Budget, &mut Report),
) -> Result<Option<Seen>> {
    let Some(cut) = p.path.cut().filter(|&c| c > 0) else { return Ok(None) };
    let gl = &p.apis.gl.gl;
    let seen = || Seen {
        surface: Surface::read(gl, &sized.targets),
        ids: check::read_ids(gl, &sized.targets),
        camera: *camera,
        frame,
    };
    if frame + 1 == cut {
        return Ok(Some(seen()));
    }
    if let (true, Some(before)) = (frame == cut, before.as_ref()) {
        let history = sized.temporal.read_history(p.apis.vk, p.apis.commands)?;
        if budget.cap > budget.fresh && budget.samples > 0 {
            history_check::cut(before, &seen(), &history, (p.path, p.ids, budget.fresh), report);
        }
    }
    Ok(before)
}

/// The last frame of the chosen walk: chapter 12's checks of the surface, the composite and the
/// overlays, the pictures, and what the path makes checkable.
fn check_last_frame(
    p: &Passes,
    sized: &mut Sized,
    camera: &Camera,
    (drawn, args): (Drawn, &Flags<Args>),
    report: &mut Report,
) -> Result<()> {
    let gl = &p.apis.gl.gl;
    let surface = chapter_12_checks(p, sized, camera, report)?;
    if let Some(last) = last_frame(p, sized, camera) {
        let prefix = args.scene.picture_name(crate::CHAPTER);
        last.write_pictures(report, &surface, &args.common.out_dir(crate::CHAPTER), &prefix)?;
    }
    let Drawn::Temporal(budget) = drawn else { return Ok(()) };
    if budget.samples == 0 {
        return Ok(()); // nothing traced: nothing to compare
    }
    let frames = args.common.frames.unwrap_or(PATH_FRAMES).max(1);
    match args.path {
        // ANCHOR: still
        // A still camera and nothing moving: every pixel's history holds all its rays, the
        // same points of the same sequence chapter 08 traces, while they fit under the cap.
        PathKind::Still if p.path.moving.is_none() => {
            let total = budget.fresh + (frames - 1) * budget.samples;
            if total <= budget.cap {
                let run = check::Chapter08Run {
                    scene: p.scene,
                    shared: p.shared,
                    camera,
                    per_frame: budget.samples,
                    total,
                    radius: p.radius,
                };
                // With the 4x4 blocks, chapter 08's rays are traced again per pixel for the
                // pixel-by-pixel comparison (chapter 12 does the same); the means are this frame's.
                let per_pixel = match budget.per_pixel {
                    true => None,
                    false => {
                        let scene_scale = p.scene.size() / 2.0;
                        let rays = Rays {
                            samples: budget.samples,
                            radius: p.radius,
                            scene_scale,
                            pattern: Pattern::PerPixel,
                            salt: 0,
                        };
                        sized.fresh.retrace(p.apis, &sized.targets, camera, rays, total)?;
                        Some(Surface::read(gl, &sized.targets))
                    }
                };
                let chapter_08 = check::trace_chapter_08(p.apis, &sized.targets, run)?;
                chapter_08.compare(&surface, per_pixel.as_ref(), report);
            } else {
                eprintln!(
                    "history: {total} rays a pixel pass the cap of {}; chapter 08 is not compared",
                    budget.cap
                );
            }
        }
        // ANCHOR_END: still
        PathKind::Pan => {
            let history = sized.temporal.read_history(p.apis.vk, p.apis.commands)?;
            let rays = 256;
            let scene_scale = p.scene.size() / 2.0;
            let reference =
                Rays { samples: rays, radius: p.radius, scene_scale, pattern: Pattern::PerPixel, salt: 1 };
            sized.fresh.retrace(p.apis, &sized.targets, camera, reference, rays)?;
            let traced = Surface::read(gl, &sized.targets);
            history_check::pan(&history, &traced, (rays, budget.cap, budget.fresh), report);
        }
        _ => {}
    }
    Ok(())
}

/// Chapter 12's checks of the last frame: the surface's values, the composite and the overlays.
/// Returns the surface, as read; a frame whose scene covers no pixel is refused.
fn chapter_12_checks(p: &Passes, sized: &Sized, camera: &Camera, report: &mut Report) -> Result<Surface> {
    let gl = &p.apis.gl.gl;
    let surface = Surface::read(gl, &sized.targets);
    surface.require_covered(crate::CHAPTER)?;
    surface.check_values(report);
    if let Some(last) = last_frame(p, sized, camera) {
        for (name, ok) in last.check(&surface) {
            report.check(name, ok);
        }
    }
    Ok(surface)
}

/// What chapter 12's last-frame checks and pictures draw with (none without overlays).
fn last_frame<'a>(p: &'a Passes, sized: &'a Sized, camera: &'a Camera) -> Option<LastFrame<'a>> {
    Some(LastFrame {
        gl: &p.apis.gl.gl,
        targets: &sized.targets,
        composite: p.composite,
        overlays: p.overlays?,
        camera,
        uniforms: p.uniforms(camera, View::Final),
    })
}

/// What exists that a resize could leak: open fds, counted resources (a kind none of which is
/// alive, such as the buffer the history is read back through, counts as none), GL objects. GL's
/// own count leaves queries out: a name `glGenQueries` made is a query to `glIsQuery` only once
/// it has been begun, and the timeline's begin in the last frames (the counted resources hold
/// every query made).
fn alive(p: &Passes) -> Result<impl PartialEq + use<>> {
    let counted: std::collections::BTreeMap<String, i64> =
        common::instruments::resources::live().into_iter().filter(|(_, n)| *n != 0).collect();
    let mut gl = p.apis.gl.live_objects();
    gl.remove("gl_queries");
    Ok((common::open_fd_count()?, counted, gl))
}

/// Frames in a window until it closes (or `frames`, if not 0): the path plays on, H switches
/// between this chapter's frame and chapter 12's, and a new window size remakes the images.
pub fn in_window(
    p: &Passes,
    sized: &mut Sized,
    window: &mut Window,
    chosen: Drawn,
    frames: u32,
    report: &mut Report,
) -> Result<()> {
    let mut clock = Clock::new(&p.apis.gl.gl, None)?;
    let mut drawn = chosen;
    let fresh = Drawn::Fresh(16);
    let (mut frame, mut camera, mut resizes, mut after_first_resize) = (0, None, 0, None);
    while frames == 0 || frame < frames {
        let keys: Vec<Key> = window.poll(p.apis.gl).collect();
        if keys.contains(&Key::Named(NamedKey::Escape)) || window.close_requested() {
            break;
        }
        if keys.iter().any(|k| matches!(k.as_ref(), Key::Character("h" | "H"))) {
            drawn = if drawn == fresh { chosen } else { fresh };
            sized.temporal.forget();
            eprintln!("window: {}", drawn.name());
        }
        let (width, height) = window.size();
        let smallest = crate::SMALLEST.width;
        if (width, height) != (sized.targets.extent.width, sized.targets.extent.height)
            && width >= smallest
            && height >= smallest
        {
            crate::resize(p, sized, Size { width, height })?;
            resizes += 1;
            if after_first_resize.is_none() {
                after_first_resize = Some(alive(p)?);
            }
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
    if let Some(first) = after_first_resize {
        report.check("nothing_grows_across_resizes", alive(p)? == first);
    }
    if let Some(camera) = camera {
        chapter_12_checks(p, sized, &camera, report)?;
    }
    Ok(())
}
