//! A window with a GL 4.5 core context (taught in chapter 04): winit makes the window and
//! delivers its events, glutin makes the context, glutin-winit's `DisplayBuilder` matches the two.
//!
//! The chapters own their frame loop, so that one loop draws offscreen (`--headless`) or into a
//! window. The window therefore does not hand control to winit's `run_app`; it *pumps* winit's
//! event loop once a frame (`pump_app_events`, which X11 and Wayland support) through an
//! `ApplicationHandler` that keeps only what is safe to handle later on Linux: key presses,
//! resizes and the close request. Rendering stays in the chapter's loop.

use super::panel::Panel;
use crate::base::cli::Size;
use crate::base::gl::{GlContext, create};
use anyhow::{Context as _, Result, anyhow, bail};
use glutin::config::{Config, ConfigTemplateBuilder, GlConfig as _};
use glutin::context::{ContextApi, ContextAttributesBuilder, GlProfile, PossiblyCurrentContext, Version};
use glutin::display::{Display, GetGlDisplay as _};
use glutin::prelude::*;
use glutin::surface::{Surface, SwapInterval, WindowSurface};
use glutin_winit::{ApiPreference, DisplayBuilder, GlWindow as _};
use std::num::NonZeroU32;
use std::time::Duration;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::platform::pump_events::{EventLoopExtPumpEvents as _, PumpStatus};
use winit::raw_window_handle::HasWindowHandle as _;
use winit::window::WindowId;

pub use winit::keyboard::{Key, NamedKey};

/// The variables that name a display this build can open a window on. Wayland's is among them
/// only with the cargo feature `wayland`: without it winit speaks X11 alone, which a Wayland
/// desktop offers through XWayland (`DISPLAY` is set there too), and the build skips Wayland's
/// protocol crates, a fifth of the release build's CPU time.
pub const DISPLAY_VARIABLES: &[&str] =
    if cfg!(feature = "wayland") { &["DISPLAY", "WAYLAND_DISPLAY"] } else { &["DISPLAY"] };

/// Is there a display to open a window on (one of [`DISPLAY_VARIABLES`] set)?
pub fn display_available() -> bool {
    DISPLAY_VARIABLES.iter().any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

/// Why no window opens: no display variable is set. Where only Wayland's is set and this build
/// has no Wayland, it says how to get one.
pub fn no_display_reason() -> String {
    let unset = DISPLAY_VARIABLES.join(" / ");
    let wayland_only = std::env::var_os("WAYLAND_DISPLAY").is_some_and(|s| !s.is_empty());
    if wayland_only && !cfg!(feature = "wayland") {
        format!(
            "no display ({unset} unset; WAYLAND_DISPLAY is set, but this build speaks X11 only: \
             start XWayland, or build with `--features wayland`)"
        )
    } else {
        format!("no display ({unset} unset)")
    }
}

/// An open window whose GL surface is current with the chapter's [`GlContext`].
pub struct Window {
    event_loop: EventLoop<()>,
    app: App,
    /// When the title last showed the frame times.
    titled: Option<std::time::Instant>,
}

#[derive(Default)]
struct App {
    title: String,
    size: Option<Size>,
    /// Made in `resumed`, the first moment winit allows it.
    opened: Option<Opened>,
    /// The context made in `resumed`, until `Window::open` wraps it in a `GlContext`.
    context: Option<(PossiblyCurrentContext, Display)>,
    error: Option<anyhow::Error>,
    keys: Vec<Key>,
    resized: Option<PhysicalSize<u32>>,
    close_requested: bool,
    /// Mouse movement with the left button held, in pixels, since it was last taken.
    drag: (f32, f32),
    dragging: bool,
    cursor: Option<winit::dpi::PhysicalPosition<f64>>,
    /// Wheel movement in lines since it was last taken.
    scroll: f32,
    /// Made once the context is current; it sees every event first.
    panel: Option<Panel>,
}

struct Opened {
    // Field order is drop order: the surface goes before the window it draws into.
    surface: Surface<WindowSurface>,
    window: winit::window::Window,
}

impl Window {
    /// Opens a `size` window with a GL 4.5 core context current on it, and wraps the context as
    /// [`GlContext::new`] does (failing, naming each one, when an extension in `required` is missing).
    pub fn open(title: &str, size: Size, required: &[&str]) -> Result<(Window, GlContext)> {
        let mut event_loop = EventLoop::new().map_err(|error| {
            // winit loads libX11, libXcursor, libXi and libxkbcommon-x11 when it starts: a
            // machine with no desktop may have only some of them.
            let hint = if error.to_string().contains("shared librar") {
                " (a library winit loads is missing: `bash .ci/deps` installs libxcursor1, libxi6 \
                 and libxkbcommon-x11-0; or run with --headless)"
            } else {
                ""
            };
            anyhow::anyhow!("connecting to the display (winit): {error}{hint}")
        })?;
        let mut app = App { title: title.to_owned(), size: Some(size), ..Default::default() };
        // ANCHOR: pump
        // winit allows windows only once its loop runs (`resumed`): pump until then.
        while app.opened.is_none() && app.error.is_none() {
            if let PumpStatus::Exit(code) =
                event_loop.pump_app_events(Some(Duration::from_millis(100)), &mut app)
            {
                bail!("the event loop stopped (code {code}) before the window opened");
            }
        }
        if let Some(error) = app.error.take() {
            return Err(error);
        }
        let (context, display) = app.context.take().expect("resumed made a context with the window");
        let gl = GlContext::new(context, &|name| display.get_proc_address(name), required)?;
        // ANCHOR_END: pump
        let opened = app.opened.as_ref().expect("checked above");
        app.panel = Some(Panel::new(&opened.window, |name| display.get_proc_address(name))?);
        // Wait for one vertical blank per swap when the driver can; a window needs no more frames.
        let _ = opened.surface.set_swap_interval(gl.context(), SwapInterval::Wait(NonZeroU32::MIN));
        eprintln!(
            "window: {}x{}, {}",
            opened.window.inner_size().width,
            opened.window.inner_size().height,
            gl.renderer
        );
        Ok((Window { event_loop, app, titled: None }, gl))
    }

    // ANCHOR: poll
    /// Handles what happened since the last call, without blocking: resizes the GL surface to the
    /// window, and returns the keys pressed since.
    pub fn poll(&mut self, gl: &GlContext) -> std::vec::Drain<'_, Key> {
        if let PumpStatus::Exit(_) = self.event_loop.pump_app_events(Some(Duration::ZERO), &mut self.app) {
            self.app.close_requested = true;
        }
        if let (Some(size), Some(opened)) = (self.app.resized.take(), &self.app.opened) {
            if let (Some(w), Some(h)) = (NonZeroU32::new(size.width), NonZeroU32::new(size.height)) {
                opened.surface.resize(gl.context(), w, h);
            }
        }
        self.app.keys.drain(..)
    }
    // ANCHOR_END: poll

    /// Mouse movement with the left button held since the last call (pixels), and wheel lines.
    pub fn take_mouse(&mut self) -> ((f32, f32), f32) {
        (std::mem::take(&mut self.app.drag), std::mem::take(&mut self.app.scroll))
    }

    /// Did the user close the window (or the window system end the loop)?
    pub fn close_requested(&self) -> bool {
        self.app.close_requested
    }

    /// The size of the window's drawable area, in pixels (0 when minimised).
    pub fn size(&self) -> (u32, u32) {
        self.app.opened.as_ref().map_or((0, 0), |o| o.window.inner_size().into())
    }

    /// Shows the GPU time of each pass in the title bar, at most twice a second (a title changed
    /// every frame keeps the window manager busy).
    /// `line` makes the text (`PassTimes::line`) only when it is shown.
    pub fn show_times(&mut self, line: impl FnOnce() -> String) {
        if self.titled.is_some_and(|t| t.elapsed() < Duration::from_millis(500)) {
            return;
        }
        if let Some(opened) = &self.app.opened {
            opened.window.set_title(&format!("{} · {}", self.app.title, line()));
            self.titled = Some(std::time::Instant::now());
        }
    }

    // ANCHOR: panel
    /// Lays out this frame's panel, titled with the window's title: `contents` adds the controls
    /// (egui's; egui may run it twice in a frame), which change the values they hold at once, so
    /// call it before the frame reads them. [`Window::swap_buffers`] draws it over the picture.
    /// F10 hides and shows it.
    pub fn panel(&mut self, contents: impl FnMut(&mut egui::Ui)) {
        if let (Some(panel), Some(opened)) = (&mut self.app.panel, &self.app.opened) {
            panel.layout(&opened.window, &self.app.title, contents);
        }
    }

    /// Draws the panel (when shown) over what the chapter put in the back buffer, and shows it.
    pub fn swap_buffers(&mut self, gl: &GlContext) -> Result<()> {
        let size = self.size();
        if let Some(panel) = &mut self.app.panel {
            panel.draw(size);
        }
        gl.check_error("drawing the panel")?;
        let opened = self.app.opened.as_ref().expect("an open Window has a surface");
        opened.surface.swap_buffers(gl.context()).context("swapping the window's buffers")
    }
    // ANCHOR_END: panel

    /// Writes the panel's state into the report: `panel_shown`, and `panel_rect` (left, top,
    /// width, height in pixels, from the window's top left) where it was last drawn.
    pub fn report_panel(&self, report: &mut crate::instruments::report::Report) {
        if let Some(panel) = &self.app.panel {
            report.set("panel_shown", panel.shown());
            if let Some(rect) = panel.rect() {
                report.set("panel_rect", rect.to_vec());
            }
        }
    }
}

impl App {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let size = self.size.take().expect("opened once");
        let attributes = winit::window::Window::default_attributes()
            .with_title(&self.title)
            .with_inner_size(PhysicalSize::new(size.width, size.height));
        // EGL first: the same API as the headless path, and the one NVIDIA and Mesa share.
        let (window, config) = DisplayBuilder::new()
            .with_preference(ApiPreference::PreferEgl)
            .with_window_attributes(Some(attributes))
            .build(event_loop, ConfigTemplateBuilder::new(), pick_config)
            .map_err(|e| no_window_config(&e.to_string()))?;
        let window = window.context("glutin-winit made no window")?;
        let display = config.display();
        let handle = window.window_handle().context("the window's native handle")?.as_raw();
        let attributes = ContextAttributesBuilder::new()
            .with_context_api(ContextApi::OpenGl(Some(Version::new(4, 5))))
            .with_profile(GlProfile::Core)
            .with_debug(true)
            .build(Some(handle));
        let context =
            unsafe { display.create_context(&config, &attributes) }.context("a GL 4.5 core context")?;
        let surface_attributes = window.build_surface_attributes(Default::default())?;
        let surface = unsafe { display.create_window_surface(&config, &surface_attributes) }
            .context("a GL surface for the window")?;
        let context = context.make_current(&surface).context("making the window's context current")?;
        self.context = Some((context, display));
        self.opened = Some(Opened { surface, window });
        Ok(())
    }
}

/// The error for a display that offers no GL for this GPU: it names the display and the way out.
/// It happens where the X server has no GLX for the GPU's driver and that driver's EGL has no X11
/// platform: an NVIDIA GPU without NVIDIA's X driver (a headless server, Xvfb), for example,
/// where `__GLX_VENDOR_LIBRARY_NAME=nvidia` loads NVIDIA's GLX and the window opens (H100,
/// 2026-11-26): the error suggests it there.
fn no_window_config(cause: &str) -> anyhow::Error {
    let wayland =
        std::env::var("WAYLAND_DISPLAY").ok().filter(|d| cfg!(feature = "wayland") && !d.is_empty());
    let display = match (&wayland, std::env::var("DISPLAY")) {
        (Some(d), _) => format!("Wayland display {d}"),
        (None, Ok(d)) => format!("X display {d}"),
        (None, Err(_)) => "the display".into(),
    };
    // NVIDIA's kernel driver is loaded: the GPU whose GL the window needs is NVIDIA's.
    let nvidia = std::path::Path::new("/proc/driver/nvidia/version").exists();
    let vendor = std::env::var("__GLX_VENDOR_LIBRARY_NAME").ok();
    anyhow!("{}", no_window_config_message(&display, cause, wayland.is_none() && nvidia, vendor.as_deref()))
}

/// The text of [`no_window_config`]. `nvidia_on_x`: the display is X's and the GPU is NVIDIA's;
/// `glx_vendor`: `__GLX_VENDOR_LIBRARY_NAME`, which makes glvnd load that vendor's GLX whatever
/// the X server names for its screen (Xvfb names Mesa, whose GL does not drive an NVIDIA GPU).
fn no_window_config_message(
    display: &str,
    cause: &str,
    nvidia_on_x: bool,
    glx_vendor: Option<&str>,
) -> String {
    let headless = "run with --headless, which checks the same things";
    if nvidia_on_x && glx_vendor != Some("nvidia") {
        format!(
            "no GL configuration for a window on {display}: {cause}\n  \
             the GPU is NVIDIA's, but this X server's GLX is another vendor's (Xvfb's is Mesa's), so \
             glvnd loads a GL that does not drive it: run with __GLX_VENDOR_LIBRARY_NAME=nvidia, \
             which loads NVIDIA's GLX there, or {headless}"
        )
    } else {
        format!(
            "no GL configuration for a window on {display}: {cause}\n  \
             neither EGL nor GLX offers this GPU's GL there (an X server without the GPU's own X \
             driver, such as Xvfb, offers Mesa's GLX only); {headless}"
        )
    }
}

/// A single-sampled configuration if there is one: the chapters read the back buffer back.
fn pick_config(configs: Box<dyn Iterator<Item = Config> + '_>) -> Config {
    configs.min_by_key(|c| c.num_samples()).expect("glutin offers at least one configuration")
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.opened.is_none() && self.error.is_none() {
            if let Err(error) = self.open(event_loop) {
                self.error = Some(error);
            }
        }
    }

    fn window_event(&mut self, _: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        // What the panel takes (a click on a control, a slider's drag) the chapter does not see.
        let taken = match (&mut self.panel, &self.opened) {
            (Some(panel), Some(opened)) => panel.event(&opened.window, &event),
            _ => false,
        };
        match event {
            // Taken or not: a drag that ends over the panel ends, and one after it starts here.
            WindowEvent::CursorMoved { position, .. } if taken => self.cursor = Some(position),
            WindowEvent::MouseInput { state: ElementState::Released, .. } if taken => self.dragging = false,
            _ if taken => {}
            WindowEvent::CloseRequested => self.close_requested = true,
            WindowEvent::Resized(size) => self.resized = Some(size),
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                self.keys.push(event.logical_key)
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                self.dragging = state == ElementState::Pressed;
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let (true, Some(last)) = (self.dragging, self.cursor) {
                    self.drag.0 += (position.x - last.x) as f32;
                    self.drag.1 += (position.y - last.y) as f32;
                }
                self.cursor = Some(position);
            }
            WindowEvent::MouseWheel { delta, .. } => {
                self.scroll += match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
            }
            _ => {}
        }
    }
}

// ANCHOR: show_pictures
/// Shows the pictures a chapter wrote (PNG files) in a window, for chapters that compute
/// headless: Space or → shows the next, ← the previous, Esc or closing the window ends it, and
/// so does `frames` > 0 frames. The window has its own GL context; the chapter's is gone by now.
/// Returns whether the first frame's centre pixel, read back before the swap, is the picture's.
pub fn show_pictures(title: &str, pictures: &[(String, std::path::PathBuf)], frames: u32) -> Result<bool> {
    use glow::HasContext;
    let images = pictures
        .iter()
        .map(|(name, path)| Ok((name.clone(), crate::instruments::output::read_png_rgba8(path)?)))
        .collect::<Result<Vec<_>>>()?;
    let Some((_, first)) = images.first() else { return Ok(false) };
    let ((width, height), pixels) = first;
    let at = 4 * ((height / 2) as usize * *width as usize + (width / 2) as usize);
    let centre: [u8; 4] = pixels[at..at + 4].try_into().expect("4 bytes");
    let size = Size { width: (*width).max(64), height: (*height).max(64) };
    let (mut window, gl_context) = Window::open(title, size, &[])?;
    let gl = &gl_context.gl;
    // One texture and read framebuffer per picture; blitting does the scaling.
    let mut shown = Vec::new();
    for (name, ((w, h), pixels)) in &images {
        let (w, h) = (*w, *h);
        // PNG rows start at the top, GL's at the bottom.
        let rows = crate::instruments::output::flip_rows(pixels, w, h);
        let texture = create(gl, "glCreateTextures for a picture", |gl| unsafe {
            gl.create_named_texture(glow::TEXTURE_2D)
        })?;
        let framebuffer =
            create(gl, "glCreateFramebuffers for a picture", |gl| unsafe { gl.create_named_framebuffer() })?;
        unsafe {
            gl.texture_storage_2d(*texture, 1, glow::RGBA8, w as i32, h as i32);
            crate::instruments::resources::created("gl_texture: RGBA8", 4 * w as u64 * h as u64);
            let pixels = glow::PixelUnpackData::Slice(Some(&rows));
            gl.pixel_store_i32(glow::UNPACK_ALIGNMENT, 1);
            gl.texture_sub_image_2d(
                *texture,
                0,
                0,
                0,
                w as i32,
                h as i32,
                glow::RGBA,
                glow::UNSIGNED_BYTE,
                pixels,
            );
            gl.named_framebuffer_texture(Some(*framebuffer), glow::COLOR_ATTACHMENT0, Some(*texture), 0);
        }
        // Each framebuffer is deleted before its texture (tuple fields drop in order).
        shown.push((name.as_str(), framebuffer, texture, w as i32, h as i32));
    }
    eprintln!("window: {} picture(s); Space/→ next, ← previous, Esc quits", shown.len());
    let (mut current, mut frame, mut seen) = (0, 0, false);
    while !window.close_requested() && (frames == 0 || frame < frames) {
        for key in window.poll(&gl_context).collect::<Vec<_>>() {
            match key.as_ref() {
                Key::Named(NamedKey::Escape) => return Ok(seen), // `shown` deletes the pictures
                Key::Named(NamedKey::Space | NamedKey::ArrowRight) => current = (current + 1) % shown.len(),
                Key::Named(NamedKey::ArrowLeft) => current = (current + shown.len() - 1) % shown.len(),
                _ => {}
            }
        }
        let (name, ref framebuffer, _, w, h) = shown[current];
        let framebuffer = **framebuffer;
        let (ww, wh) = window.size();
        // As large as fits, aspect kept, centred.
        let scale = (ww as f32 / w as f32).min(wh as f32 / h as f32);
        let (dw, dh) = ((w as f32 * scale) as i32, (h as f32 * scale) as i32);
        let (x, y) = ((ww as i32 - dw) / 2, (wh as i32 - dh) / 2);
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, None);
            gl.viewport(0, 0, ww as i32, wh as i32);
            gl.clear_color(0.1, 0.1, 0.12, 1.0);
            gl.clear(glow::COLOR_BUFFER_BIT);
            let filter = if scale >= 1.0 { glow::NEAREST } else { glow::LINEAR };
            gl.blit_named_framebuffer(
                Some(framebuffer),
                None,
                0,
                0,
                w,
                h,
                x,
                y,
                x + dw,
                y + dh,
                glow::COLOR_BUFFER_BIT,
                filter,
            );
        }
        if frame == 0 {
            eprintln!("window: showing {name}");
            let mut pixel = [0u8; 4];
            unsafe {
                let data = glow::PixelPackData::Slice(Some(&mut pixel));
                gl.read_pixels(ww as i32 / 2, wh as i32 / 2, 1, 1, glow::RGBA, glow::UNSIGNED_BYTE, data);
            }
            // Scaling may blend neighbours: close, not equal.
            seen = pixel[..3].iter().zip(&centre[..3]).all(|(a, b)| a.abs_diff(*b) <= 24);
        }
        window.swap_buffers(&gl_context)?;
        frame += 1;
    }
    Ok(seen) // `shown` deletes the pictures (before the window's context: declared after it)
}
// ANCHOR_END: show_pictures

#[cfg(test)]
mod tests {
    use super::no_window_config_message as message;

    /// On X beside an NVIDIA GPU the error suggests NVIDIA's GLX; elsewhere, or once the variable
    /// is set, it keeps to --headless.
    #[test]
    fn no_window_config_suggests_nvidias_glx_where_it_helps() {
        let variable = "__GLX_VENDOR_LIBRARY_NAME=nvidia";
        let nvidia = message("X display :99", "no config", true, None);
        assert!(
            nvidia.starts_with("no GL configuration for a window on X display :99: no config\n"),
            "{nvidia}"
        );
        assert!(nvidia.contains(variable) && nvidia.contains("--headless"), "{nvidia}");
        assert!(message("X display :99", "c", true, Some("mesa")).contains(variable));
        for other in [
            message("X display :99", "c", false, None),
            message("X display :99", "c", true, Some("nvidia")),
            message("Wayland display wayland-0", "c", false, None),
        ] {
            assert!(!other.contains(variable) && other.contains("run with --headless"), "{other}");
        }
    }
}
