//! The flags every chapter accepts, so that scripts and tests can run them all alike.

use crate::instruments::report::Print;
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::time::Duration;

// ANCHOR: number
/// A numeric flag's value parser (`#[arg(long, value_parser = number::<u32>(2..=16))]`): a
/// number within `range`, or clap refuses it before anything runs (exit 2, naming the flag and
/// the range): not a number, NaN, an infinity, a negative number where the range has none,
/// anything past either end. Every numeric flag of every program takes its value through this
/// (or [`seconds`]), so that no value a user can type reaches the code unchecked; a test feeds
/// each flag that `--help` lists such values. Name the type (`::<u32>`): clap checks it against
/// the field's only at run time, and a bare `2..=16` would be an `i32`.
pub fn number<T>(
    range: RangeInclusive<T>,
) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: std::str::FromStr + PartialOrd + std::fmt::Display + Send + Sync + 'static,
{
    let range = std::sync::Arc::new(range);
    move |text: &str| match text.trim().parse::<T>() {
        // NaN is within no range: every comparison with it is false.
        Ok(value) if range.contains(&value) => Ok(value),
        _ => Err(format!("expected a number from {} to {}", range.start(), range.end())),
    }
}

/// [`number`] for a flag in seconds, as a `Duration` (which would panic on NaN, an infinity or
/// a negative number: they never reach it).
pub fn seconds(
    range: RangeInclusive<f64>,
) -> impl Fn(&str) -> Result<Duration, String> + Clone + Send + Sync + 'static {
    let (start, end) = (*range.start(), *range.end());
    let number = number(range);
    move |text: &str| {
        let seconds =
            number(text).map_err(|_| format!("expected a number of seconds from {start} to {end}"))?;
        Ok(Duration::from_secs_f64(seconds))
    }
}
// ANCHOR_END: number

/// Flags shared by every chapter: `run_chapter` puts them before the chapter's own (`--time`
/// where it animates, `--scene` where it loads a model), and `Flags` holds both.
#[derive(clap::Args, Debug, Clone)]
pub struct CommonArgs {
    /// No window: render offscreen and write images to --out.
    #[arg(long)]
    pub headless: bool,

    /// Size of what the chapter renders or allocates, as WIDTHxHEIGHT (each chapter states its
    /// smallest; the largest is the device's).
    #[arg(long, default_value = "800x600", value_parser = parse_size)]
    pub size: Size,

    /// How many frames to run, 0 to 10000000 [default: 1 headless; a window runs until it is
    /// closed, as with 0].
    #[arg(long, value_parser = number::<u32>(0..=10_000_000))]
    pub frames: Option<u32>,

    /// Where images go [default: out/<chapter>/].
    #[arg(long)]
    pub out: Option<PathBuf>,

    /// Print exactly one JSON report on stdout; everything human-readable goes to stderr.
    #[arg(long)]
    pub json: bool,
}

impl CommonArgs {
    /// Frames to run headless: `--frames N`, at least 1 (there is nothing to close), else 1.
    pub fn headless_frames(&self) -> u32 {
        self.frames.map_or(1, |n| n.max(1))
    }

    /// Frames to show in a window: `--frames N`, else 0, "until the window is closed".
    pub fn window_frames(&self) -> u32 {
        self.frames.unwrap_or(0)
    }

    /// What the report prints: all of it as JSON on stdout with `--json`.
    pub fn print(&self) -> Print {
        if self.json { Print::Json } else { Print::Summary }
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
    #[arg(long, default_value_t = 0.0, value_parser = number::<f32>(-1e5..=1e5), allow_negative_numbers = true)]
    pub time: f32,
    /// Seconds between frames (0: nothing moves, and the occlusion accumulates).
    #[arg(long, default_value_t = 1.0 / 30.0, value_parser = number::<f32>(0.0..=3600.0), allow_negative_numbers = true)]
    pub step: f32,
    /// Rebuild the structure that moves every K frames instead of updating it in place (0: never).
    #[arg(long, default_value_t = 0, value_parser = number::<u32>(0..=1_000_000))]
    pub rebuild_every: u32,
    /// Headless: write every frame, not only the first and the last.
    #[arg(long)]
    pub every_frame: bool,
}

impl AnimationArgs {
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

impl Size {
    /// The same size as Vulkan's `VkExtent2D`.
    pub fn extent(self) -> ash::vk::Extent2D {
        ash::vk::Extent2D { width: self.width, height: self.height }
    }

    /// Width over height, as a camera's projection takes it.
    pub fn aspect(self) -> f32 {
        self.width as f32 / self.height as f32
    }
}

impl std::fmt::Display for Size {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

/// The largest side `--size` takes: a guard against typing mistakes, not a device limit (the
/// largest any GPU of today allows, NVIDIA's 32768). The device's own limits ([`Largest`]) are
/// checked once its contexts exist.
pub const TYPED_LIMIT: u32 = 32768;

/// `WIDTHxHEIGHT`, each side 1 to [`TYPED_LIMIT`].
pub fn parse_size(text: &str) -> Result<Size, String> {
    let bad = || format!("expected WIDTHxHEIGHT, such as 800x600, not {text:?}");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let width: u32 = w.trim().parse().map_err(|_| bad())?;
    let height: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(1..=TYPED_LIMIT).contains(&width) || !(1..=TYPED_LIMIT).contains(&height) {
        return Err(format!("{width}x{height}: each side must be between 1 and {TYPED_LIMIT}"));
    }
    Ok(Size { width, height })
}

// ANCHOR: smallest
/// The smallest picture a program can draw and still check, stated by each program with why:
/// its checks probe pixels that need room, or count pixels that must be enough to mean something.
#[derive(Debug, Clone, Copy)]
pub struct Smallest {
    pub width: u32,
    pub height: u32,
    /// What the checks need the pixels for, in a few words.
    pub why: &'static str,
    /// The widest and the tallest shape the checks hold at, each as a ratio of the sides
    /// (width / height, height / width), and why (`None`: any shape).
    pub shape: Option<(f32, f32, &'static str)>,
}

impl Smallest {
    /// Any size: nothing the program checks depends on how many pixels there are.
    pub const ANY: Smallest = Smallest { width: 1, height: 1, why: "", shape: None };

    /// Refuses `size` (an error, which `run_chapter` turns into exit 2) when it is smaller than
    /// this on either side, or wider or taller than `shape`; before anything is made.
    pub fn check(&self, program: &str, size: Size) -> anyhow::Result<()> {
        self.check_flag("--size", program, size)
    }

    /// [`Smallest::check`] for a size given by `flag` (the bench's `--sizes`).
    pub fn check_flag(&self, flag: &str, program: &str, size: Size) -> anyhow::Result<()> {
        match self.unfit(size) {
            Some((what, need)) => {
                anyhow::bail!("{flag} {size} is {what} for {program}: its checks need {need}")
            }
            None => Ok(()),
        }
    }

    /// Why the checks cannot judge a picture of `size`, if they cannot: what it is ("too small",
    /// "too wide", "too tall") and what they need. Only headless runs are refused: a window's
    /// checks say themselves which of them its size leaves unjudged.
    pub fn unfit(&self, size: Size) -> Option<(&'static str, String)> {
        if size.width < self.width || size.height < self.height {
            return Some((
                "too small",
                format!("at least {}x{} pixels ({})", self.width, self.height, self.why),
            ));
        }
        let (widest, tallest, why) = self.shape?;
        let (width, height) = (size.width as f32, size.height as f32);
        if width > widest * height {
            return Some(("too wide", format!("a width of at most {widest} times the height ({why})")));
        }
        if height > tallest * width {
            return Some(("too tall", format!("a height of at most {tallest} times the width ({why})")));
        }
        None
    }
}
// ANCHOR_END: smallest

/// Refuses a size the scene covers no pixel of (an error, which `run_chapter` turns into exit 2),
/// found once GL has drawn it: every mean, minimum and check over the covered pixels would be
/// over none, and a mean of nothing is not a number. `flag` is `--size` (the bench's `--sizes`).
pub fn check_covered(flag: &str, program: &str, size: Size, covered: u64) -> anyhow::Result<()> {
    let shape = match size.width.cmp(&size.height) {
        std::cmp::Ordering::Greater => "wide",
        std::cmp::Ordering::Less => "tall",
        std::cmp::Ordering::Equal => "small",
    };
    anyhow::ensure!(
        covered > 0,
        "{flag} {size} is too {shape} for {program}: the scene covers no pixel of it, and a mean or a \
         check over no pixel means nothing (a shape nearer the scene's, such as 800x600, shows it)"
    );
    Ok(())
}

// ANCHOR: largest
/// The largest picture a device allows, and the limits that set it.
#[derive(Debug, Clone)]
pub struct Largest {
    pub width: u32,
    pub height: u32,
    /// The most pixels in all (`u64::MAX`: no bound beyond the sides).
    pub pixels: u64,
    /// The device, and each limit with its value, e.g. "llvmpipe: Vulkan maxImageDimension2D
    /// 16384, GL_MAX_TEXTURE_SIZE 16384".
    pub limits: String,
}

impl Largest {
    /// Refuses `size` when either side is beyond what the device allows; before anything is made.
    pub fn check(&self, program: &str, size: Size) -> anyhow::Result<()> {
        self.check_flag("--size", program, size)
    }

    /// [`Largest::check`] for a size given by `flag` (the bench's `--sizes`).
    pub fn check_flag(&self, flag: &str, program: &str, size: Size) -> anyhow::Result<()> {
        anyhow::ensure!(
            size.width <= self.width && size.height <= self.height,
            "{flag} {size} is too large for {program}: at most {}x{} pixels here ({})",
            self.width,
            self.height,
            self.limits
        );
        let pixels = size.width as u64 * size.height as u64;
        anyhow::ensure!(
            pixels <= self.pixels,
            "{flag} {size} is too large for {program}: at most {} pixels in all here, e.g. {side}x{side} ({})",
            self.pixels,
            self.limits,
            side = (self.pixels as f64).sqrt() as u64
        );
        Ok(())
    }
}
// ANCHOR_END: largest

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sizes() {
        assert_eq!(parse_size("800x600"), Ok(Size { width: 800, height: 600 }));
        assert_eq!(parse_size("7X3"), Ok(Size { width: 7, height: 3 }));
        assert!(parse_size("800").is_err());
        assert!(parse_size("0x600").is_err());
        assert!(parse_size("32768x10").is_ok());
        assert!(parse_size("32769x10").is_err());
        assert!(parse_size("axb").is_err());
    }

    #[test]
    fn refuses_what_is_too_small_too_tall_or_too_large() {
        let at = |width, height| Size { width, height };
        let smallest = Smallest { width: 16, height: 8, why: "room", shape: Some((2.0, 1.0, "framing")) };
        assert!(smallest.check("p", at(16, 8)).is_ok());
        assert!(smallest.check("p", at(16, 16)).is_ok());
        let small = smallest.check("p", at(15, 8)).unwrap_err().to_string();
        assert_eq!(small, "--size 15x8 is too small for p: its checks need at least 16x8 pixels (room)");
        assert!(smallest.check("p", at(16, 7)).is_err());
        assert!(smallest.check("p", at(16, 17)).unwrap_err().to_string().contains("too tall"));
        assert!(smallest.check("p", at(32, 16)).is_ok());
        assert!(smallest.check("p", at(33, 16)).unwrap_err().to_string().contains("too wide"));
        assert!(Smallest::ANY.check("p", at(1, 1)).is_ok());
        assert!(check_covered("--size", "p", at(16384, 1), 1).is_ok());
        let uncovered = check_covered("--size", "p", at(16384, 1), 0).unwrap_err().to_string();
        assert_eq!(
            uncovered,
            "--size 16384x1 is too wide for p: the scene covers no pixel of it, and a mean or a check over \
             no pixel means nothing (a shape nearer the scene's, such as 800x600, shows it)"
        );
        assert!(check_covered("--size", "p", at(1, 16384), 0).unwrap_err().to_string().contains("too tall"));
        assert!(
            check_covered("--sizes", "p", at(2, 2), 0)
                .unwrap_err()
                .to_string()
                .starts_with("--sizes 2x2 is too small")
        );
        let largest = Largest { width: 100, height: 50, pixels: 4000, limits: "limit 100".into() };
        assert!(largest.check("p", at(80, 50)).is_ok());
        assert!(largest.check("p", at(100, 40)).is_ok());
        let large = largest.check("p", at(101, 1)).unwrap_err().to_string();
        assert_eq!(large, "--size 101x1 is too large for p: at most 100x50 pixels here (limit 100)");
        assert!(largest.check("p", at(1, 51)).is_err());
        let many = largest.check("p", at(81, 50)).unwrap_err().to_string();
        assert!(many.contains("at most 4000 pixels in all here, e.g. 63x63"), "{many}");
    }
}
