//! Chapter 13's path: where the camera and the one moving instance are at every frame. The
//! same on every run and for every method, so that errors and times along it compare.

use common::interop::exportable::ExportedBuffer;
use common::scene::{Camera, Instance, Scene};
use glam::{Mat4, Vec3, Vec4};
use std::f32::consts::TAU;

/// What the camera does (`--path`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PathKind {
    /// Turns about the scene's centre, and once (`--cut-at`) jumps to another view.
    Orbit,
    /// Slides sideways, looking the same way.
    Pan,
    /// Stands still.
    Still,
}

/// Whether an instance moves (`--mover`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mover {
    /// One instance runs in a circle (a scene of one instance: it turns where it stands).
    Circle,
    None,
}

/// The path's flags, which chapter 13 and `convergence temporal` share.
#[derive(clap::Args, Clone, Debug)]
pub struct PathArgs {
    /// What the camera does: `orbit` (turns about the scene, with one cut), `pan` (slides
    /// sideways), `still`.
    #[arg(long, value_enum, default_value = "orbit")]
    pub path: PathKind,
    /// The frame at which the orbiting camera jumps to another view (0: no cut).
    #[arg(long, default_value_t = 60, value_parser = common::base::cli::number::<u32>(0..=1_000_000))]
    pub cut_at: u32,
    /// Whether one instance moves while the camera does (`circle`) or not (`none`).
    #[arg(long, value_enum, default_value = "circle")]
    pub mover: Mover,
}

/// How far the orbiting camera turns, or the panning one slides, each frame: 720 frames a lap.
const DEGREES_PER_FRAME: f32 = 0.5;
/// Frames per lap of the moving instance.
const LAP_FRAMES: f32 = 240.0;
/// The cut: how far round the camera jumps, how much it tilts and how much closer it comes.
const CUT: (f32, f32, f32) = (2.2, -0.25, 1.6);

pub struct Path {
    kind: PathKind,
    start: Camera,
    bounds: (Vec3, Vec3),
    /// Radians per frame.
    speed: f32,
    cut_at: u32,
    pub moving: Option<Moving>,
}

/// The instance that moves: where it started, about which point it turns, how far it runs.
pub struct Moving {
    pub index: usize,
    start: Mat4,
    centre: Vec3,
    radius: f32,
    /// The mesh's bounding sphere in its object space (centre, radius), as `start` places it.
    sphere: (Vec3, f32),
}

impl Path {
    pub fn new(scene: &Scene, start: Camera, args: &PathArgs) -> Path {
        let moving = (args.mover == Mover::Circle).then(|| Moving::choose(scene));
        let (kind, cut_at) = (args.path, if args.path == PathKind::Orbit { args.cut_at } else { 0 });
        Path { kind, start, bounds: scene.bounds, speed: DEGREES_PER_FRAME.to_radians(), cut_at, moving }
    }

    // ANCHOR: camera
    /// The camera at `frame`: worked out from the start every time, never step by step, so that
    /// any frame can be drawn again exactly.
    pub fn camera(&self, frame: u32) -> Camera {
        let mut camera = self.start;
        let turned = self.speed * frame as f32;
        match self.kind {
            PathKind::Still => {}
            PathKind::Orbit if self.is_after_cut(frame) => {
                let (yaw, pitch, zoom) = CUT;
                camera.orbit(yaw + turned, pitch, zoom, self.bounds);
            }
            PathKind::Orbit => camera.orbit(turned, 0.0, 1.0, self.bounds),
            PathKind::Pan => {
                // Sideways by as much as the orbit would turn the view at the target.
                let forward = (camera.target - camera.eye).normalize();
                let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
                let step = right * (camera.target - camera.eye).length() * turned.tan();
                camera.eye += step;
                camera.target += step;
            }
        }
        camera
    }
    // ANCHOR_END: camera

    /// What the camera does.
    pub fn kind(&self) -> PathKind {
        self.kind
    }

    pub fn is_after_cut(&self, frame: u32) -> bool {
        self.cut_at > 0 && frame >= self.cut_at
    }

    /// The frame the camera jumps at, if the path has one.
    pub fn cut(&self) -> Option<u32> {
        (self.cut_at > 0).then_some(self.cut_at)
    }
}

/// The frames a headless walk along the path draws unless `--frames` says otherwise: the whole
/// path, cut included.
pub const PATH_FRAMES: u32 = 120;

/// `--frames`'s help where a walk of the path is the headless run (chapter 13, `convergence
/// temporal`): every chapter's help, with this default.
pub fn frames_help(arg: clap::Arg) -> clap::Arg {
    arg.help(format!(
        "How many frames to run, 0 to 10000000 [default: {PATH_FRAMES} headless, the whole path; a window \
         runs until it is closed, as with 0]"
    ))
}

impl Moving {
    /// The instance nearest the scene's centre, other than the ground (instance 0) where there
    /// are others; grown four times where there are, so that it and its shadow cover pixels
    /// enough to see at any size (a tetrahedron of the default scene is a few pixels across).
    fn choose(scene: &Scene) -> Moving {
        let matrix = |i: usize| {
            let [r0, r1, r2] = scene.instances[i].transform;
            Mat4::from_cols(Vec4::from(r0), Vec4::from(r1), Vec4::from(r2), Vec4::W).transpose()
        };
        let centre = (scene.bounds.0 + scene.bounds.1) / 2.0;
        let mesh_of =
            |i: usize| scene.mesh_instances.iter().position(|r| r.contains(&(i as u32))).unwrap_or(0);
        let middle = |i: usize| {
            let mesh = &scene.meshes[mesh_of(i)];
            let (low, high) = mesh.vertices.iter().fold((Vec3::MAX, Vec3::MIN), |(l, h), v| {
                (l.min(Vec3::from(v.position)), h.max(Vec3::from(v.position)))
            });
            let m = matrix(i);
            (
                m.transform_point3((low + high) / 2.0),
                (m.transform_vector3(high - low)).length(),
                (low + high) / 2.0,
            )
        };
        let candidates = if scene.instances.len() > 1 { 1..scene.instances.len() } else { 0..1 };
        let index = candidates
            .min_by(|&a, &b| (middle(a).0 - centre).length().total_cmp(&(middle(b).0 - centre).length()))
            .unwrap_or(0);
        let (at, size, object_centre) = middle(index);
        let alone = scene.instances.len() == 1;
        let grow = if alone { 1.0 } else { 4.0 };
        let start =
            Mat4::from_translation(at) * Mat4::from_scale(Vec3::splat(grow)) * Mat4::from_translation(-at);
        let sphere = (object_centre, grow * size / 2.0);
        Moving {
            index,
            start: start * matrix(index),
            centre: at,
            radius: if alone { 0.0 } else { 2.0 * grow * size },
            sphere,
        }
    }

    // ANCHOR: mover
    /// Object to world at `frame`: round a circle of `radius` about where it started, turning
    /// as it goes (one lap in LAP_FRAMES frames).
    pub fn at(&self, frame: u32) -> Mat4 {
        let angle = TAU * frame as f32 / LAP_FRAMES;
        let offset = Vec3::new(angle.cos() - 1.0, 0.0, angle.sin()) * self.radius;
        let turn = Mat4::from_rotation_y(angle);
        Mat4::from_translation(self.centre + offset)
            * turn
            * Mat4::from_translation(-self.centre)
            * self.start
    }

    /// A sphere (centre, radius) holding the instance at the frame before `frame` and at
    /// `frame`: everything that moved between them.
    pub fn swept(&self, frame: u32) -> (Vec3, f32) {
        let (before, now) = (self.at(frame.saturating_sub(1)), self.at(frame));
        let (a, b) = (before.transform_point3(self.sphere.0), now.transform_point3(self.sphere.0));
        ((a + b) / 2.0, (b - a).length() / 2.0 + self.sphere.1)
    }

    /// Writes the transform at `frame` into `copy`, a copy of the instance buffer (where only
    /// the 48 transform bytes of this instance's row change).
    pub fn write(&self, copy: &mut [u8], frame: u32) {
        let (offset, now) = self.row(frame);
        copy[offset..offset + size_of_val(&now)].copy_from_slice(bytemuck::cast_slice(&now));
    }

    /// Writes the transform at `frame` into `instances`, the shared buffer GL draws the ids with
    /// and the TLAS is updated from. Nothing may be reading it: the caller waited for GL's last
    /// ids and the last TLAS update.
    pub fn write_shared(&self, instances: &ExportedBuffer, frame: u32) {
        let (offset, now) = self.row(frame);
        assert!(offset + size_of_val(&now) <= instances.bytes as usize);
        // SAFETY: in bounds of the coherent mapping (checked above), and nothing reads it now.
        unsafe { instances.mapped.add(offset).cast::<[[f32; 4]; 3]>().write_unaligned(now) };
    }

    /// Where this instance's transform starts in an instance buffer, and its transform at `frame`.
    fn row(&self, frame: u32) -> (usize, [[f32; 4]; 3]) {
        let offset = self.index * size_of::<Instance>() + std::mem::offset_of!(Instance, transform);
        (offset, Instance::new(self.at(frame), [0; 3]).transform)
    }
    // ANCHOR_END: mover
}
