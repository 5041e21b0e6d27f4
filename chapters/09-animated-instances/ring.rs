//! Chapter 09's scene: a ring of bunnies running in a circle over a ground plane, and where each
//! one is at any moment.

use anyhow::{Result, ensure};
use common::interop::exportable::ExportedBuffer;
use common::scene::{Instance, Mesh, Normals, Scene, ground_plane, load_obj};
use glam::{Mat4, Quat, Vec3};
use std::f32::consts::TAU;
use std::path::Path;

/// The ring's size and pace. Everything is in the world the scene was made in; `origin` is the
/// scene's floating origin (`Scene::origin`), subtracted from every transform written.
pub struct Ring {
    pub count: u32,
    /// Of the circle the bunnies' centres run on.
    pub radius: f32,
    /// Scales the model to one unit long.
    scale: f32,
    /// Lifts the scaled model so that its lowest point touches the ground.
    lift: f32,
    /// Seconds per lap.
    pub lap_s: f32,
    origin: Vec3,
}

/// The ground (mesh 0, instance 0) and `count` instances of the model (mesh 1), placed as at
/// `time` seconds.
pub fn scene(model: &Path, count: u32, lap_s: f32, time: f32) -> Result<(Scene, Ring)> {
    ensure!((2..=1000).contains(&count), "--count {count}: choose between 2 and 1000 runners");
    ensure!(lap_s.is_finite() && lap_s > 0.0, "--lap {lap_s}: must be a positive number of seconds");
    let loaded = load_obj(model, Normals::Smooth)?;
    let model_mesh: Mesh = loaded.meshes.into_iter().next().expect("load_obj returns at least one mesh");
    let (low, high) = bounds(&model_mesh);
    // One unit from nose to tail (the model's longest horizontal side runs along the ring).
    let length = (high.x - low.x).max(high.z - low.z);
    let scale = 1.0 / length;
    // ANCHOR: ring_radius
    // Neighbours' centres 1.5 lengths apart along the chord: each bunny runs just behind the next.
    let gap = 1.5;
    let radius = gap / (2.0 * (std::f32::consts::PI / count as f32).sin());
    // ANCHOR_END: ring_radius
    let mut ring = Ring { count, radius, scale, lift: -low.y * scale, lap_s, origin: Vec3::ZERO };
    // The ground: the 20 x 20 plane, scaled to reach a little beyond the ring.
    let ground_scale = (radius + 2.0) / 10.0;
    let ground = Instance::new(Mat4::from_scale(Vec3::new(ground_scale, 1.0, ground_scale)), [200, 200, 200]);
    let runners = (0..count).map(|i| Instance::new(ring.object_to_world(i, time), hue(i, count)));
    let instances: Vec<Instance> = std::iter::once(ground).chain(runners).collect();
    let scene = Scene::new(vec![ground_plane(), model_mesh], instances, vec![0..1, 1..count + 1])?;
    // The floating origin: Scene::new moved everything by minus the bounds' centre. The ground
    // is symmetric about the ring's axis and wider than the ring, and the runners only turn
    // about that axis, so the centre found now holds at every moment.
    ring.origin = Vec3::from(scene.origin.map(|c| c as f32));
    Ok((scene, ring))
}

impl Ring {
    // ANCHOR: transform
    /// Runner `i` at `time` seconds, in the world the ring was made in: on the circle, facing
    /// along it (the model's +x axis turned onto the direction of travel).
    fn object_to_world(&self, i: u32, time: f32) -> Mat4 {
        let angle = TAU * (i as f32 / self.count as f32 + time / self.lap_s);
        let centre = Vec3::new(self.radius * angle.cos(), self.lift, self.radius * angle.sin());
        // Travelling anticlockwise seen from above: the tangent is (-sin, 0, cos). Turning +x
        // onto it is a rotation about +y by -(angle + 90 degrees).
        let heading = Quat::from_rotation_y(-(angle + TAU / 4.0));
        Mat4::from_scale_rotation_translation(Vec3::splat(self.scale), heading, centre)
    }

    /// Writes every runner's transform at `time` into the shared instance buffer, relative to
    /// the scene's origin. Only the 48 transform bytes of each instance are written: the BLAS
    /// address and the colour stay. The GPU must not be reading the buffer (see the caller).
    pub fn write(&self, instances: &ExportedBuffer, time: f32) {
        for i in 0..self.count {
            let world = Mat4::from_translation(-self.origin) * self.object_to_world(i, time);
            let transform = Instance::new(world, [0; 3]).transform;
            let index = 1 + i as usize; // after the ground
            let offset = index * size_of::<Instance>() + std::mem::offset_of!(Instance, transform);
            assert!(
                offset + size_of_val(&transform) <= instances.bytes as usize,
                "runner {i} outside the buffer"
            );
            // SAFETY: in bounds of the coherent mapping (checked above), and no GPU work reads
            // the buffer now (the caller waited for the previous frame).
            unsafe { instances.mapped.add(offset).cast::<[[f32; 4]; 3]>().write_unaligned(transform) };
        }
    }
    // ANCHOR_END: transform

    /// How far a runner travels in `seconds`, in model lengths.
    pub fn lengths_travelled(&self, seconds: f32) -> f32 {
        TAU * self.radius * seconds / self.lap_s
    }
}

fn bounds(mesh: &Mesh) -> (Vec3, Vec3) {
    mesh.vertices.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(low, high), v| {
        let p = Vec3::from(v.position);
        (low.min(p), high.max(p))
    })
}

/// A colour per runner, around the colour wheel.
fn hue(i: u32, count: u32) -> [u8; 3] {
    let h = i as f32 / count as f32;
    let channel = |offset: f32| {
        let x = ((h + offset).fract() * 6.0 - 3.0).abs() - 1.0;
        (70.0 + 170.0 * x.clamp(0.0, 1.0)) as u8
    };
    [channel(0.0), channel(2.0 / 3.0), channel(1.0 / 3.0)]
}
