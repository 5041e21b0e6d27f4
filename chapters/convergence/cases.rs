//! The scenes `convergence` measures: two with an exact answer at every pixel, and the default
//! scene, whose answer is a long run of the same tracer.

use crate::exact;
use common::scene::{Camera, Instance, Mesh, Scene, Vertex, default_scene};
use glam::{DVec3, Mat4};

/// One scene to measure, with its camera, its radius, and its exact answer if it has one.
pub struct Case {
    pub name: &'static str,
    pub scene: Scene,
    pub camera: Camera,
    pub radius: f32,
    /// The exact visibility (1 − occlusion) at a world position GL wrote into the G-buffer, or
    /// `None` where the finite planes are too close to an edge to stand in for infinite ones.
    pub exact: Option<Box<dyn Fn(DVec3) -> Option<f64>>>,
}

impl Case {
    /// A case with an exact answer: `exact` takes a point in the case's own units, where it is
    /// `size` across (before `place` scaled and moved it), and `radius` is in those units too.
    fn exact(
        name: &'static str,
        scene: Scene,
        camera: Camera,
        place: Placement,
        (size, radius): (f64, f64),
        exact: impl Fn(DVec3) -> Option<f64> + 'static,
    ) -> Case {
        let origin = DVec3::from(scene.origin);
        let exact = move |p: DVec3| exact(place.to_case(p, origin, size));
        Case { name, scene, camera, radius: (radius * place.scale) as f32, exact: Some(Box::new(exact)) }
    }
}

/// Where an exact case sits: scaled by `scale` about its own origin, then moved `offset` times
/// its own size along a diagonal that is no axis (the scale/offset invariance tests use it).
#[derive(Clone, Copy)]
pub struct Placement {
    pub scale: f64,
    pub offset: f64,
}

impl Placement {
    const DIRECTION: DVec3 = DVec3::new(0.6, -0.48, 0.64); // unit length

    /// Where the case's origin goes: the instance's translation, as f32 holds it. The mesh
    /// itself stays in the case's own (scaled) coordinates, as a real program keeps a model in
    /// its own coordinates and places it with a transform: vertices rounded to f32 10,000 sizes
    /// away would lose the precision the rays need.
    fn translation(&self, size: f64) -> DVec3 {
        (Self::DIRECTION * (self.offset * size * self.scale)).as_vec3().as_dvec3()
    }

    /// From the case's own coordinates to the world the scene is described in.
    fn to_world(self, p: DVec3, size: f64) -> DVec3 {
        p * self.scale + self.translation(size)
    }

    /// Back from a re-centred position (what the G-buffer holds) to the case's coordinates.
    fn to_case(self, p: DVec3, origin: DVec3, size: f64) -> DVec3 {
        (p + origin - self.translation(size)) / self.scale
    }
}

/// A mesh of quads, each given by four corners (counter-clockwise seen from the side its normal
/// faces), in the case's coordinates times its scale.
fn quads(corners: &[[DVec3; 4]], place: Placement) -> Mesh {
    let mut vertices = Vec::new();
    let mut indices = Vec::new();
    for quad in corners {
        let normal = (quad[1] - quad[0]).cross(quad[2] - quad[0]).normalize().as_vec3();
        let base = vertices.len() as u32;
        for &c in quad {
            let p = (c * place.scale).as_vec3(); // in the mesh's own coordinates
            vertices.push(Vertex { position: p.into(), normal: normal.into() });
        }
        indices.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    Mesh { name: "planes".into(), vertices, indices }
}

/// A camera looking from `eye` at `target` (case coordinates), placed like the scene.
fn camera(
    scene: &Scene,
    place: Placement,
    size: f64,
    (eye, target): (DVec3, DVec3),
    (near, far): (f64, f64),
) -> Camera {
    let origin = DVec3::from(scene.origin);
    Camera {
        eye: (place.to_world(eye, size) - origin).as_vec3(),
        target: (place.to_world(target, size) - origin).as_vec3(),
        fov_y: 45f32.to_radians(),
        near: (near * place.scale) as f32,
        far: (far * place.scale) as f32,
    }
}

/// One mesh, placed by one instance, and a second instance of it scaled to nothing between the
/// planes: an instance with zero scale must draw nothing and occlude nothing (its triangles
/// have no area), so the exact answer still holds.
fn one_mesh_scene(mesh: Mesh, place: Placement, size: f64, inside: DVec3) -> anyhow::Result<Scene> {
    let transform = Mat4::from_translation(place.translation(size).as_vec3());
    let vanished =
        Mat4::from_translation(place.to_world(inside, size).as_vec3()) * Mat4::from_scale(glam::Vec3::ZERO);
    let instances = vec![Instance::new(transform, [200, 200, 200]), Instance::new(vanished, [255, 0, 0])];
    let the_mesh_instances = 0..instances.len() as u32;
    Scene::new(vec![mesh], instances, vec![the_mesh_instances])
}

// ANCHOR: cases
/// Two parallel planes `H` apart, `L` wide, the camera between them: every point of either
/// plane at least `R` from an edge has visibility (H / R)², exactly.
pub fn parallel_planes(place: Placement) -> anyhow::Result<Case> {
    const L: f64 = 8.0;
    const H: f64 = 1.0;
    const R: f64 = 2.0;
    let (a, b) = (-L / 2.0, L / 2.0);
    let floor = [DVec3::new(a, 0.0, a), DVec3::new(a, 0.0, b), DVec3::new(b, 0.0, b), DVec3::new(b, 0.0, a)];
    let ceiling = floor.map(|c| c + DVec3::Y * H);
    let ceiling = [ceiling[0], ceiling[3], ceiling[2], ceiling[1]]; // facing down
    let scene = one_mesh_scene(quads(&[floor, ceiling], place), place, L, DVec3::new(0.5, H / 2.0, 0.0))?;
    let camera = camera(
        &scene,
        place,
        L,
        (DVec3::new(0.0, H / 2.0, 2.5), DVec3::new(0.0, H / 2.0, -2.0)),
        (0.05, 20.0),
    );
    let exact = move |p: DVec3| {
        let inside = p.x.abs() <= b - R && p.z.abs() <= b - R;
        inside.then(|| 1.0 - exact::between_planes(H, R))
    };
    Ok(Case::exact("parallel-planes", scene, camera, place, (L, R), exact))
}

/// A floor (y = 0, x >= 0) meeting a wall (x = 0) along the z axis, `L` wide: a floor point at
/// distance x from the wall has visibility 1 − S(x / R) / π, and a wall point at height y the same.
pub fn floor_and_wall(place: Placement) -> anyhow::Result<Case> {
    const L: f64 = 6.0;
    const R: f64 = 1.0;
    let (a, b) = (-L / 2.0, L / 2.0);
    let floor =
        [DVec3::new(0.0, 0.0, a), DVec3::new(0.0, 0.0, b), DVec3::new(L, 0.0, b), DVec3::new(L, 0.0, a)];
    let wall =
        [DVec3::new(0.0, 0.0, a), DVec3::new(0.0, L, a), DVec3::new(0.0, L, b), DVec3::new(0.0, 0.0, b)];
    let scene = one_mesh_scene(quads(&[floor, wall], place), place, L, DVec3::new(0.5, 0.5, 0.0))?;
    let camera =
        camera(&scene, place, L, (DVec3::new(3.2, 2.4, 1.6), DVec3::new(0.3, 0.3, -0.6)), (0.05, 20.0));
    let exact = move |p: DVec3| {
        // On the floor the height is (nearly) 0 and the distance to the wall is x; on the wall
        // the other way round. At the corner both formulas give 1/2.
        let (distance, across) = if p.y.abs() < p.x.abs() { (p.x, L - p.x) } else { (p.y, L - p.y) };
        let inside = across >= R && p.z.abs() <= b - R;
        inside.then(|| 1.0 - exact::beside_wall(distance.max(0.0), R))
    };
    Ok(Case::exact("floor-and-wall", scene, camera, place, (L, R), exact))
}
// ANCHOR_END: cases

/// The default scene (`instances` tetrahedra), framed as the chapters frame it, at their radius;
/// no exact answer: a long run of the same tracer is the reference.
pub fn default_scene_case(instances: u32, aspect: f32) -> Case {
    let scene = default_scene(instances, 1);
    let camera = Camera::framing(scene.bounds, aspect);
    let radius = 0.05 * scene.size();
    Case { name: "default-scene", scene, camera, radius, exact: None }
}

/// Half the scene's diagonal, for the ray offset (`AoRays::scene_scale`).
pub fn scene_scale(scene: &Scene) -> f32 {
    scene.size() / 2.0
}
