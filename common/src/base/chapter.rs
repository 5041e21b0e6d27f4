//! The contract every chapter shares: its size checked, run, report, exit code; and the few steps
//! every chapter from 03 on repeats (both contexts connected, open fds counted, CPU time measured).

use super::cli::{CommonArgs, Largest, Size, Smallest};
use super::gl::{self, GlContext, MEMORY_EXTENSIONS};
use super::vulkan::{self, Requirements, VulkanContext};
use super::window;
use super::window::Window;
use crate::instruments::report::{Print, Report};
use crate::instruments::{fail, resources};
use std::process::ExitCode;

/// The flags a chapter runs with: its own (`A`, which `Flags` derefs to: `args.scene`), and
/// those every chapter takes (`args.common`), which [`run_chapter`] adds to the chapter's.
pub struct Flags<A> {
    pub common: CommonArgs,
    own: A,
}

impl<A> std::ops::Deref for Flags<A> {
    type Target = A;
    fn deref(&self) -> &A {
        &self.own
    }
}

/// Runs a chapter with the contract every chapter shares: parse the flags (the chapter's own,
/// `A`, and [`CommonArgs`]), refuse a `--size` smaller than the chapter's checks need
/// (`smallest`) before anything is made, run, then print the report (as JSON with `--json`) and
/// turn failed checks or validation errors into a non-zero exit.
///
/// Exit codes: 0 all checks passed; 1 a check failed or the validation layer reported an error;
/// 2 the chapter could not run (missing extension, bad input ...), with the reason on stderr.
pub fn run_chapter<A: clap::Args + clap::FromArgMatches>(
    chapter: &'static str,
    smallest: Smallest,
    run: impl FnOnce(&Flags<A>, &mut Report) -> anyhow::Result<()>,
) -> ExitCode {
    run_chapter_with_args(chapter, smallest, std::env::args_os(), run)
}

/// [`run_chapter`] for a chapter that draws live in a window where there is a display: a window
/// is never refused for its size (the user may make it any size anyway). `smallest` is then the
/// chapter's to apply: a check that cannot mean anything at the window's size is reported as not
/// judged ([`Report::not_judged`], [`Smallest::fits`]). Headless, the size is refused as ever.
pub fn run_chapter_in_window<A: clap::Args + clap::FromArgMatches>(
    chapter: &'static str,
    smallest: Smallest,
    run: impl FnOnce(&Flags<A>, &mut Report) -> anyhow::Result<()>,
) -> ExitCode {
    run_flags(chapter, smallest, std::env::args_os(), true, run)
}

/// [`run_chapter`] on `args` (the program's name first) instead of the process's own: for a
/// tool whose subcommand drives a chapter's frame (`convergence temporal`).
pub fn run_chapter_with_args<A: clap::Args + clap::FromArgMatches>(
    chapter: &'static str,
    smallest: Smallest,
    args: impl IntoIterator<Item = std::ffi::OsString>,
    run: impl FnOnce(&Flags<A>, &mut Report) -> anyhow::Result<()>,
) -> ExitCode {
    run_flags(chapter, smallest, args, false, run)
}

/// The contract, on `args`; `windowed`: the chapter opens a window where there is a display, and
/// `smallest` refuses a size only when it will run headless.
fn run_flags<A: clap::Args + clap::FromArgMatches>(
    chapter: &'static str,
    smallest: Smallest,
    args: impl IntoIterator<Item = std::ffi::OsString>,
    windowed: bool,
    run: impl FnOnce(&Flags<A>, &mut Report) -> anyhow::Result<()>,
) -> ExitCode {
    use clap::{Args as _, FromArgMatches as _};
    // Every chapter's flags, then the chapter's own (whose doc comment is the command's about);
    // a flag clap refuses exits here, with code 2 and clap's message, as `A::parse` would.
    let mut command = A::augment_args(CommonArgs::augment_args(clap::Command::new(chapter)));
    let matches = command.try_get_matches_from_mut(args).unwrap_or_else(|error| error.exit());
    let parsed = A::from_arg_matches(&matches)
        .and_then(|own| Ok(Flags { common: CommonArgs::from_arg_matches(&matches)?, own }));
    let args = parsed.unwrap_or_else(|error| error.format(&mut command).exit());
    let common = &args.common;
    let mut report = Report::new(chapter);
    let result = accounted(|| {
        if !windowed || common.headless || !window::display_available() {
            smallest.check(chapter, common.size)?;
        }
        run(&args, &mut report)
    });
    if let Err(error) = result {
        eprintln!("error: {error:#}");
        return ExitCode::from(2);
    }
    show_pictures(chapter, common, &mut report);
    finish(report, common.print())
}

/// Runs `run`, having checked `VKGL_FAIL_AT` (`instruments::fail`); when it is set, prints what `run`
/// left behind on stderr: the fds it opened and did not close, and the counted resources still
/// alive. (`run_chapter` does this for every chapter; `bench` and `convergence` call it.)
pub fn accounted<T>(run: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<T> {
    fail::check_armed()?;
    // With `VKGL_FAIL_AT` set, the fds open before anything ran, to compare at exit.
    let fds_before = fail::armed().map(|_| resources::open_fds());
    let result = run();
    if let Some(before) = fds_before {
        // Everything `run` made is gone by now (dropped at its end, or on the way out of an
        // early return): so must its fds be. Drivers may keep a few of their own.
        let left: Vec<_> = resources::open_fds().into_iter().filter(|fd| !before.contains(fd)).collect();
        eprintln!("fds: left open after the chapter ran: {left:?}");
        // And the objects whose destruction is counted (exportable memory and images, every GL
        // object, which would otherwise die unseen with its context): none may be alive.
        let alive: Vec<_> = resources::live().into_iter().filter(|(_, n)| *n != 0).collect();
        eprintln!("resources: alive after the chapter ran: {alive:?}");
    }
    result
}

/// Fills in what the run left behind (the validation layer's and GL's error counts, the
/// resources created), prints the report and decides the exit code. The report knows nothing
/// of either API (no module cycle): the counts are gathered here.
pub fn finish(mut report: Report, print: Print) -> ExitCode {
    report.validation = vulkan::validation_counts();
    report.resources = resources::list();
    report.validation.gl_errors = gl::gl_error_count();
    report.finish(print)
}

/// A chapter that computed its pictures headless shows them in a window when there is a
/// display (and no `--headless`), and says so when there is none. Chapters with windows of their
/// own (04, 08) report `window` themselves.
fn show_pictures(chapter: &str, common: &CommonArgs, report: &mut Report) {
    if report.images.is_empty() || report.details.contains_key("window") {
        return;
    }
    let out = common.out_dir(chapter);
    let shown = if common.headless {
        false
    } else if !window::display_available() {
        eprintln!("window: {}; the pictures are in {}", window::no_display_reason(), out.display());
        false
    } else {
        let pictures: Vec<_> =
            report.images.iter().map(|i| (i.name.clone(), std::path::PathBuf::from(&i.path))).collect();
        match window::show_pictures(chapter, &pictures, common.window_frames()) {
            Ok(seen) => {
                report.check("window_shows_the_pictures", seen);
                true
            }
            Err(error) => {
                eprintln!("window: cannot show the pictures ({error:#}); they are in {}", out.display());
                false
            }
        }
    };
    report.set("window", shown);
}

// ANCHOR: connect
/// What every chapter from 03 on does once both contexts exist (chapter 02 spells it out): fill
/// the report's `vulkan`, `gl` and `uuids_match`, and fail unless both run on the same device.
pub fn connect(report: &mut Report, vk: &VulkanContext, gl: &GlContext) -> anyhow::Result<()> {
    report.vulkan = Some(vk.report());
    report.gl = Some(gl.report());
    report.uuids_match = Some(gl::uuids_match(&vk.info, gl));
    gl::ensure_same_device(&vk.info, gl)
}
// ANCHOR_END: connect

// ANCHOR: contexts
/// Both contexts on one device, as chapter 03 made them, for a picture of `size` (which
/// [`run_chapter`] has checked against the chapter's smallest): Vulkan with `requirements`, and a
/// headless GL context on the EGL device with Vulkan's UUID and the memory-object extensions;
/// [`connect`]ed, and `size` refused if either API cannot hold it ([`largest_size`]).
pub fn contexts(
    chapter: &str,
    report: &mut Report,
    requirements: &Requirements,
    size: Size,
) -> anyhow::Result<(VulkanContext, GlContext)> {
    let vk = VulkanContext::new(requirements)?;
    let gl = GlContext::headless(&vk.info, &MEMORY_EXTENSIONS)?;
    connect(report, &vk, &gl)?;
    largest_size(&vk, &gl).check(chapter, size)?;
    Ok((vk, gl))
}
// ANCHOR_END: contexts

/// [`contexts`], with GL in a window as chapter 04 opened it, titled with the chapter's number and
/// name ("08 · composite"): unless `--headless` is given or there is no display (said on
/// stderr), when GL is headless. The report's `window`
/// says which. Dropped in the order bound: GL's context, the window, then Vulkan's.
pub fn contexts_in_window(
    chapter: &str,
    report: &mut Report,
    requirements: &Requirements,
    common: &CommonArgs,
) -> anyhow::Result<(VulkanContext, Option<Window>, GlContext)> {
    let vk = VulkanContext::new(requirements)?;
    let title = chapter.replacen('-', " · ", 1).replace('-', " ");
    let (window, gl) = gl_in_window(&title, common.size, &vk.info, common.headless)?;
    connect(report, &vk, &gl)?;
    largest_size(&vk, &gl).check(chapter, common.size)?;
    report.set("window", window.is_some());
    Ok((vk, window, gl))
}

/// GL with [`MEMORY_EXTENSIONS`] in a window titled `title`, unless `headless` or there is no
/// display (said on stderr); else headless GL on `vulkan`'s device. In a window the window
/// system picks GL's device: the UUID check must follow.
pub fn gl_in_window(
    title: &str,
    size: Size,
    vulkan: &vulkan::DeviceInfo,
    headless: bool,
) -> anyhow::Result<(Option<Window>, GlContext)> {
    if headless || !window::display_available() {
        if !headless {
            eprintln!("window: {}: running headless", window::no_display_reason());
        }
        return Ok((None, GlContext::headless(vulkan, &MEMORY_EXTENSIONS)?));
    }
    let (window, gl) = Window::open(title, size, &MEMORY_EXTENSIONS)?;
    Ok((Some(window), gl))
}

// ANCHOR: largest_size
/// The largest picture both APIs allow on this device: Vulkan's `maxImageDimension2D`, and GL's
/// largest texture, renderbuffer and viewport; and as many RGBA8 pixels as GL reads back in one
/// call (`glReadPixels` writes at most `i32::MAX` bytes: a GLsizei), which every chapter's checks
/// do. Each is named in the refusal, with its value.
pub fn largest_size(vk: &VulkanContext, gl: &GlContext) -> Largest {
    use glow::HasContext as _;
    let limits = unsafe { vk.instance.get_physical_device_properties(vk.physical_device) }.limits;
    let vulkan = limits.max_image_dimension2_d;
    let (texture, renderbuffer, mut viewport) = unsafe {
        let texture = gl.gl.get_parameter_i32(glow::MAX_TEXTURE_SIZE).max(0) as u32;
        let renderbuffer = gl.gl.get_parameter_i32(glow::MAX_RENDERBUFFER_SIZE).max(0) as u32;
        (texture, renderbuffer, [0i32; 2])
    };
    unsafe { gl.gl.get_parameter_i32_slice(glow::MAX_VIEWPORT_DIMS, &mut viewport) };
    let side = vulkan.min(texture).min(renderbuffer);
    Largest {
        width: side.min(viewport[0].max(0) as u32),
        height: side.min(viewport[1].max(0) as u32),
        pixels: i32::MAX as u64 / 4,
        limits: format!(
            "{}: Vulkan maxImageDimension2D {vulkan}, GL_MAX_TEXTURE_SIZE {texture}, \
             GL_MAX_RENDERBUFFER_SIZE {renderbuffer}, GL_MAX_VIEWPORT_DIMS {}x{}; GL reads back at \
             most {} bytes in one call, 4 a pixel",
            vk.info.name,
            viewport[0],
            viewport[1],
            i32::MAX
        ),
    }
}
// ANCHOR_END: largest_size

/// Milliseconds since `start` (CPU time; GPU work is timed with timestamps).
pub fn ms_since(start: std::time::Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}
