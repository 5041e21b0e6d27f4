//! What the checks of a composited frame look at: the G-buffers and the AO read back, the
//! composite's formula on the CPU, and whether a line's colour shows at a pixel.

use super::composite::Uniforms;
use crate::instruments::output;
use crate::rt::ao::AoTracer;
use crate::scene::gbuffer::GBuffers;
use glam::Vec3;

/// Does the line's colour appear within a pixel of (x, y)? (A 1-pixel line may be rasterised on
/// a neighbour of the point's own pixel.)
pub fn shows_colour(pixels: &[u8], width: usize, (x, y, colour): (usize, usize, [u8; 3])) -> bool {
    (y - 1..=y + 1).any(|v| {
        (x - 1..=x + 1).any(|u| {
            let p = &pixels[(v * width + u) * 4..][..3];
            p.iter().zip(colour).all(|(&a, b)| a.abs_diff(b) <= 3)
        })
    })
}

/// The G-buffers and the AO as GL read them back (memory order).
pub struct Pixels {
    pub width: usize,
    pub height: usize,
    pub positions: Vec<f32>,
    pub normals: Vec<f32>,
    pub albedo: Vec<f32>,
    pub visibility: Vec<f32>,
}

impl Pixels {
    /// The G-buffers and the AO image, read back through GL.
    pub fn read(gl: &glow::Context, gbuffers: &GBuffers, tracer: &AoTracer) -> Pixels {
        let (w, h) = (gbuffers.extent.width, gbuffers.extent.height);
        let textures = gbuffers.textures();
        Pixels {
            width: w as usize,
            height: h as usize,
            positions: output::read_texture_f32(gl, textures[0], w, h, 4),
            normals: output::read_texture_f32(gl, textures[1], w, h, 4),
            albedo: output::read_texture_f32(gl, textures[2], w, h, 4),
            visibility: output::read_texture_f32(gl, *tracer.image.texture.texture, w, h, 1),
        }
    }

    /// The view depth at each pixel (the position G-buffer's w), 0 where nothing was drawn: what
    /// [`Overlays::probe`](super::Overlays::probe) tests the lines against.
    pub fn view_depth(&self) -> Vec<f32> {
        self.positions.chunks_exact(4).map(|p| p[3]).collect()
    }
}

// ANCHOR: reference
/// The composite shader's formula on the CPU, at a spread of covered pixels, against what GL
/// drew (within 2/255 per channel).
pub fn matches_reference(g: &Pixels, drawn: &[u8], u: &Uniforms) -> bool {
    let (w, h) = (g.width as i32, g.height as i32);
    let at = |x: i32, y: i32| (y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize;
    let covered: Vec<usize> = (0..g.width * g.height).filter(|&i| g.positions[i * 4 + 3] > 0.0).collect();
    let step = (covered.len() / 64).max(1);
    let mut compared = 0;
    for &i in covered.iter().step_by(step) {
        let (x, y) = ((i % g.width) as i32, (i / g.width) as i32);
        let (depth, normal) = (g.positions[i * 4 + 3], Vec3::from_slice(&g.normals[i * 4..i * 4 + 3]));
        let (mut sum, mut count) = (0.0, 0.0);
        for dy in -u.blur_radius..=u.blur_radius {
            for dx in -u.blur_radius..=u.blur_radius {
                let j = at(x + dx, y + dy);
                let other = g.positions[j * 4 + 3];
                let same_depth = other > 0.0 && (other - depth).abs() <= u.depth_tolerance * depth;
                let same_facing =
                    Vec3::from_slice(&g.normals[j * 4..j * 4 + 3]).dot(normal) >= u.normal_tolerance;
                if same_depth && same_facing {
                    sum += g.visibility[j];
                    count += 1.0;
                }
            }
        }
        let occlusion = (sum / count).powf(u.power);
        for c in 0..3 {
            let expected = (g.albedo[i * 4 + c] * occlusion * 255.0).round();
            // Pixels right at a tolerance's edge may go either way between GPU and CPU floats.
            if (drawn[i * 4 + c] as f32 - expected).abs() > 2.0 {
                eprintln!("composite differs at ({x}, {y}): drew {}, expected {expected}", drawn[i * 4 + c]);
                return false;
            }
        }
        compared += 1;
    }
    compared > 0
}
// ANCHOR_END: reference
