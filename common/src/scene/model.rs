//! Scenes (chapter 05): meshes, instances, and the default scene of many tetrahedra over a
//! ground plane. OBJ files are read in `obj.rs`, the camera is in `camera.rs`.

use super::obj::{Normals, meshes_from_obj};
use anyhow::{Result, bail};
use glam::{Mat4, Vec3};
use std::ops::Range;

/// One vertex as both GL (two vec3 attributes) and the BLAS build (R32G32B32 position at offset
/// 0, stride 24) read it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
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
#[derive(Clone, Copy, Debug, PartialEq)]
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

// ---------------------------------------------------------------------------------------------
// The default scene

/// `count` faceted tetrahedra, placed and scaled by a seeded normal distribution, over a
/// 20 x 20 ground plane: two meshes, `count + 1` instances. The same seed gives the same scene.
pub fn default_scene(count: u32, seed: u64) -> Scene {
    let mut random = Random(seed);
    let ground = Instance::new(Mat4::IDENTITY, [200, 200, 200]);
    let tetrahedra = (0..count).map(|_| {
        let scale = 0.15 + 0.1 * random.normal().abs();
        let x = (2.5 * random.normal()).clamp(-9.5, 9.5);
        let z = (2.5 * random.normal()).clamp(-9.5, 9.5);
        let y = scale + 1.5 * random.normal().abs();
        let rotation = glam::Quat::from_euler(
            glam::EulerRot::YXZ,
            random.uniform() * std::f32::consts::TAU,
            random.uniform() * std::f32::consts::TAU,
            0.0,
        );
        let transform =
            Mat4::from_scale_rotation_translation(Vec3::splat(scale), rotation, Vec3::new(x, y, z));
        Instance::new(transform, hue_to_rgb(random.uniform()))
    });
    let instances: Vec<Instance> = std::iter::once(ground).chain(tetrahedra).collect();
    Scene::new(vec![ground_plane(), tetrahedron()], instances, vec![0..1, 1..count + 1])
        .expect("the ground plane alone has a size")
}

/// The default scene's meshes, kept as OBJ files in `assets/` and built into the binaries.
const TETRAHEDRON_OBJ: &str = include_str!("../../../assets/tetrahedron.obj");
const GROUND_OBJ: &str = include_str!("../../../assets/ground.obj");

/// A regular tetrahedron of circumradius 1 with one normal per face (12 vertices).
pub fn tetrahedron() -> Mesh {
    embedded(TETRAHEDRON_OBJ, "assets/tetrahedron.obj", Normals::Flat)
}

/// A 20 x 20 square in the y = 0 plane, facing up.
pub fn ground_plane() -> Mesh {
    embedded(GROUND_OBJ, "assets/ground.obj", Normals::Flat)
}

fn embedded(text: &str, name: &str, normals: Normals) -> Mesh {
    let mut reader = std::io::BufReader::new(text.as_bytes());
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let loaded = tobj::load_obj_buf(&mut reader, &options, |_| Err(tobj::LoadError::OpenFileFailed))
        .map_err(|e| anyhow::anyhow!("{name}: not a valid OBJ file ({e})"))
        .and_then(|(models, _)| meshes_from_obj(models, &[], name, normals, [0.0; 3]));
    // Our own files, built in: a failure here is a bug, and the unit tests below would catch it.
    let mut meshes = loaded.expect("the built-in OBJ files parse");
    meshes.remove(0).0
}

/// A small, seeded generator (SplitMix64): the scene must be the same on every machine.
pub struct Random(pub u64);

impl Random {
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn uniform(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Standard normal (Box-Muller).
    fn normal(&mut self) -> f32 {
        let u = self.uniform().max(f32::MIN_POSITIVE);
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    }
}

fn hue_to_rgb(hue: f32) -> [u8; 3] {
    let channel = |offset: f32| {
        let x = ((hue + offset).fract() * 6.0 - 3.0).abs() - 1.0;
        (60.0 + 180.0 * x.clamp(0.0, 1.0)) as u8
    };
    [channel(0.0), channel(2.0 / 3.0), channel(1.0 / 3.0)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instance_is_laid_out_as_vulkan_wants() {
        assert_eq!(std::mem::size_of::<Instance>(), 64);
        assert_eq!(std::mem::offset_of!(Instance, custom_index_and_mask), 48);
        assert_eq!(std::mem::offset_of!(Instance, blas_address), 56);
        assert_eq!(std::mem::size_of::<Vertex>(), 24);
        let m = Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)) * Mat4::from_scale(Vec3::splat(2.0));
        let instance = Instance::new(m, [1, 2, 3]);
        assert_eq!(instance.transform[0], [2.0, 0.0, 0.0, 1.0], "row-major, translation last");
        assert_eq!(instance.custom_index_and_mask, 0xFF03_0201);
        assert_eq!(instance.object_to_world(), m);
    }

    #[test]
    fn default_scene_is_deterministic_and_sized() {
        let a = default_scene(100, 7);
        let b = default_scene(100, 7);
        assert_eq!(a.instances, b.instances);
        assert_eq!(a.instances.len(), 101);
        assert_eq!(a.triangles(), 2 + 100 * 4);
        // Re-centred: the bounds sit around the origin, `origin` says where they were.
        let centre = (a.bounds.0 + a.bounds.1) / 2.0;
        assert!(centre.length() < 1e-5, "{centre}");
        assert!((a.origin[1] as f32 + a.bounds.0.y).abs() < 1e-3, "the ground was at y = 0");
    }

    #[test]
    fn tetrahedron_normals_point_outwards() {
        let t = tetrahedron();
        for v in &t.vertices {
            assert!(Vec3::from(v.normal).dot(Vec3::from(v.position)) > 0.0);
        }
    }
}
