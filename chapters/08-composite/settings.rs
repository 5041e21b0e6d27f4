//! Chapter 08's flags, and the settings the keys change.

use common::frame::View;
use common::rt::accel::BlasLayout;
use common::rt::ao::AoArgs;
use common::scene::SceneArgs;

/// Chapter 08: albedo x ray-traced AO, composited by GL, with depth-correct overlays.
#[derive(clap::Parser)]
pub struct Args {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub ao: AoArgs,
    /// Blur radius in pixels (0 skips the blur).
    #[arg(long, default_value_t = 2, value_parser = common::base::cli::number::<u32>(0..=8))]
    pub blur: u32,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    pub view: View,
    /// Headless: also write every debug view.
    #[arg(long)]
    pub all_views: bool,
    /// Headless: make every shared image anew at another size every K frames, as a window's
    /// resize does (the leak test uses it).
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    pub resize_every: Option<u32>,
    /// The instance whose box is drawn [default: the first tetrahedron, or the first object].
    #[arg(long, value_parser = common::base::cli::number::<usize>(0..=1_000_000))]
    pub select: Option<usize>,
    /// Start this many times closer to the scene's centre than the framing puts the camera (as
    /// the mouse wheel does; from about 3000 on, the far plane is over 10^5 times the near one).
    #[arg(long, default_value_t = 1.0, value_parser = common::scene::parse_zoom, allow_negative_numbers = true)]
    pub zoom: f32,
    /// How the rays' structures hold the triangles: one BLAS per mesh under a TLAS of every
    /// instance (chapter 06), or one flat BLAS of every instance's triangles (see the
    /// performance page).
    #[arg(long, value_enum, default_value = "per-mesh")]
    pub blas: BlasLayout,
}

/// What the keys change (`common::frame::input`, whose `apply_key` takes the views 1 to 6).
pub type Settings = common::frame::input::Settings<View>;
