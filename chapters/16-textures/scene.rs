//! Chapter 16's scenes: meshes with texture coordinates, and materials whose colour and cut-out
//! come from pictures. An OBJ file's (read with tobj, its images decoded with `image`), or the
//! chapter's own: the tetrahedra of chapter 05 alternating two pictures over a textured ground,
//! and a fence whose picture is cut out by alpha.

use anyhow::{Result, bail};
use common::scene::{Instance, Mesh, Normals, Random, Scene, Vertex, file_centre, meshes_from_obj};
use glam::{Mat4, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Alpha below this is a hole (GL's discard and the any-hit shader's test alike).
pub const CUTOFF: f32 = 0.5;

/// One picture, decoded: sRGB colour and linear alpha, 8 bits each, rows top first.
pub struct Picture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// What a textured mesh draws with: which picture, and whether its alpha cuts holes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    pub picture: usize,
    pub cut_out: bool,
}

/// A scene, each mesh's texture coordinates (one per vertex, or none) and surface (`None`: the
/// material's plain colour, as chapter 08 draws it), and the pictures, each once.
pub struct TexturedScene {
    pub scene: Scene,
    pub uvs: Vec<Vec<[f32; 2]>>,
    pub surfaces: Vec<Option<Surface>>,
    pub pictures: Vec<Picture>,
}

impl TexturedScene {
    /// Does any instance's material cut holes? Only then do the rays need an any-hit shader.
    pub fn has_cut_outs(&self) -> bool {
        self.surfaces.iter().flatten().any(|s| s.cut_out)
    }

    /// Forgets every picture: each material keeps its plain colour, as chapter 08 draws it.
    pub fn drop_pictures(&mut self) {
        self.surfaces.iter_mut().for_each(|s| *s = None);
        self.pictures.clear();
    }
}

// ANCHOR: load
/// An OBJ file with its materials' pictures: `map_Kd` (colour) and `map_d` (alpha), their paths
/// relative to the file's folder. A picture that cannot be read is a warning naming the file and
/// the problem, and its material keeps its plain colour.
pub fn load(path: &Path, normals: Normals) -> Result<TexturedScene> {
    let shown = path.display().to_string();
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let (models, materials) = tobj::load_obj(path, &options).map_err(|e| match e {
        tobj::LoadError::OpenFileFailed => anyhow::anyhow!("{shown}: cannot open the file (does it exist?)"),
        other => anyhow::anyhow!("{shown}: not a valid OBJ file ({other})"),
    })?;
    let materials = materials.unwrap_or_else(|e| {
        eprintln!("scene: {shown}: materials not loaded ({e}); using grey");
        Vec::new()
    });
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut pictures = Pictures::default();
    let (mut meshes, mut albedos, mut uvs, mut surfaces) = (vec![], vec![], vec![], vec![]);
    // Chapter 05's floating origin: the file's numbers less their centre, in f64.
    let centre = file_centre(&models);
    for model in models {
        let material = model.mesh.material_id.and_then(|id| materials.get(id));
        let texcoords = model.mesh.texcoords.clone();
        let original = model.mesh.indices.clone();
        let count = model.mesh.positions.len() / 3;
        for (mesh, albedo) in meshes_from_obj(vec![model], &materials, &shown, normals, centre)? {
            // Texture coordinates as GL and Vulkan read them: v down from the picture's top row
            // (row 0 in memory), where OBJ's v goes up from its bottom row.
            let per_vertex: Vec<[f32; 2]> = if texcoords.len() == 2 * count {
                (0..count).map(|i| [texcoords[2 * i] as f32, 1.0 - texcoords[2 * i + 1] as f32]).collect()
            } else {
                Vec::new()
            };
            // Flat normals gave every corner its own vertex, in index order: follow them.
            let per_vertex = match per_vertex.is_empty() || mesh.vertices.len() == count {
                true => per_vertex,
                false => original.iter().map(|&i| per_vertex[i as usize]).collect(),
            };
            let surface = match (material, per_vertex.is_empty()) {
                (Some(material), false) => pictures.of(material, folder, &shown),
                _ => None,
            };
            uvs.push(if surface.is_some() { per_vertex } else { Vec::new() });
            surfaces.push(surface);
            meshes.push(mesh);
            albedos.push(albedo);
        }
    }
    if meshes.is_empty() {
        bail!("{shown}: the file has no faces");
    }
    let instances = albedos.iter().map(|a| Instance::new(Mat4::IDENTITY, *a)).collect();
    let ranges = (0..meshes.len() as u32).map(|i| i..i + 1).collect();
    let mut scene = Scene::new(meshes, instances, ranges).map_err(|e| anyhow::anyhow!("{shown}: {e}"))?;
    scene.origin = [0, 1, 2].map(|i| centre[i] + scene.origin[i]);
    Ok(TexturedScene { scene, uvs, surfaces, pictures: pictures.list })
}
// ANCHOR_END: load

/// The pictures read so far, each colour and alpha pair once however many materials name it.
#[derive(Default)]
struct Pictures {
    list: Vec<Picture>,
    seen: HashMap<(Option<PathBuf>, Option<PathBuf>), Option<Surface>>,
}

impl Pictures {
    /// The surface a material's maps make, `None` for a material with neither map or whose
    /// pictures cannot be read (said on stderr).
    fn of(&mut self, material: &tobj::Material, folder: &Path, shown: &str) -> Option<Surface> {
        let colour = material.diffuse_texture.as_deref().map(|p| resolve(folder, p));
        let alpha = material.dissolve_texture.as_deref().map(|p| resolve(folder, p));
        if colour.is_none() && alpha.is_none() {
            return None;
        }
        let key = (colour.clone(), alpha.clone());
        if let Some(surface) = self.seen.get(&key) {
            return *surface;
        }
        let read = |path: &PathBuf| {
            decode(path).map_err(|problem| {
                eprintln!(
                    "scene: {shown}: material {:?}: {}: {problem}; using its plain colour",
                    material.name,
                    path.display()
                )
            })
        };
        let picture = match (&colour, &alpha) {
            (Some(c), None) => read(c).ok(),
            (None, Some(a)) => read(a).ok().map(|a| with_alpha(white(&a), &a)),
            (Some(c), Some(a)) => read(c).ok().zip(read(a).ok()).map(|(c, a)| with_alpha(c, &a)),
            (None, None) => None,
        };
        let surface = picture.map(|picture| {
            // A cut-out where the material says so (map_d), or where its colour has holes.
            let cut_out =
                alpha.is_some() || picture.rgba.chunks_exact(4).any(|p| (p[3] as f32) < CUTOFF * 255.0);
            self.list.push(picture);
            Surface { picture: self.list.len() - 1, cut_out }
        });
        self.seen.insert(key, surface);
        surface
    }
}

/// A map's path as the .mtl wrote it, on this machine: relative to the OBJ file's folder, its
/// backslashes (files written on Windows) read as folder separators; spaces are kept.
fn resolve(folder: &Path, written: &str) -> PathBuf {
    // An option before the name (`-bm 1 name.png`, `-clamp on name.png`) is not part of it.
    let mut words: Vec<&str> = written.split(' ').collect();
    while words.len() > 2 && words[0].starts_with('-') {
        words.drain(..2);
    }
    folder.join(words.join(" ").replace('\\', "/"))
}

// ANCHOR: decode
/// A picture file as RGBA8, whatever it holds (grey, 16-bit, palette, RGB): PNG, JPEG or TGA.
/// The error says what is wrong with the file, not where it is (the caller names it).
pub fn decode(path: &Path) -> std::result::Result<Picture, String> {
    if path.is_dir() {
        return Err("is a directory, not a picture".into());
    }
    let reader = image::ImageReader::open(path).map_err(|e| format!("cannot open it ({e})"))?;
    let reader = reader.with_guessed_format().map_err(|e| format!("cannot read it ({e})"))?;
    let decoded = reader.decode().map_err(|e| format!("not a picture this chapter reads ({e})"))?;
    let rgba = decoded.to_rgba8(); // 16 bits round to 8, grey and palette expand, alpha 255 added
    let (width, height) = rgba.dimensions();
    if width == 0 || height == 0 {
        return Err(format!("is {width}x{height}: a picture needs at least one pixel"));
    }
    let name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    Ok(Picture { name, width, height, rgba: rgba.into_raw() })
}
// ANCHOR_END: decode

/// `colour` with the alpha of `alpha` (its grey: the mean of its red, green and blue), sampled at
/// the nearest pixel where the sizes differ.
fn with_alpha(mut colour: Picture, alpha: &Picture) -> Picture {
    for y in 0..colour.height {
        for x in 0..colour.width {
            let (ax, ay) = (x * alpha.width / colour.width, y * alpha.height / colour.height);
            let a = &alpha.rgba[4 * (ay * alpha.width + ax) as usize..][..4];
            let grey = (a[0] as u32 + a[1] as u32 + a[2] as u32).div_ceil(3) as u8;
            colour.rgba[4 * (y * colour.width + x) as usize + 3] = if a[3] < 255 { a[3] } else { grey };
        }
    }
    colour
}

fn white(like: &Picture) -> Picture {
    Picture {
        name: like.name.clone(),
        width: like.width,
        height: like.height,
        rgba: vec![255; like.rgba.len()],
    }
}

// ANCHOR: default_scene
/// The chapter's own scene: `count` tetrahedra over a ground, alternating two pictures (the
/// reference sample's idea), and a fence standing over them, cut out by its picture's alpha.
/// Its pictures are made here, at sizes no power of two divides (odd levels get made too).
pub fn default_scene(count: u32) -> Result<TexturedScene> {
    let pictures =
        vec![
            picture("ground", 64, 64, |x, y| {
                if (x / 8 + y / 8) % 2 == 0 { [92, 128, 70, 255] } else { [150, 170, 110, 255] }
            }),
            picture("tiles", 48, 48, |x, y| {
                if x % 12 < 2 || y % 12 < 2 { [60, 40, 30, 255] } else { [214, 120, 60, 255] }
            }),
            picture("rings", 37, 23, |x, y| {
                let d = ((x as f32 - 18.0).powi(2) + (y as f32 - 11.0).powi(2)).sqrt();
                if (d / 3.0) as u32 % 2 == 0 { [70, 110, 200, 255] } else { [230, 230, 240, 255] }
            }),
            // A lattice of slats: alpha 0 between them, so half the fence is holes.
            picture("fence", 64, 32, |x, y| {
                if x % 16 < 5 || y % 16 < 4 { [200, 190, 170, 255] } else { [0, 0, 0, 0] }
            }),
        ];
    let mut random = Random(16);
    let mut tetrahedra = [Vec::new(), Vec::new()];
    for i in 0..count {
        let (x, z) = (random.uniform_in(-8.0, 8.0), random.uniform_in(-8.0, 8.0));
        let turn = Mat4::from_rotation_y(random.uniform_in(0.0, std::f32::consts::TAU));
        tetrahedra[i as usize % 2]
            .push(Instance::new(Mat4::from_translation(Vec3::new(x, 0.0, z)) * turn, [255; 3]));
    }
    let [a, b] = tetrahedra;
    let fence = Mat4::from_translation(Vec3::new(0.0, 0.0, 2.0));
    let instances: Vec<Instance> = [Instance::new(Mat4::IDENTITY, [255; 3])]
        .into_iter()
        .chain(a.iter().copied())
        .chain(b.iter().copied())
        .chain([Instance::new(fence, [255; 3])])
        .collect();
    let counts = [1, a.len() as u32, b.len() as u32, 1];
    let mut ranges = Vec::new();
    for n in counts {
        let start = ranges.last().map_or(0, |r: &std::ops::Range<u32>| r.end);
        ranges.push(start..start + n);
    }
    let (ground, ground_uv) =
        quad("ground", [-10.0, 0.0, -10.0], [20.0, 0.0, 0.0], [0.0, 0.0, 20.0], [5.0, 5.0]);
    let (tetra_a, tetra_uv) = tetrahedron("tetrahedron a");
    let (tetra_b, _) = tetrahedron("tetrahedron b");
    let (fence, fence_uv) = quad("fence", [-6.0, 0.0, 0.0], [12.0, 0.0, 0.0], [0.0, 3.0, 0.0], [6.0, 1.5]);
    let scene = Scene::new(vec![ground, tetra_a, tetra_b, fence], instances, ranges)?;
    let surface = |picture, cut_out| Some(Surface { picture, cut_out });
    Ok(TexturedScene {
        scene,
        uvs: vec![ground_uv, tetra_uv.clone(), tetra_uv, fence_uv],
        surfaces: vec![surface(0, false), surface(1, false), surface(2, false), surface(3, true)],
        pictures,
    })
}
// ANCHOR_END: default_scene

fn picture(name: &str, width: u32, height: u32, texel: impl Fn(u32, u32) -> [u8; 4]) -> Picture {
    let rgba =
        (0..height).flat_map(|y| (0..width).map(move |x| (x, y))).flat_map(|(x, y)| texel(x, y)).collect();
    Picture { name: name.into(), width, height, rgba }
}

/// A parallelogram from `corner` along `u` and `v`, seen from both sides (the AO rays start on
/// the side facing the camera), its texture repeated `repeat` times along each edge.
fn quad(name: &str, corner: [f32; 3], u: [f32; 3], v: [f32; 3], repeat: [f32; 2]) -> (Mesh, Vec<[f32; 2]>) {
    let (c, u, v) = (Vec3::from(corner), Vec3::from(u), Vec3::from(v));
    let normal = v.cross(u).normalize().to_array();
    let corners = [c, c + u, c + u + v, c + v];
    let vertices = corners.iter().map(|p| Vertex { position: p.to_array(), normal }).collect();
    let uvs = vec![[0.0, repeat[1]], [repeat[0], repeat[1]], [repeat[0], 0.0], [0.0, 0.0]];
    (Mesh { name: name.into(), vertices, indices: vec![0, 2, 1, 0, 3, 2] }, uvs)
}

/// Chapter 05's tetrahedron, one picture per face: each face's own three corners.
fn tetrahedron(name: &str) -> (Mesh, Vec<[f32; 2]>) {
    let corners = [[0.0, 1.6, 0.0], [-0.8, 0.0, -0.5], [0.8, 0.0, -0.5], [0.0, 0.0, 0.9]].map(Vec3::from);
    let faces = [[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]];
    let (mut vertices, mut uvs) = (Vec::new(), Vec::new());
    for face in faces {
        let [a, b, c] = face.map(|i| corners[i]);
        let normal = (b - a).cross(c - a).normalize().to_array();
        for (p, uv) in [(a, [0.5, 0.0]), (b, [1.0, 1.0]), (c, [0.0, 1.0])] {
            vertices.push(Vertex { position: p.to_array(), normal });
            uvs.push(uv);
        }
    }
    (Mesh { name: name.into(), vertices, indices: (0..12).collect() }, uvs)
}

/// `Random` in a range.
trait UniformIn {
    fn uniform_in(&mut self, low: f32, high: f32) -> f32;
}

impl UniformIn for Random {
    fn uniform_in(&mut self, low: f32, high: f32) -> f32 {
        low + (high - low) * ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32)
    }
}
