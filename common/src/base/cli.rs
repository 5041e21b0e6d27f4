//! The flags every chapter accepts, so that scripts and tests can run them all alike.

use std::path::PathBuf;

/// Flags shared by every chapter. A chapter embeds these with `#[command(flatten)]` and adds its
/// own (`--time` where it animates, `--scene` where it loads a model).
#[derive(clap::Args, Debug, Clone)]
pub struct CommonArgs {
    /// No window: render offscreen and write images to --out.
    #[arg(long)]
    pub headless: bool,

    /// Size of what the chapter renders or allocates, as WIDTHxHEIGHT.
    #[arg(long, default_value = "800x600", value_parser = parse_size)]
    pub size: Size,

    /// How many frames to run [default: 1 headless; a window runs until it is closed].
    #[arg(long)]
    pub frames: Option<u32>,

    /// Where images go [default: out/<chapter>/].
    #[arg(long)]
    pub out: Option<PathBuf>,

    /// Print exactly one JSON report on stdout; everything human-readable goes to stderr.
    #[arg(long)]
    pub json: bool,
}

impl CommonArgs {
    /// Frames to run: `--frames N`, else 1 headless and 0 ("until closed") in a window. Headless,
    /// at least 1: there is nothing to close.
    pub fn frame_count(&self, windowed: bool) -> u32 {
        match (self.frames, windowed) {
            (Some(n), true) => n,
            (Some(n), false) => n.max(1),
            (None, true) => 0,
            (None, false) => 1,
        }
    }

    /// The folder images go to: `--out`, or `out/<chapter>/`.
    pub fn out_dir(&self, chapter: &str) -> PathBuf {
        self.out.clone().unwrap_or_else(|| PathBuf::from("out").join(chapter))
    }
}

/// The flags of the chapters that animate (09, 10): a reproducible sequence of frames.
#[derive(clap::Args, Debug, Clone)]
pub struct AnimationArgs {
    /// The time of the first frame, in seconds.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub time: f32,
    /// Seconds between frames (0: nothing moves, and the occlusion accumulates).
    #[arg(long, default_value_t = 1.0 / 30.0, allow_negative_numbers = true)]
    pub step: f32,
    /// Rebuild the structure that moves every K frames instead of updating it in place (0: never).
    #[arg(long, default_value_t = 0)]
    pub rebuild_every: u32,
    /// Headless: write every frame, not only the first and the last.
    #[arg(long)]
    pub every_frame: bool,
}

impl AnimationArgs {
    /// Refuses a time that is not a number and a step that is not 0 or more seconds.
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.step.is_finite() && self.step >= 0.0,
            "--step {}: must be 0 or more seconds",
            self.step
        );
        anyhow::ensure!(self.time.is_finite(), "--time {}: must be a number of seconds", self.time);
        Ok(())
    }

    /// The animation time of frame `frame`.
    pub fn at(&self, frame: u32) -> f32 {
        self.time + frame as f32 * self.step
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Size {
    pub width: u32,
    pub height: u32,
}

fn parse_size(text: &str) -> Result<Size, String> {
    let bad = || format!("expected WIDTHxHEIGHT, such as 800x600, not {text:?}");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let width: u32 = w.trim().parse().map_err(|_| bad())?;
    let height: u32 = h.trim().parse().map_err(|_| bad())?;
    // A sanity bound for typing mistakes; the device's own limits are checked where images are made.
    if !(1..=16384).contains(&width) || !(1..=16384).contains(&height) {
        return Err(format!("{width}x{height}: each side must be between 1 and 16384"));
    }
    Ok(Size { width, height })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sizes() {
        assert_eq!(parse_size("800x600"), Ok(Size { width: 800, height: 600 }));
        assert_eq!(parse_size("7X3"), Ok(Size { width: 7, height: 3 }));
        assert!(parse_size("800").is_err());
        assert!(parse_size("0x600").is_err());
        assert!(parse_size("20000x10").is_err());
        assert!(parse_size("axb").is_err());
    }
}
