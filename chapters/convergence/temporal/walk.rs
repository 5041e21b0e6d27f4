//! The walks along chapter 13's path: each method of a comparison in turn, its error measured
//! where asked, chapter 13's checks on the chosen method's walk.

use super::measure::{ErrorProbe, Flips, FrameRecord, References, Walk, measured};
use anyhow::Result;
use common::Report;
use common::clocks::timeline::Timeline;
use std::path::PathBuf;
use temporal_reuse::{Budget, Checks, Clock, Drawn, Passes, Sized};

/// What the walks do: how many frames, which methods, what they measure, where they write.
pub struct Walking {
    /// The name the checks refuse a frame with no covered pixel by.
    pub name: &'static str,
    pub frames: u32,
    /// Every method of [`compared`], not only the chosen one.
    pub compare: bool,
    /// Rays of the converged trace each measured frame's error is taken against (0: none).
    pub error_against: u32,
    pub error_every: u32,
    /// The chosen walk's last N frames on one clock (0: none).
    pub timeline: u32,
    pub out: PathBuf,
    /// The pictures' name (`<prefix>.png`, `<prefix>-ao.png`).
    pub prefix: String,
}

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

/// Every walk along the path headless, and the checks of the chosen method's (`budget`: the
/// rays chapter 13's walks of a comparison take, besides their samples).
pub fn headless(
    p: &Passes,
    sized: &mut Sized,
    (chosen, budget): (Drawn, Budget),
    args: &Walking,
    report: &mut Report,
) -> Result<Vec<Walk>> {
    let frames = args.frames;
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
        let (mut records, mut flips) = (Vec::new(), Flips::default());
        let (out, prefix) = (args.out.clone(), args.prefix.clone());
        let mut checks = Checks { chapter: args.name, frames, out, prefix, before_cut: None };
        for frame in 0..frames {
            // The next frame's ids may be drawn at the end of this one unless something reads
            // this frame's back first (the cut's checks, the last frame's, the error).
            let cut = p.path.cut();
            let read_back = (checking && checks.reads_back(p.path, frame))
                || (args.error_against > 0 && measured(frame, args.error_every, cut));
            let next = frame + 1 < frames && !read_back;
            let camera = p.draw(sized, drawn, frame, &mut clock, next)?;
            if checking {
                checks.after(p, sized, (drawn, &camera, frame), report)?;
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
        clock.finish(p)?;
        if let Some(timeline) = clock.finish_timeline(p, &args.out.join("timeline"))? {
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
        let walk = Walk::new(drawn.name(), records, p.path.cut(), args.error_every);
        match (walk.error_mean, walk.error_worst) {
            (Some(mean), Some(worst)) => eprintln!(
                "walk: {frames} frames done ({}): error after the blur {mean:.4} on average, {worst:.4} at worst",
                drawn.described()
            ),
            _ => eprintln!("walk: {frames} frames done ({})", drawn.described()),
        }
        walks.push(walk);
    }
    report.set("frames", frames);
    walks.sort_by_key(|w: &Walk| table.iter().position(|m| m.name() == w.method));
    Ok(walks)
}
