//! A window's panel: the chapter's settings and values on screen, drawn with egui over the
//! finished picture. egui lays the panel out from this frame's input (egui-winit turns winit's
//! events into it) and returns triangles; egui_glow draws them with GL into the window's back
//! buffer, after the chapter has put its picture there, so no image the chapter shares or checks
//! ever holds the panel.
//!
//! egui_glow 0.32 speaks glow 0.16, the chapters glow 0.18. A `glow::Context` is only the GL
//! functions the driver's loader returns, so the panel makes a second one, of egui's glow, from
//! the same loader: both call the one GL context that is current on the window.

use anyhow::{Result, anyhow};
use egui_glow::glow::{self, HasContext as _};
use std::ffi::{CStr, c_void};
use std::sync::Arc;
use winit::event::{ElementState, WindowEvent};
use winit::keyboard::{Key, NamedKey};

/// The key that hides and shows the panel (the one the NVIDIA samples use).
const TOGGLE: NamedKey = NamedKey::F10;

pub(super) struct Panel {
    context: egui::Context,
    input: egui_winit::State,
    painter: egui_glow::Painter,
    shown: bool,
    /// What the last layout asked to draw, until the window draws it.
    pending: Option<(Vec<egui::ClippedPrimitive>, egui::TexturesDelta, f32)>,
    /// Where the panel was last drawn, in pixels: left, top, width, height.
    rect: Option<[u32; 4]>,
}

impl Panel {
    /// `loader`: the GL functions of the context current on `window`.
    pub(super) fn new(
        window: &winit::window::Window,
        loader: impl Fn(&CStr) -> *const c_void,
    ) -> Result<Panel> {
        let gl = unsafe { glow::Context::from_loader_function_cstr(loader) };
        let painter = egui_glow::Painter::new(Arc::new(gl), "", None, false)
            .map_err(|e| anyhow!("the panel's GL painter (egui_glow): {e}"))?;
        let context = egui::Context::default();
        // Smaller than egui's default text, so that the panel leaves more of a small window to
        // the picture.
        context.style_mut(|style| {
            style.text_styles.values_mut().for_each(|font| font.size *= 0.85);
            style.spacing.item_spacing *= 0.75;
            // No shadow: the panel covers its rectangle and not a pixel outside it.
            style.visuals.window_shadow = egui::Shadow::NONE;
            style.visuals.popup_shadow = egui::Shadow::NONE;
        });
        let scale = Some(window.scale_factor() as f32);
        let max_side = Some(painter.max_texture_side());
        let viewport = egui::ViewportId::ROOT;
        let input = egui_winit::State::new(context.clone(), viewport, window, scale, None, max_side);
        Ok(Panel { context, input, painter, shown: true, pending: None, rect: None })
    }

    /// Gives egui one of the window's events. True when the panel takes it (a click on a
    /// control, a drag of a slider): the chapter then leaves it alone. F10 hides or shows the
    /// panel, and a hidden panel takes nothing.
    pub(super) fn event(&mut self, window: &winit::window::Window, event: &WindowEvent) -> bool {
        if let WindowEvent::KeyboardInput { event: key, .. } = event {
            if key.state == ElementState::Pressed && key.logical_key == Key::Named(TOGGLE) {
                self.shown = !self.shown;
            }
        }
        self.shown && self.input.on_window_event(window, event).consumed
    }

    /// Lays the panel out for this frame: `contents` adds the controls, which change the values
    /// they are given at once. The triangles wait for [`Panel::draw`].
    pub(super) fn layout(
        &mut self,
        window: &winit::window::Window,
        title: &str,
        mut contents: impl FnMut(&mut egui::Ui),
    ) {
        let input = self.input.take_egui_input(window);
        if !self.shown {
            self.pending = None;
            return;
        }
        let mut rect = None;
        let output = self.context.run(input, |context| {
            let shown = egui::Window::new(title)
                .anchor(egui::Align2::LEFT_TOP, [8.0, 8.0])
                .resizable(false)
                .show(context, |ui| {
                    contents(ui);
                    ui.separator();
                    ui.weak("F10 hides this panel");
                });
            rect = shown.map(|s| s.response.rect);
        });
        self.input.handle_platform_output(window, output.platform_output);
        let scale = output.pixels_per_point;
        let triangles = self.context.tessellate(output.shapes, scale);
        self.pending = Some((triangles, output.textures_delta, scale));
        // In pixels, rounded outwards: the screenshot tests compare the pixels outside it.
        self.rect = rect.map(|r| {
            let (min, max) = ((r.min * scale).floor(), (r.max * scale).ceil());
            [min.x.max(0.0) as u32, min.y.max(0.0) as u32, (max.x - min.x) as u32, (max.y - min.y) as u32]
        });
    }

    /// Draws what [`Panel::layout`] made into the window's back buffer (`size` pixels), over what
    /// is there, and puts back the GL state egui changes that the chapters' passes rely on.
    pub(super) fn draw(&mut self, (width, height): (u32, u32)) {
        let Some((triangles, textures, scale)) = self.pending.take() else { return };
        let gl = self.painter.gl().clone();
        unsafe { gl.bind_framebuffer(glow::FRAMEBUFFER, None) };
        self.painter.paint_and_update_textures([width, height], scale, &triangles, &textures);
        unsafe {
            // egui blends (premultiplied alpha) and uploads its font with rows of any length;
            // the chapters draw unblended and upload with GL's default alignment of 4.
            gl.disable(glow::BLEND);
            gl.pixel_store_i32(glow::UNPACK_ALIGNMENT, 4);
        }
    }

    pub(super) fn shown(&self) -> bool {
        self.shown
    }

    pub(super) fn rect(&self) -> Option<[u32; 4]> {
        self.rect
    }
}

impl Drop for Panel {
    /// egui_glow's textures, buffers and program are deleted while the window's context exists
    /// (the window is dropped before its context).
    fn drop(&mut self) {
        self.painter.destroy();
    }
}
