//! Chapter 08's flags and settings: what the flags start with and the keys change, and the
//! composite's uniforms that follow from them.

use common::CommonArgs;
use common::base::window::Key;
use common::frame::{Uniforms, View};
use common::rt::accel::BlasLayout;
use common::rt::ao::AoArgs;
use common::scene::{Camera, Scene, SceneArgs};

/// Chapter 08: albedo x ray-traced AO, composited by GL, with depth-correct overlays.
#[derive(clap::Parser)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub ao: AoArgs,
    /// Blur radius in pixels (0 skips the blur).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(0..=8))]
    pub blur: u32,
    /// Which picture to show.
    #[arg(long, value_enum, default_value = "final")]
    pub view: View,
    /// Headless: also write every debug view.
    #[arg(long)]
    pub all_views: bool,
    /// Headless: make every shared image anew at another size every K frames, as a window's
    /// resize does (the leak test uses it).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub resize_every: Option<u32>,
    /// The instance whose box is drawn [default: the first tetrahedron, or the first object].
    #[arg(long)]
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

/// What the keys change. Only the radius changes what the occlusion measures; the rest change how
/// many rays a frame adds or how the mean is shown.
#[derive(Clone, Copy, PartialEq)]
pub struct Settings {
    pub samples: u32,
    pub radius: f32,
    pub power: f32,
    pub blur: u32,
    pub view: View,
    pub overlays: bool,
}

// ANCHOR: keys
pub fn apply_key(key: &Key, s: &mut Settings) {
    // Named keys do nothing here: Esc ends the loop before keys get here.
    let Key::Character(c) = key.as_ref() else { return };
    match c {
        "1" | "2" | "3" | "4" | "5" | "6" => s.view = View::from_index(c.parse::<u32>().unwrap() - 1),
        "+" | "=" => s.samples = (s.samples * 2).clamp(1, 256),
        "-" => s.samples = (s.samples / 2).max(1),
        "]" => s.radius *= 1.25,
        "[" => s.radius /= 1.25,
        "b" | "B" => s.blur = (s.blur + 1) % 5,
        "p" | "P" => s.power = s.power.floor() % 3.0 + 1.0, // 1, 2, 3, 1 ...
        "o" | "O" => s.overlays = !s.overlays,
        _ => {}
    }
}
// ANCHOR_END: keys

pub fn uniforms(s: &Settings, scene: &Scene, camera: &Camera) -> Uniforms {
    Uniforms {
        blur_radius: s.blur as i32,
        depth_tolerance: 0.02,
        normal_tolerance: 0.9,
        power: s.power,
        view: s.view,
        bounds: scene.bounds,
        far_depth: camera.far,
    }
}
