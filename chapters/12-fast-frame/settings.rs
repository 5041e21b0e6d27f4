//! Chapter 12's flags and settings: what the flags start with and the keys change, and what
//! follows from them (the rays a frame traces).

use common::base::window::Key;
use common::frame::input;
use common::rt::accel::BlasLayout;
use common::rt::ao::AoArgs;
use common::scene::SceneArgs;
use fast_frame::composite::View;
use fast_frame::trace::{Pattern, Rays};

/// Chapter 12: chapter 08's frame from a visibility buffer, with a compute composite.
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
    /// Which points of the AO sample sequence each pixel takes: 4x4 blocks sharing one run
    /// (the least error after the blur, measured), per pixel (chapter 07's), or shared by 8x8
    /// tiles for coherent rays (see the book for what each does to time and error).
    #[arg(long, value_enum, default_value = "tile4x4")]
    pub pattern: Pattern,
    /// As chapter 08's `--blas`: one flat BLAS of every instance (measured faster here), or one
    /// BLAS per mesh.
    #[arg(long, value_enum, default_value = "flat")]
    pub blas: BlasLayout,
    /// Start this many times closer to the scene's centre than the framing puts the camera.
    #[arg(long, default_value_t = 1.0, value_parser = common::scene::parse_zoom, allow_negative_numbers = true)]
    pub zoom: f32,
    /// After the frames: trace one fresh frame of --samples rays per pixel, then a converged one
    /// of this many, and report how far the fresh frame's occlusion is from the converged one,
    /// before and after the blur (0: don't).
    #[arg(long, default_value_t = 0, value_parser = common::base::cli::number::<u32>(0..=1 << 20))]
    pub error_against: u32,
    /// Headless: make the images of one size anew every K frames, as a window's resize does.
    #[arg(long, value_parser = common::base::cli::number::<u32>(1..=1_000_000))]
    pub resize_every: Option<u32>,
}

/// What the keys change: chapter 08's (`common::frame::input`, less its debug views of
/// positions), and T for the sample pattern.
#[derive(Clone, Copy, PartialEq)]
pub struct Settings {
    pub keys: input::Settings<View>,
    pub pattern: Pattern,
}

impl std::ops::Deref for Settings {
    type Target = input::Settings<View>;
    fn deref(&self) -> &Self::Target {
        &self.keys
    }
}

pub fn apply_key(key: &Key, s: &mut Settings) {
    if !s.keys.apply_key(key, &View::ALL) && matches!(key.as_ref(), Key::Character("t" | "T")) {
        s.pattern = Pattern::ALL[(s.pattern as usize + 1) % Pattern::ALL.len()];
    }
}

impl Settings {
    pub fn rays(&self, samples: u32, scene_scale: f32) -> Rays {
        Rays { samples, radius: self.radius, scene_scale, pattern: self.pattern, salt: 0 }
    }
}
