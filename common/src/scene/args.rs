//! The flags of every chapter that draws a scene (05 on), and the scene they choose: the
//! default one, a built-in one or an OBJ file. The top of the scene layer's small stack: it
//! stands on `obj.rs` and `builtin.rs`, and nothing in the layer stands on it.

use super::builtin::{Ground, SceneKind, default_scene};
use super::model::Scene;
use super::obj::{Normals, load_obj};
use anyhow::Result;

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
    #[arg(long, default_value_t = 10_000, value_parser = crate::base::cli::number::<u32>(0..=1_000_000))]
    pub instances: u32,
    /// One of the scenes `bench` measures instead: `large` (the default scene's tetrahedra over a
    /// million-triangle rippled ground) or `ceiling` (one triangle every ray misses).
    #[arg(long, value_enum, conflicts_with = "scene")]
    pub builtin: Option<SceneKind>,
}

impl SceneArgs {
    /// The OBJ file's scene, or the default one (seeded: the same on every run).
    pub fn load(&self) -> Result<Scene> {
        match (&self.scene, self.builtin) {
            (Some(path), _) => load_obj(path, self.normals),
            (None, Some(kind)) => kind.build(Ground::Fine),
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
