//! The scenes built into the binaries: the default scene of many tetrahedra over a ground plane
//! (chapter 05), and the scenes `bench` measures, which every chapter loads too (`--builtin`):
//! the default, a large one (over a million triangles), and a one-triangle "ceiling" whose rays
//! all miss, which measures the best the GPU's traversal can do.

use super::model::{Instance, Mesh, Random, Scene, Vertex};
use super::obj::{Normals, meshes_from_obj};
use anyhow::Result;
use glam::{Mat4, Vec3};

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

fn hue_to_rgb(hue: f32) -> [u8; 3] {
    let channel = |offset: f32| {
        let x = ((hue + offset).fract() * 6.0 - 3.0).abs() - 1.0;
        (60.0 + 180.0 * x.clamp(0.0, 1.0)) as u8
    };
    [channel(0.0), channel(2.0 / 3.0), channel(1.0 / 3.0)]
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SceneKind {
    /// Chapter 08's default: 10,000 tetrahedra over a ground plane (40,002 triangles).
    Default,
    /// The default scene's tetrahedra over a finely tessellated, rippled ground.
    Large,
    /// One triangle: every AO ray misses it.
    Ceiling,
}

/// How finely the large scene's ground is tessellated (the other scenes have one ground).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ground {
    /// 720 x 720 quads: what `bench` measures.
    Fine,
    /// 32 x 32 quads, so that a test (`bench --quick`) builds it in a second on a CPU.
    Coarse,
}

impl SceneKind {
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::Default => "default",
            SceneKind::Large => "large",
            SceneKind::Ceiling => "ceiling",
        }
    }

    pub fn build(self, ground: Ground) -> Result<Scene> {
        match self {
            SceneKind::Default => Ok(default_scene(10_000, 1)),
            SceneKind::Large => {
                // 720 x 720 quads: 1,036,800 triangles of ground, plus the 40,000 of the tetrahedra.
                let Scene { mut meshes, instances, mesh_instances, .. } = default_scene(10_000, 1);
                meshes[0] = rippled_ground(match ground {
                    Ground::Fine => 720,
                    Ground::Coarse => 32,
                });
                Scene::new(meshes, instances, mesh_instances)
            }
            SceneKind::Ceiling => {
                let up = [0.0, 1.0, 0.0];
                let corner = |x: f32, z: f32| Vertex { position: [x, 0.0, z], normal: up };
                let mesh = Mesh {
                    name: "one triangle".into(),
                    // Counter-clockwise seen from above (+y), as the ground plane's triangles are.
                    vertices: vec![corner(-10.0, 10.0), corner(10.0, 10.0), corner(0.0, -10.0)],
                    indices: vec![0, 1, 2],
                };
                let instance = Instance::new(Mat4::IDENTITY, [200, 200, 200]);
                Scene::new(vec![mesh], vec![instance], std::iter::once(0..1).collect())
            }
        }
    }
}

/// A 20 x 20 ground of `n` x `n` quads in y = 0, with gentle ripples (0.1 high) so that the
/// triangles are not coplanar and the BLAS has real depth to sort.
fn rippled_ground(n: u32) -> Mesh {
    let height = |x: f32, z: f32| 0.05 * ((x * 3.0).sin() + (z * 2.3).cos());
    let mut vertices = Vec::with_capacity(((n + 1) * (n + 1)) as usize);
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (-10.0 + 20.0 * i as f32 / n as f32, -10.0 + 20.0 * j as f32 / n as f32);
            // The surface's normal: (-dh/dx, 1, -dh/dz), normalised.
            let (dx, dz) = (0.15 * (x * 3.0).cos(), -0.115 * (z * 2.3).sin());
            let normal = Vec3::new(-dx, 1.0, -dz).normalize().to_array();
            vertices.push(Vertex { position: [x, height(x, z), z], normal });
        }
    }
    let mut indices = Vec::with_capacity((n * n * 6) as usize);
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            // Counter-clockwise seen from above: a, c, b and b, c, d (z grows towards the viewer).
            indices.extend_from_slice(&[a, c, b, b, c, d]);
        }
    }
    Mesh { name: format!("rippled ground {n}x{n}"), vertices, indices }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::obj::compute_normals;

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

    #[test]
    fn smooth_and_flat_normals() {
        let mut m = tetrahedron();
        compute_normals(&mut m, Normals::Flat);
        assert_eq!(m.vertices.len(), 12);
        let mut shared = ground_plane();
        compute_normals(&mut shared, Normals::Smooth);
        assert!(shared.vertices.iter().all(|v| (Vec3::from(v.normal) - Vec3::Y).length() < 1e-6));
    }
}
