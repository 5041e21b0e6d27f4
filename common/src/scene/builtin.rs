//! The scenes `bench` measures, which chapter 12 loads too (`--builtin`): chapter 08's default
//! scene, a large one (over a million triangles), and a one-triangle "ceiling" whose rays all
//! miss, which measures the best the GPU's traversal can do.

use super::model::{Instance, Mesh, Scene, Vertex, default_scene};
use anyhow::Result;
use glam::{Mat4, Vec3};

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
