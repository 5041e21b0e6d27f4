//! The camera every chapter from 05 on draws and traces with.

use glam::{Mat4, Vec3};

// ANCHOR: camera
/// A perspective camera. GL rasterises with `view` and `projection`; the ray tracer (chapter 06)
/// builds the very same rays from `eye` and the inverse of `view_projection`.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub fov_y: f32,
    pub near: f32,
    pub far: f32,
}

/// `--zoom`'s parser (chapters 08 and 12): a factor the camera starts closer by, between 0.001
/// and 10^6. Beyond those the near and far planes lose the scene (tests/numerics.rs walks up to
/// 10^5).
pub fn parse_zoom(text: &str) -> Result<f32, String> {
    crate::base::cli::number(1e-3..=1e6)(text)
}

impl Camera {
    /// Looks at the bounds' centre from above and in front, far enough that they fit; near and
    /// far hug the bounds, so depth precision follows the scene's scale.
    pub fn framing(bounds: (Vec3, Vec3), aspect: f32) -> Camera {
        let centre = (bounds.0 + bounds.1) / 2.0;
        let radius = ((bounds.1 - bounds.0).length() / 2.0).max(1e-6);
        let fov_y = 45f32.to_radians();
        let fov = if aspect < 1.0 { 2.0 * ((fov_y / 2.0).tan() * aspect).atan() } else { fov_y };
        // radius / sin fits the whole bounding sphere; most scenes (a flat ground, a bunny) fill
        // far less of it, so come closer by a quarter.
        let distance = 0.75 * radius / (fov / 2.0).sin();
        let direction = Vec3::new(0.55, 0.6, 1.0).normalize();
        Camera {
            eye: centre + direction * distance,
            target: centre,
            fov_y,
            near: (distance - radius).max(distance * 1e-2),
            far: distance + radius,
        }
    }

    /// Turns the camera around its target (yaw about the world's up, pitch about the camera's
    /// right, in radians) and moves it closer (`zoom` > 1) or away, keeping `bounds` between
    /// the near and far planes.
    pub fn orbit(&mut self, yaw: f32, pitch: f32, zoom: f32, bounds: (Vec3, Vec3)) {
        let offset = self.eye - self.target;
        let distance = (offset.length() / zoom).max(1e-6);
        let direction = offset.normalize();
        let current_pitch = direction.y.clamp(-1.0, 1.0).asin();
        // Stop short of the poles, where "up" and the view direction would coincide.
        let limit = 85f32.to_radians();
        let pitch = (current_pitch + pitch).clamp(-limit, limit) - current_pitch;
        let right = direction.cross(Vec3::Y).normalize_or(Vec3::X);
        let turned =
            glam::Quat::from_axis_angle(Vec3::Y, yaw) * glam::Quat::from_axis_angle(right, pitch) * direction;
        self.eye = self.target + turned * distance;
        let radius = ((bounds.1 - bounds.0).length() / 2.0).max(1e-6);
        let to_centre = ((bounds.0 + bounds.1) / 2.0 - self.eye).length();
        self.near = (to_centre - radius).max(to_centre * 1e-2);
        self.far = to_centre + radius;
    }

    pub fn view(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.eye, self.target, Vec3::Y)
    }

    /// GL's clip space: depth from -1 to 1.
    pub fn projection(&self, aspect: f32) -> Mat4 {
        glam::camera::rh::proj::opengl::perspective(self.fov_y, aspect, self.near, self.far)
    }

    pub fn view_projection(&self, aspect: f32) -> Mat4 {
        self.projection(aspect) * self.view()
    }
}
// ANCHOR_END: camera
