//! A frame's input, as chapter 08 taught it and chapter 12 takes it again: the settings the keys
//! change, a window's keys and mouse (Esc ends, a drag orbits, the wheel zooms, a new size is
//! asked for), and headless, the sizes `--resize-every` steps through.

use super::composite::Uniforms;
use crate::base::cli::Size;
use crate::base::gl::GlContext;
use crate::base::window::{Key, NamedKey, Window};
use crate::scene::Camera;
use glam::Vec3;

/// What the keys change, whichever views the composite has (`V`). Only the radius changes what
/// the occlusion measures; the rest change how many rays a frame adds or how the mean is shown.
#[derive(Clone, Copy, PartialEq)]
pub struct Settings<V> {
    pub samples: u32,
    pub radius: f32,
    pub power: f32,
    pub blur: u32,
    pub view: V,
    pub overlays: bool,
}

impl<V: Copy> Settings<V> {
    // ANCHOR: keys
    /// One key: 1 to `views.len()` picks a view, the rest as the book's table says. False for a
    /// key that is none of these (a chapter may have more).
    pub fn apply_key(&mut self, key: &Key, views: &[V]) -> bool {
        // Named keys do nothing here: Esc ends the loop before keys get here.
        let Key::Character(c) = key.as_ref() else { return false };
        match c {
            "+" | "=" => self.samples = (self.samples * 2).clamp(1, 256),
            "-" => self.samples = (self.samples / 2).max(1),
            "]" => self.radius *= 1.25,
            "[" => self.radius /= 1.25,
            "b" | "B" => self.blur = (self.blur + 1) % 5,
            "p" | "P" => self.power = self.power.floor() % 3.0 + 1.0, // 1, 2, 3, 1 ...
            "o" | "O" => self.overlays = !self.overlays,
            _ => match c.parse::<usize>() {
                Ok(n @ 1..) if n <= views.len() => self.view = views[n - 1],
                _ => return false,
            },
        }
        true
    }
    // ANCHOR_END: keys

    /// The composite's uniforms these settings ask for.
    pub fn uniforms(&self, far_depth: f32) -> Uniforms<V> {
        Uniforms::new(self.blur, self.power, self.view, far_depth)
    }
}

// ANCHOR: window
/// One frame's window input: `None` when Esc was pressed or the window closed; else every key
/// given to `apply_key`, the mouse's drag and wheel turned into an orbit of `camera` about
/// `bounds`, and the window's size if it is no longer `size` and at least `smallest` each way.
pub fn window_input(
    window: &mut Window,
    gl: &GlContext,
    (camera, bounds): (&mut Camera, (Vec3, Vec3)),
    (size, smallest): (Size, u32),
    mut apply_key: impl FnMut(&Key),
) -> Option<Option<Size>> {
    let keys: Vec<Key> = window.poll(gl).collect();
    if keys.contains(&Key::Named(NamedKey::Escape)) || window.close_requested() {
        return None;
    }
    keys.iter().for_each(&mut apply_key);
    let ((dx, dy), wheel) = window.take_mouse();
    if dx != 0.0 || dy != 0.0 || wheel != 0.0 {
        camera.orbit(-dx * 0.01, dy * 0.01, 1.1f32.powf(wheel), bounds);
    }
    let (width, height) = window.size();
    let resized = (width, height) != (size.width, size.height) && width >= smallest && height >= smallest;
    Some(resized.then_some(Size { width, height }))
}
// ANCHOR_END: window

/// Headless, `--resize-every K`: every Kth frame, the size a window's resize would bring, three
/// quarters, whole, half of `full` in turn (at least `smallest` each way).
pub fn resize_every(every: Option<u32>, frame: u32, full: Size, smallest: u32) -> Option<Size> {
    let every = every.filter(|&k| frame > 0 && frame % k == 0)?;
    let quarters = [2, 3, 4][(frame / every) as usize % 3];
    let scale = |side: u32| (side * quarters / 4).max(smallest);
    Some(Size { width: scale(full.width), height: scale(full.height) })
}
