//! Chapter 11's scene and its ray tracer on the CPU: the same maths as `shaders/cuda/trace.cu`,
//! operation for operation, so that the CPU and CUDA pictures can be compared pixel by pixel.

use common::scene::Camera;
use glam::Vec3;

pub const MAX_SPHERES: usize = 8;
/// Half the side of the ground square, which lies at y = 0 around the origin.
pub const GROUND_HALF: f32 = 4.0;

/// One sphere, as the kernel reads it (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Default, Debug)]
pub struct Sphere {
    pub centre: [f32; 3],
    pub radius: f32,
    pub albedo: [f32; 3],
    _pad: f32,
}

// ANCHOR: params
/// The kernel's parameter block (`Params` in trace.cu), passed by value at each launch.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct TraceParams {
    pub width: u32,
    pub height: u32,
    pub sphere_count: u32,
    _pad: u32,
    /// A pixel's ray points along forward + x * right + y * up, with x and y in -1..1.
    pub eye: [f32; 4],
    pub forward: [f32; 4],
    pub right: [f32; 4],
    pub up: [f32; 4],
    /// Unit vector towards the light.
    pub light: [f32; 4],
    /// [half side, height] of the ground square.
    pub ground: [f32; 4],
    pub spheres: [Sphere; MAX_SPHERES],
}
// ANCHOR_END: params

/// Spheres of several sizes standing on the ground: each hides parts of the others, of the
/// ground, and of the lines GL draws among them.
pub fn spheres() -> Vec<Sphere> {
    let sphere =
        |centre: [f32; 3], radius: f32, albedo: [f32; 3]| Sphere { centre, radius, albedo, _pad: 0.0 };
    vec![
        sphere([0.0, 1.0, 0.0], 1.0, [0.85, 0.3, 0.25]),
        sphere([-2.2, 0.6, 1.0], 0.6, [0.3, 0.75, 0.35]),
        sphere([1.8, 0.8, -1.5], 0.8, [0.3, 0.45, 0.9]),
        sphere([1.5, 0.4, 1.8], 0.4, [0.95, 0.8, 0.25]),
        sphere([-1.5, 1.3, -2.2], 1.3, [0.8, 0.8, 0.8]),
    ]
}

/// The box around the ground and every sphere, for framing the camera.
pub fn bounds(spheres: &[Sphere]) -> (Vec3, Vec3) {
    let top = spheres.iter().map(|s| s.centre[1] + s.radius).fold(0.0, f32::max);
    (Vec3::new(-GROUND_HALF, 0.0, -GROUND_HALF), Vec3::new(GROUND_HALF, top, GROUND_HALF))
}

// ANCHOR: camera
/// The camera GL rasterises with, as the ray tracer's three vectors: `right` and `up` are scaled
/// so that x and y in -1..1 span the field of view exactly as the projection matrix does.
pub fn params(camera: &Camera, width: u32, height: u32, spheres: &[Sphere]) -> TraceParams {
    let forward = (camera.target - camera.eye).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let tan_half = (camera.fov_y / 2.0).tan();
    let aspect = width as f32 / height as f32;
    let mut all = [Sphere::default(); MAX_SPHERES];
    all[..spheres.len()].copy_from_slice(spheres);
    let four = |v: Vec3| [v.x, v.y, v.z, 0.0];
    TraceParams {
        width,
        height,
        sphere_count: spheres.len() as u32,
        _pad: 0,
        eye: four(camera.eye),
        forward: four(forward),
        right: four(right * tan_half * aspect),
        up: four(up * tan_half),
        light: four(Vec3::new(-0.4, 1.0, 0.5).normalize()),
        ground: [GROUND_HALF, 0.0, 0.0, 0.0],
        spheres: all,
    }
}
// ANCHOR_END: camera

/// What a ray hit: its distance (0: nothing), and what the shading needs.
#[derive(Clone, Copy)]
pub struct Hit {
    pub t: f32,
    normal: [f32; 3],
    albedo: [f32; 3],
    /// Which object: a sphere's index, `GROUND` for the ground (the depth check looks for it).
    pub object: usize,
}

pub const GROUND: usize = usize::MAX;

fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn three(v: [f32; 4]) -> [f32; 3] {
    [v[0], v[1], v[2]]
}

/// `nearest` in trace.cu.
pub fn nearest(p: &TraceParams, origin: [f32; 3], dir: [f32; 3], t_min: f32) -> Hit {
    let mut hit = Hit { t: 0.0, normal: [0.0; 3], albedo: [0.0; 3], object: 0 };
    for (i, s) in p.spheres[..p.sphere_count as usize].iter().enumerate() {
        let oc = [origin[0] - s.centre[0], origin[1] - s.centre[1], origin[2] - s.centre[2]];
        let b = dot3(oc, dir);
        let c = dot3(oc, oc) - s.radius * s.radius;
        let disc = b * b - c;
        if disc < 0.0 {
            continue;
        }
        let root = disc.sqrt();
        let mut t = -b - root;
        if t <= t_min {
            t = -b + root;
        }
        if t <= t_min || (hit.t > 0.0 && t >= hit.t) {
            continue;
        }
        hit.t = t;
        for k in 0..3 {
            let point = origin[k] + t * dir[k];
            hit.normal[k] = (point - s.centre[k]) / s.radius;
        }
        hit.albedo = s.albedo;
        hit.object = i;
    }
    if dir[1] != 0.0 {
        let t = (p.ground[1] - origin[1]) / dir[1];
        let x = origin[0] + t * dir[0];
        let z = origin[2] + t * dir[2];
        let inside = x.abs() <= p.ground[0] && z.abs() <= p.ground[0];
        if t > t_min && inside && (hit.t == 0.0 || t < hit.t) {
            hit.t = t;
            hit.normal = [0.0, 1.0, 0.0];
            let light_square = ((x.floor() as i32 + z.floor() as i32) & 1) == 0;
            hit.albedo = [if light_square { 0.8 } else { 0.5 }; 3];
            hit.object = GROUND;
        }
    }
    hit
}

fn to_byte(value: f32) -> u32 {
    (value.clamp(0.0, 1.0) * 255.0 + 0.5) as u32
}

// ANCHOR: trace_pixel
/// The kernel's body for pixel (x, y) (row 0 at the bottom): its packed RGBA8 colour, and the hit.
pub fn trace_pixel(p: &TraceParams, x: u32, y: u32) -> (u32, Hit) {
    let sx = (x as f32 + 0.5) / p.width as f32 * 2.0 - 1.0;
    let sy = (y as f32 + 0.5) / p.height as f32 * 2.0 - 1.0;
    let mut dir: [f32; 3] = std::array::from_fn(|k| p.forward[k] + sx * p.right[k] + sy * p.up[k]);
    let length = dot3(dir, dir).sqrt();
    dir = dir.map(|d| d / length);

    let hit = nearest(p, three(p.eye), dir, 0.0);
    let rgb = if hit.t == 0.0 {
        let up = (dir[1] * 0.5 + 0.5).clamp(0.0, 1.0);
        [0.75 - 0.35 * up, 0.82 - 0.25 * up, 0.9]
    } else {
        let mut lambert = dot3(hit.normal, three(p.light)).max(0.0);
        if lambert > 0.0 {
            let mut start = [0.0; 3];
            for k in 0..3 {
                start[k] = p.eye[k] + hit.t * dir[k] + 1e-3 * hit.normal[k];
            }
            if nearest(p, start, three(p.light), 0.0).t > 0.0 {
                lambert = 0.0;
            }
        }
        hit.albedo.map(|a| a * (0.25 + 0.75 * lambert))
    };
    let colour = to_byte(rgb[0]) | to_byte(rgb[1]) << 8 | to_byte(rgb[2]) << 16 | 255 << 24;
    (colour, hit)
}
// ANCHOR_END: trace_pixel

/// Traces every pixel into `traced`: all colours, then all hit distances (as the kernel's
/// buffer holds them). Returns the hits, for the checks.
pub fn trace(p: &TraceParams, traced: &mut [u32]) -> Vec<Hit> {
    let pixels = (p.width * p.height) as usize;
    let mut hits = Vec::with_capacity(pixels);
    for y in 0..p.height {
        for x in 0..p.width {
            let (colour, hit) = trace_pixel(p, x, y);
            let i = (y * p.width + x) as usize;
            traced[i] = colour;
            traced[pixels + i] = hit.t.to_bits();
            hits.push(hit);
        }
    }
    hits
}

// ANCHOR: depth
/// The depth GL's rasteriser writes for a point at hit distance `t` along the ray through
/// (x, y) in -1..1: the view depth d = t / |forward + x right + y up| (forward is a unit vector
/// at right angles to `right` and `up`), then the window depth of glam's OpenGL `perspective` with
/// glDepthRange(0, 1): f (d - n) / ((f - n) d). `raytraced.frag` computes the same.
pub fn window_depth(t: f32, (x, y): (f32, f32), tan_half: (f32, f32), (near, far): (f32, f32)) -> f32 {
    let view_depth = t / Vec3::new(x * tan_half.0, y * tan_half.1, 1.0).length();
    far * (view_depth - near) / ((far - near) * view_depth)
}
// ANCHOR_END: depth

/// The same depth the long way: the hit point through GL's view and projection matrices.
#[cfg(test)]
pub fn projected_depth(point: Vec3, view_projection: glam::Mat4) -> f32 {
    let clip = view_projection * point.extend(1.0);
    (clip.z / clip.w + 1.0) / 2.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_match_the_kernels_layout() {
        // trace.cu's Params is 368 bytes (see the PTX).
        common::base::pipeline::assert_layout!(TraceParams is 368 bytes: eye at 16, spheres at 112);
        assert_eq!(size_of::<Sphere>(), 32);
    }

    #[test]
    fn window_depth_is_what_the_projection_matrix_gives() {
        let bounds = bounds(&spheres());
        let camera = Camera::framing(bounds, 4.0 / 3.0);
        let p = params(&camera, 40, 30, &spheres());
        let tan_half = ((camera.fov_y / 2.0).tan() * 4.0 / 3.0, (camera.fov_y / 2.0).tan());
        let view_projection = camera.view_projection(4.0 / 3.0);
        let mut compared = 0;
        for y in 0..30 {
            for x in 0..40 {
                let (_, hit) = trace_pixel(&p, x, y);
                if hit.t == 0.0 {
                    continue;
                }
                let (sx, sy) = ((x as f32 + 0.5) / 20.0 - 1.0, (y as f32 + 0.5) / 15.0 - 1.0);
                let dir = (Vec3::from_slice(&p.forward[..3])
                    + sx * Vec3::from_slice(&p.right[..3])
                    + sy * Vec3::from_slice(&p.up[..3]))
                .normalize();
                let point = camera.eye + hit.t * dir;
                let ours = window_depth(hit.t, (sx, sy), tan_half, (camera.near, camera.far));
                let theirs = projected_depth(point, view_projection);
                assert!((0.0..=1.0).contains(&ours));
                // Float rounding of two different computations: a few parts in 10^6.
                assert!((ours - theirs).abs() < 4e-6, "({x}, {y}): {ours} vs {theirs}");
                compared += 1;
            }
        }
        assert!(compared > 300, "the scene covers much of the picture: {compared} of 1200 pixels");
        // The ends of the range: the near plane is depth 0, the far plane 1.
        let on_axis = |t| window_depth(t, (0.0, 0.0), tan_half, (camera.near, camera.far));
        assert!(on_axis(camera.near).abs() < 1e-6 && (on_axis(camera.far) - 1.0).abs() < 1e-6);
    }
}
