//! Chapter 12's settings: what the flags start with and the keys change, and what follows
//! from them (the rays a frame traces, the composite's uniforms).

use crate::composite::{Uniforms, View};
use crate::trace::{Pattern, Rays};
use common::base::window::Key;
use common::scene::Camera;

/// What the keys change (chapter 08's, less its debug views of positions).
#[derive(Clone, Copy, PartialEq)]
pub struct Settings {
    pub samples: u32,
    pub radius: f32,
    pub power: f32,
    pub blur: u32,
    pub view: View,
    pub overlays: bool,
    pub pattern: Pattern,
}

pub fn apply_key(key: &Key, s: &mut Settings) {
    if let Key::Character(c) = key.as_ref() {
        match c {
            "1" | "2" | "3" | "4" | "5" => s.view = View::ALL[c.parse::<usize>().unwrap() - 1],
            "+" | "=" => s.samples = (s.samples * 2).clamp(1, 256),
            "-" => s.samples = (s.samples / 2).max(1),
            "]" => s.radius *= 1.25,
            "[" => s.radius /= 1.25,
            "b" | "B" => s.blur = (s.blur + 1) % 5,
            "p" | "P" => s.power = s.power.floor() % 3.0 + 1.0,
            "o" | "O" => s.overlays = !s.overlays,
            "t" | "T" => s.pattern = Pattern::ALL[(s.pattern as usize + 1) % Pattern::ALL.len()],
            _ => {}
        }
    }
}

impl Settings {
    pub fn rays(&self, samples: u32, scene_scale: f32) -> Rays {
        Rays { samples, radius: self.radius, scene_scale, pattern: self.pattern, salt: 0 }
    }
}

pub fn uniforms(s: &Settings, camera: &Camera) -> Uniforms {
    Uniforms {
        blur_radius: s.blur as i32,
        depth_tolerance: 0.02,
        normal_tolerance: 0.9,
        power: s.power,
        view: s.view,
        far_depth: camera.far,
    }
}
