//! Chapter 13's flags: chapter 12's frame, the rays each pixel traces and what its history
//! keeps, the path the camera and one instance follow, and what to measure along it.

use crate::path::{Mover, PathKind};
use common::frame::fast::composite::View;
use common::rt::accel::BlasLayout;
use common::scene::SceneArgs;

/// The frames a headless run draws unless `--frames` says otherwise: the whole path.
pub const PATH_FRAMES: u32 = 120;

/// Chapter 13: chapter 12's frame, its ambient occlusion reused from frame to frame.
#[derive(clap::Parser)]
pub struct Args {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Rays per pixel per frame where the history is still filling (1-64).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(1..=64))]
    pub samples: u32,
    /// Rays for a pixel with no history: a surface just uncovered, every pixel after a cut (1-256).
    #[arg(long, default_value_t = 32, value_parser = common::base::cli::number::<u32>(1..=256))]
    pub fresh: u32,
    /// The most rays a pixel's mean weighs (1-4096): new rays always count at least
    /// samples / (cap + samples), so a change around the pixel fades in within about cap rays.
    #[arg(long, default_value_t = 128, value_parser = common::base::cli::number::<u32>(1..=4096))]
    pub cap: u32,
    /// A pixel whose history holds `cap` rays traces one frame in this many (0: never again).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=64))]
    pub settled_every: u32,
    /// The most rays a pixel remembers where something moved within the radius of it since the
    /// previous frame (its occlusion changed there, by how much no test can tell from a few new
    /// rays); 0: no limit, the cap alone.
    #[arg(long, default_value_t = 16, value_parser = common::base::cli::number::<u32>(0..=4096))]
    pub near_motion_cap: u32,
    /// Which tests a remembered texel must pass to be reused (`none`: every texel is reused, so
    /// moving things leave ghosts; for measuring what the tests are worth).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "instance,plane,normal")]
    pub accept: Vec<Accept>,
    /// Which points of the sample sequence each pixel takes: chapter 12's 4x4 blocks, carried on
    /// from frame to frame, or chapter 07's rotation per pixel (a still camera then traces
    /// chapter 08's very rays).
    #[arg(long, value_enum, default_value = "tile4x4")]
    pub pattern: Pattern,
    /// Where a pixel with nothing remembered traces its `--fresh` rays: `packed`, in a second
    /// launch, one ray per invocation, over the pixels the first listed; `inline`, in the one
    /// launch, where its warp waits for them while its neighbours trace a few. The same rays
    /// either way, so the same picture.
    #[arg(long, value_enum, default_value = "packed")]
    pub fresh_pass: FreshPass,
    /// When GL draws the next frame's ids: `early`, at the end of this frame, before the CPU
    /// waits for this frame's trace, so that the GPU never waits for the CPU; `late`, after that
    /// wait, as chapter 12 does. The same pictures either way.
    #[arg(long, value_enum, default_value = "early")]
    pub next_ids: NextIds,
    /// `temporal`: this chapter's frame; `fresh`: chapter 12's, new rays every frame and nothing
    /// kept, drawn along the same path for comparison.
    #[arg(long, value_enum, default_value = "temporal")]
    pub method: Method,
    /// How far an occluder counts, in world units, 0 to 1000000 [default: 5% of the scene's
    /// diagonal].
    #[arg(long, value_parser = common::base::cli::number::<f32>(0.0..=1e6), allow_negative_numbers = true)]
    pub radius: Option<f32>,
    /// Contrast: the picture shows visibility to this power (1-3).
    #[arg(long, default_value_t = 2.0, value_parser = common::base::cli::number::<f32>(1.0..=3.0), allow_negative_numbers = true)]
    pub power: f32,
    /// Blur radius in pixels (0 skips the blur), as chapter 12's.
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=8))]
    pub blur: u32,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    pub view: View,
    /// What the camera does: `orbit` (turns about the scene, with one cut), `pan` (slides
    /// sideways), `still`.
    #[arg(long, value_enum, default_value = "orbit")]
    pub path: PathKind,
    /// The orbit's speed, in degrees per frame (0-30).
    #[arg(long, default_value_t = 0.5, value_parser = parse_speed)]
    pub orbit_speed: f32,
    /// The frame at which the orbiting camera jumps to another view (0: no cut).
    #[arg(long, default_value_t = 60, value_parser = common::base::cli::number::<u32>(0..=10_000_000))]
    pub cut_at: u32,
    /// Whether one instance moves while the camera does (`circle`) or not (`none`).
    #[arg(long, value_enum, default_value = "circle")]
    pub mover: Mover,
    /// As chapter 12's `--blas`; only the per-mesh layout lets an instance move.
    #[arg(long, value_enum, default_value = "per-mesh")]
    pub blas: BlasLayout,
    /// Headless: after every `--error-every`th frame, trace this many rays per pixel of the
    /// same frame with no history, and report the frame's error against them after the blur
    /// (0: don't; 1024 is the book's reference).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=1 << 16))]
    pub error_against: u32,
    /// Measure the error on every Kth frame of the path (the frames around the cut always).
    #[arg(long, default_value_t = 1, value_parser = common::base::cli::number::<u32>(1..=1000))]
    pub error_every: u32,
    /// Headless: the last N frames' passes, GL's and Vulkan's on one clock, into timeline.json
    /// and timeline.svg in --out, as chapter 12's (0: none).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=64))]
    pub timeline: u32,
    /// Headless: make the images of one size anew every K frames, as a window's resize does
    /// (the history starts again).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    pub resize_every: Option<u32>,
    /// Headless: draw the path again with chapter 12's frame at 16, 8 and 4 rays and this
    /// chapter's at 1, 2 and 4, each timed and (with --error-against) measured, and write
    /// compare.md, compare.csv and compare.svg to --out.
    #[arg(long)]
    pub compare: bool,
    /// Headless, with --compare: each method's GPU times in the table and in the plot of error
    /// against time come from this compare.csv, written by a run without --error-against (whose
    /// read-backs between frames, and FLIP on the CPU, slow the GPU).
    #[arg(long, requires = "compare")]
    pub times_from: Option<std::path::PathBuf>,
}

/// A test a remembered texel must pass (`--accept`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Accept {
    /// The texel saw the same instance.
    Instance,
    /// The point the texel saw lies on this point's plane.
    Plane,
    /// The texel's normal is this point's.
    Normal,
    /// No test: everything remembered is reused.
    None,
}

/// Which points of the sequence a pixel's rays take (`--pattern`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pattern {
    Tile4x4,
    PerPixel,
}

/// Where the rays of a pixel with nothing remembered are traced (`--fresh-pass`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FreshPass {
    /// In a second launch, one ray per invocation, over the pixels the first listed.
    Packed,
    /// In the one launch, beside the pixels that trace a few.
    Inline,
}

/// When GL draws the next frame's ids (`--next-ids`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NextIds {
    Early,
    Late,
}

/// How a frame's occlusion is made (`--method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    Temporal,
    Fresh,
}

fn parse_speed(text: &str) -> Result<f32, String> {
    common::base::cli::number(0.0..=30.0)(text)
        .map_err(|_| "expected a number of degrees per frame from 0 to 30".into())
}
