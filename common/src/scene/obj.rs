//! OBJ files (chapter 05 on), read with tobj, their normals made where they have none.

use super::model::{Instance, Mesh, Scene, Vertex};
use anyhow::{Result, bail};
use glam::{Mat4, Vec3};
use std::path::{Path, PathBuf};

/// One of the tutorial's own files in `assets/`, for a chapter's default model: found in the
/// checkout the binary was built from, so that the chapter runs from any directory (a path the
/// user gives stays relative to the current directory). An error names the path tried and
/// `flag`, which gives a file instead.
pub fn default_asset(name: &str, flag: &str) -> Result<PathBuf> {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(|root| root.join("assets"));
    let path = assets.unwrap_or_default().join(name);
    if !path.is_file() {
        bail!(
            "{}: the default for {flag} is not there (binaries look for it in the checkout they were \
             built from); name a file with {flag} PATH",
            path.display()
        );
    }
    Ok(path)
}

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
    // A scene with no size is refused by `Scene::new`, which sees the centred numbers: name the
    // point in the file's own coordinates here instead.
    let mut positions = meshes.iter().flat_map(|(m, _)| m.vertices.iter().map(|v| Vec3::from(v.position)));
    if let Some(first) = positions.next()
        && positions.all(|p| p == first)
    {
        let at = glam::DVec3::from(centre) + first.as_dvec3();
        bail!("{shown}: all of the file's vertices coincide at {at}: it has no size to frame or trace");
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
pub fn file_centre(models: &[tobj::Model]) -> [f64; 3] {
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
/// in errors. (Chapter 16 calls it one object at a time, to keep each object's material.)
pub fn meshes_from_obj(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Random;

    /// The OBJ loader on random and mutated files (truncated lines, huge and negative indices,
    /// NaN and infinity, missing and zero normals, stray bytes, many faces): it never panics, and
    /// returns either a scene whose numbers are all finite, with unit normals, or an error that
    /// names the file.
    #[test]
    fn default_assets_are_found_or_named() {
        let bunny = default_asset("bunny.obj", "--model").unwrap();
        assert!(bunny.is_absolute() && bunny.ends_with("assets/bunny.obj"), "{}", bunny.display());
        let missing = default_asset("no-such.obj", "--model").unwrap_err().to_string();
        assert!(missing.contains("assets/no-such.obj") && missing.contains("--model PATH"), "{missing}");
    }

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
            for _ in 0..1 + (random.next_u64() % 4) {
                let at = (random.next_u64() % (text.len() as u64 + 1)) as usize;
                match random.next_u64() % 3 {
                    0 => {
                        text.insert(at, pieces[(random.next_u64() % pieces.len() as u64) as usize].to_owned())
                    }
                    1 if at < text.len() => {
                        let line = &text[at];
                        let cut = (random.next_u64() % (line.len() as u64 + 1)) as usize;
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
}
