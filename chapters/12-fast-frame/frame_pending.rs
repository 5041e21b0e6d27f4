// TEMPORARY: replaced by common::frame once it lands.
use glam::{Mat4, Vec3};
pub struct Target { pub framebuffer: glow::Framebuffer, pub width: u32, pub height: u32 }
pub struct Probes { pub hidden: Option<(usize, usize, [u8; 3])>, pub visible: Option<(usize, usize, [u8; 3])> }
pub struct Overlays;
impl Overlays {
    pub fn new(_gl: &glow::Context, _scene: &common::scene::Scene, _select: usize) -> anyhow::Result<Self> { Ok(Overlays) }
    pub fn draw(&self, _gl: &glow::Context, _t: &Target, _vp: Mat4) {}
    pub fn probe(&self, _d: &[f32], _w: usize, _h: usize, _vp: Mat4, _e: Vec3, _f: Vec3) -> Probes { Probes { hidden: None, visible: None } }
}
pub fn shows_colour(_p: &[u8], _w: usize, _x: (usize, usize, [u8; 3])) -> bool { false }
