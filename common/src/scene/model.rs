//! Scenes (chapter 05): meshes, instances, the default scene of many tetrahedra over a ground
//! plane, OBJ loading, and a camera that frames whatever was loaded.

use anyhow::{Result, bail};
use glam::{Mat4, Vec3};
use std::ops::Range;
use std::path::Path;

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

/// The flags of every chapter that draws a scene (05 on).
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// An OBJ file to use instead of the default scene.
    #[arg(long)]
    pub scene: Option<std::path::PathBuf>,
    /// Normals for an OBJ file that has none.
    #[arg(long, value_enum, default_value = "smooth")]
    pub normals: Normals,
    /// Tetrahedra in the default scene (0 to a million).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u32).range(0..=1_000_000))]
    pub instances: u32,
    /// One of the scenes `bench` measures instead: `large` (the default scene's tetrahedra over a
    /// million-triangle rippled ground) or `ceiling` (one triangle every ray misses).
    #[arg(long, value_enum, conflicts_with = "scene")]
    pub builtin: Option<super::builtin::SceneKind>,
}

impl SceneArgs {
    /// The OBJ file's scene, or the default one (seeded: the same on every run).
    pub fn load(&self) -> Result<Scene> {
        match (&self.scene, self.builtin) {
            (Some(path), _) => load_obj(path, self.normals),
            (None, Some(kind)) => kind.build(false),
            (None, None) => Ok(default_scene(self.instances, 1)),
        }
    }

    /// Picture names: `<chapter>` for the default scene, `<chapter>-<file stem>` for a model.
    pub fn picture_name(&self, chapter: &str) -> String {
        match (self.scene.as_ref().and_then(|p| p.file_stem()), self.builtin) {
            (Some(stem), _) => format!("{chapter}-{}", stem.to_string_lossy()),
            (None, Some(kind)) => format!("{chapter}-{}", kind.name()),
            (None, None) => chapter.to_owned(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// OBJ files

/// How to make normals for a file that has none.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Normals {
    /// One normal per face: facets show.
    Flat,
    /// Area-weighted average of the faces around each vertex: curved surfaces look smooth.
    Smooth,
}

/// Loads every object in an OBJ file (triangulated) as a mesh with one instance, its albedo the
/// material's diffuse colour (light grey without one). Errors name the file and the problem.
pub fn load_obj(path: &Path, normals: Normals) -> Result<Scene> {
    let shown = path.display();
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, materials) = tobj::load_obj(path, &options).map_err(|e| match e {
        tobj::LoadError::OpenFileFailed => anyhow::anyhow!("{shown}: cannot open the file (does it exist?)"),
        other => anyhow::anyhow!("{shown}: not a valid OBJ file ({other})"),
    })?;
    // A missing .mtl is not fatal: the objects fall back to grey.
    let materials = materials.unwrap_or_else(|e| {
        eprintln!("scene: {shown}: materials not loaded ({e}); using grey");
        Vec::new()
    });
    // The floating origin, already while reading: the file's numbers are subtracted from their
    // centre in f64 (tobj's `use_f64`), so a model far from the origin arrives in f32 as
    // precise as one at the origin. An instance transform could not do this: the vertices would
    // still be far away, in f32, where the BLAS and its rays meet them.
    let centre = file_centre(&models);
    let meshes = meshes_from_obj(models, &materials, &shown.to_string(), normals, centre)?;
    if meshes.is_empty() {
        bail!("{shown}: the file has no faces");
    }
    let instances = meshes.iter().map(|(_, albedo)| Instance::new(Mat4::IDENTITY, *albedo)).collect();
    let mesh_instances = (0..meshes.len() as u32).map(|i| i..i + 1).collect();
    let meshes = meshes.into_iter().map(|(m, _)| m).collect();
    let mut scene =
        Scene::new(meshes, instances, mesh_instances).map_err(|e| anyhow::anyhow!("{shown}: {e}"))?;
    scene.origin = [0, 1, 2].map(|i| centre[i] + scene.origin[i]);
    Ok(scene)
}

/// The centre of the bounds of every finite vertex used by a face, in f64.
fn file_centre(models: &[tobj::Model]) -> [f64; 3] {
    let (mut low, mut high) = ([f64::MAX; 3], [f64::MIN; 3]);
    for m in models {
        for &i in &m.mesh.indices {
            for axis in 0..3 {
                let c = m.mesh.positions.get(3 * i as usize + axis).copied().unwrap_or(f64::NAN);
                if c.is_finite() {
                    low[axis] = low[axis].min(c);
                    high[axis] = high[axis].max(c);
                }
            }
        }
    }
    [0, 1, 2].map(|a| if low[a] <= high[a] { (low[a] + high[a]) / 2.0 } else { 0.0 })
}

/// Each object of a parsed OBJ file with faces, as a mesh and its albedo; `shown` names the file
/// in errors.
fn meshes_from_obj(
    models: Vec<tobj::Model>,
    materials: &[tobj::Material],
    shown: &str,
    normals: Normals,
    centre: [f64; 3],
) -> Result<Vec<(Mesh, [u8; 3])>> {
    let mut meshes = Vec::new();
    for model in models {
        let m = &model.mesh;
        if m.indices.is_empty() {
            continue;
        }
        if m.positions.iter().any(|c| !c.is_finite()) {
            bail!(
                "{shown}: object {:?} has a vertex that is not a finite number (NaN or infinity)",
                model.name
            );
        }
        if let Some(p) =
            m.positions.chunks_exact(3).find(|p| (0..3).any(|a| ((p[a] - centre[a]) as f32).is_infinite()))
        {
            bail!(
                "{shown}: object {:?} has a vertex ({}, {}, {}) beyond 32-bit float range (about 3.4e38) \
                 from the file's centre",
                model.name,
                p[0],
                p[1],
                p[2]
            );
        }
        let count = (m.positions.len() / 3) as u32;
        if let Some(bad) = m.indices.iter().find(|&&i| i >= count) {
            bail!("{shown}: object {:?} refers to vertex {} but has only {count}", model.name, bad + 1);
        }
        let albedo = m
            .material_id
            .and_then(|id| materials.get(id))
            .and_then(|mat| mat.diffuse)
            .map(|d| d.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8))
            .unwrap_or([180, 180, 180]);
        let mut mesh = Mesh {
            name: model.name.clone(),
            vertices: m
                .positions
                .chunks_exact(3)
                .map(|p| Vertex { position: [0, 1, 2].map(|a| (p[a] - centre[a]) as f32), normal: [0.0; 3] })
                .collect(),
            indices: m.indices.clone(),
        };
        // The file's normals, if every vertex has a usable one: `vn 0 0 0` or NaN would put NaN
        // normals into the G-buffer (and NaN rays into traceRayEXT, which is undefined).
        let usable = |n: &[f64]| {
            let n = glam::DVec3::new(n[0], n[1], n[2]);
            n.is_finite() && n.length() > 1e-12
        };
        if m.normals.len() == m.positions.len() && m.normals.chunks_exact(3).all(usable) {
            for (v, n) in mesh.vertices.iter_mut().zip(m.normals.chunks_exact(3)) {
                v.normal = glam::DVec3::new(n[0], n[1], n[2]).normalize().as_vec3().into();
            }
        } else {
            if !m.normals.is_empty() {
                eprintln!(
                    "scene: {shown}: object {:?} has zero or invalid normals; computing them",
                    model.name
                );
            }
            compute_normals(&mut mesh, normals);
        }
        meshes.push((mesh, albedo));
    }
    Ok(meshes)
}

/// Fills in normals for a mesh that has none.
pub fn compute_normals(mesh: &mut Mesh, normals: Normals) {
    if normals == Normals::Flat {
        // Every triangle gets its own three vertices, so each can carry the face's normal.
        let old = std::mem::take(&mut mesh.vertices);
        mesh.vertices = mesh.indices.iter().map(|&i| old[i as usize]).collect();
        mesh.indices = (0..mesh.vertices.len() as u32).collect();
    }
    let mut sums = vec![Vec3::ZERO; mesh.vertices.len()];
    for t in mesh.indices.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| Vec3::from(mesh.vertices[i as usize].position));
        // Not normalised: its length is twice the area, which weights the average.
        let face = (b - a).cross(c - a);
        for &i in t {
            sums[i as usize] += face;
        }
    }
    for (v, n) in mesh.vertices.iter_mut().zip(sums) {
        v.normal = n.normalize_or(Vec3::Y).into();
    }
}

// ---------------------------------------------------------------------------------------------
// Camera

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
        Mat4::look_at_rh(self.eye, self.target, Vec3::Y)
    }

    /// GL's clip space: depth from -1 to 1.
    pub fn projection(&self, aspect: f32) -> Mat4 {
        Mat4::perspective_rh_gl(self.fov_y, aspect, self.near, self.far)
    }

    pub fn view_projection(&self, aspect: f32) -> Mat4 {
        self.projection(aspect) * self.view()
    }
}
// ANCHOR_END: camera

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

    /// The OBJ loader on random and mutated files (truncated lines, huge and negative indices,
    /// NaN and infinity, missing and zero normals, stray bytes, many faces): it never panics, and
    /// returns either a scene whose numbers are all finite, with unit normals, or an error that
    /// names the file.
    #[test]
    fn obj_loader_never_panics_on_bad_input() {
        let base = "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n\
                    f 1//1 2//2 3//3\nf 2//2 4//4 3//3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n";
        let pieces = [
            "f 1 2 99999999999\n",
            "f -1 -2 -9\n",
            "f 0 1 2\n",
            "v nan 0 0\n",
            "v inf -inf 1\n",
            "v 1e39 0 0\n",
            "vn 0 0 0\n",
            "vn nan 1 0\n",
            "f 1/1/1 2/2/2 3/3/3\n",
            "f 1 2\n",
            "f\n",
            "v 1 2\n",
            "v\n",
            "f 1 2 3 4 5 6 7\n",
            "o\n",
            "g group\n",
            "usemtl none\n",
            "mtllib missing.mtl\n",
            "\u{0}\u{ff}\n",
            "f 1// 2// 3//\n",
            "v 1e-45 1e-45 1e-45\n",
            "v 1e39 0 0\n",
            "v 1e30 -1e30 0\n",
        ];
        let dir = std::env::temp_dir().join(format!("vkgl-obj-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut random = Random(42);
        for case in 0..3000 {
            let mut text: Vec<String> = base.lines().map(|l| format!("{l}\n")).collect();
            for _ in 0..1 + (random.next() % 4) {
                let at = (random.next() % (text.len() as u64 + 1)) as usize;
                match random.next() % 3 {
                    0 => text.insert(at, pieces[(random.next() % pieces.len() as u64) as usize].to_owned()),
                    1 if at < text.len() => {
                        let line = &text[at];
                        let cut = (random.next() % (line.len() as u64 + 1)) as usize;
                        text[at] = line.chars().take(cut).collect(); // a truncated line
                    }
                    _ if at < text.len() => {
                        text.remove(at);
                    }
                    _ => {}
                }
            }
            let path = dir.join(format!("case{case}.obj"));
            std::fs::write(&path, text.concat()).unwrap();
            let loaded = std::panic::catch_unwind(|| load_obj(&path, Normals::Smooth));
            match loaded {
                Err(_) => panic!("the loader panicked on:\n{}", text.concat()),
                Ok(Err(error)) => assert!(error.to_string().contains(path.to_str().unwrap()), "{error}"),
                Ok(Ok(scene)) => {
                    assert!(scene.bounds.0.is_finite() && scene.bounds.1.is_finite(), "{}", text.concat());
                    for v in scene.meshes.iter().flat_map(|m| &m.vertices) {
                        let n = Vec3::from(v.normal);
                        assert!((n.length() - 1.0).abs() < 1e-3, "normal {n} in:\n{}", text.concat());
                        assert!(Vec3::from(v.position).is_finite(), "{}", text.concat());
                    }
                }
            }
        }
        // Millions of faces: loads, with every index checked.
        let path = dir.join("many.obj");
        let mut many = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
        many.push_str(&"f 1 2 3\n".repeat(2_000_000));
        std::fs::write(&path, many).unwrap();
        let scene = load_obj(&path, Normals::Flat).unwrap();
        assert_eq!(scene.triangles(), 2_000_000);
        std::fs::remove_dir_all(&dir).unwrap();
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
