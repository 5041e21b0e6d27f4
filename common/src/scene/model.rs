//! Scenes (chapter 05): meshes, instances, and the seeded generator that places them. The
//! lowest module of the scene layer: OBJ files are read in `obj.rs`, the default scene is built
//! in `builtin.rs`, the flags that choose one are in `args.rs`, the camera is in `camera.rs`.

use anyhow::{Result, bail};
use glam::{Mat4, Vec3};
use std::ops::Range;

/// One vertex as both GL (two vec3 attributes) and the BLAS build (R32G32B32 position at offset
/// 0, stride 24) read it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

pub struct Mesh {
    pub name: String,
    pub vertices: Vec<Vertex>,
    /// Triangles, three indices each.
    pub indices: Vec<u32>,
}

// ANCHOR: instance
/// One instance, laid out exactly as `VkAccelerationStructureInstanceKHR` (64 bytes), so that
/// one buffer feeds both GL's instanced draw (chapter 05) and the TLAS build (chapter 06).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Instance {
    /// Object to world, the top three rows of a 4x4 matrix, row-major.
    pub transform: [[f32; 4]; 3],
    /// Low 24 bits: the instance's albedo as 0xBBGGRR (`instanceCustomIndex` to a ray, a
    /// `uint` attribute to GL). High 8 bits: the ray visibility mask.
    pub custom_index_and_mask: u32,
    /// Low 24 bits: hit-group offset (unused: no hit groups here). High 8 bits: instance flags.
    pub sbt_offset_and_flags: u32,
    /// The BLAS's device address, filled in by chapter 06; GL ignores it.
    pub blas_address: u64,
}
// ANCHOR_END: instance

impl Instance {
    pub fn new(object_to_world: Mat4, albedo: [u8; 3]) -> Self {
        let rows = object_to_world.transpose().to_cols_array_2d();
        let colour = albedo[0] as u32 | (albedo[1] as u32) << 8 | (albedo[2] as u32) << 16;
        Instance {
            transform: [rows[0], rows[1], rows[2]],
            custom_index_and_mask: colour | 0xFF << 24,
            sbt_offset_and_flags: 0,
            blas_address: 0,
        }
    }

    pub fn object_to_world(&self) -> Mat4 {
        let t = self.transform;
        Mat4::from_cols_array_2d(&[t[0], t[1], t[2], [0.0, 0.0, 0.0, 1.0]]).transpose()
    }
}

pub struct Scene {
    pub meshes: Vec<Mesh>,
    /// Grouped by mesh: `instances[mesh_instances[m]]` are mesh `m`'s, one instanced draw each.
    pub instances: Vec<Instance>,
    pub mesh_instances: Vec<Range<u32>>,
    /// World-space bounds of every instance, around `origin`.
    pub bounds: (Vec3, Vec3),
    /// Where the scene's own origin lies in the world the file or generator described, in f64.
    /// Everything the GPU sees is relative to it (a floating origin), so a model 10,000 times its
    /// own size away from the world's origin keeps the float precision of one at the origin.
    pub origin: [f64; 3],
}

impl Scene {
    pub fn triangles(&self) -> u64 {
        self.mesh_instances
            .iter()
            .zip(&self.meshes)
            .map(|(r, m)| (r.len() * m.indices.len() / 3) as u64)
            .sum()
    }

    /// The diagonal of the bounds: the scene's size, for anything that must scale with it.
    pub fn size(&self) -> f32 {
        (self.bounds.1.as_dvec3() - self.bounds.0.as_dvec3()).length() as f32
    }

    // ANCHOR: scene_new
    /// A scene from meshes and their instances (grouped by mesh, `instances[mesh_instances[m]]`
    /// being mesh `m`'s), re-centred: the instances move so that the bounds' centre is at the
    /// origin, and `origin` records where that was. Errors when there is nothing to trace or
    /// nothing has a size.
    pub fn new(
        meshes: Vec<Mesh>,
        mut instances: Vec<Instance>,
        mesh_instances: Vec<Range<u32>>,
    ) -> Result<Self> {
        let (low, high) = Self::world_bounds(&meshes, &instances, &mesh_instances);
        if !(low.is_finite() && high.is_finite()) {
            bail!("the scene's vertices reach beyond 32-bit float range (bounds {low} to {high})");
        }
        if !(low.cmple(high).all()) {
            bail!("the scene has no triangles");
        }
        if (high - low).max_element() <= 0.0 {
            bail!("all of the scene's vertices coincide at {low}: it has no size to frame or trace");
        }
        // The GPU squares lengths in 32-bit floats (normalising a cross product, a dot product),
        // which overflow past about 1e19 and underflow below about 1e-19: keep well inside.
        let diagonal = (high.as_dvec3() - low.as_dvec3()).length();
        if !(1e-15..=1e15).contains(&diagonal) {
            bail!(
                "the scene is {diagonal:e} units across; 32-bit floats on the GPU handle scenes from 1e-15 \
                 to 1e15 units across: scale it"
            );
        }
        let centre = (low + high) / 2.0;
        for instance in &mut instances {
            for (row, c) in instance.transform.iter_mut().zip(centre.to_array()) {
                row[3] -= c;
            }
        }
        let origin = centre.to_array().map(f64::from);
        Ok(Scene { meshes, instances, mesh_instances, bounds: (low - centre, high - centre), origin })
    }
    // ANCHOR_END: scene_new

    fn world_bounds(meshes: &[Mesh], instances: &[Instance], mesh_instances: &[Range<u32>]) -> (Vec3, Vec3) {
        let (mut low, mut high) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for (mesh, range) in meshes.iter().zip(mesh_instances) {
            for instance in &instances[range.start as usize..range.end as usize] {
                let m = instance.object_to_world();
                for t in mesh.indices.chunks_exact(3) {
                    for &i in t {
                        let p = m.transform_point3(Vec3::from(mesh.vertices[i as usize].position));
                        low = low.min(p);
                        high = high.max(p);
                    }
                }
            }
        }
        (low, high)
    }
}

/// A small, seeded generator (SplitMix64): the scene must be the same on every machine.
pub struct Random(pub u64);

impl Random {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(super) fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Standard normal (Box-Muller).
    pub(super) fn normal(&mut self) -> f32 {
        let u = self.uniform().max(f32::MIN_POSITIVE);
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instance_is_laid_out_as_vulkan_wants() {
        crate::base::pipeline::assert_layout!(Instance is 64 bytes: custom_index_and_mask at 48, blas_address at 56);
        assert_eq!(std::mem::size_of::<Vertex>(), 24);
        let m = Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)) * Mat4::from_scale(Vec3::splat(2.0));
        let instance = Instance::new(m, [1, 2, 3]);
        assert_eq!(instance.transform[0], [2.0, 0.0, 0.0, 1.0], "row-major, translation last");
        assert_eq!(instance.custom_index_and_mask, 0xFF03_0201);
        assert_eq!(instance.object_to_world(), m);
    }
}
