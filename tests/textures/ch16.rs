//! Chapter 16 (textured scenes), a package of its own so that the other chapters do not build
//! the image decoders: its tests are that package's (only they can name its binary), with the
//! harness, snapshots and reference images every chapter's tests use.

#[path = "../harness/mod.rs"]
mod harness;

use harness::{DEFAULT_TOLERANCE, Run, assert_images_match, assert_report_snapshot, run_chapter};
use std::path::{Path, PathBuf};

const BIN: &str = env!("CARGO_BIN_EXE_16-textures");

#[test]
fn ch16_default_scene() {
    let args = ["--size", "160x120", "--frames", "2", "--samples", "4", "--all-views"];
    let run = run_chapter(BIN, &args, &[]);
    let report = run.succeeded();
    assert_eq!(report["textures"], 4);
    // Every level of the chain, down to 1x1: 64x64 has 7, 37x23 has 6.
    let sizes = report["texture_sizes"].as_array().unwrap();
    assert!(
        sizes.iter().any(|s| s == "64x64 (7 levels)") && sizes.iter().any(|s| s == "37x23 (6 levels)"),
        "{sizes:?}"
    );
    assert_eq!(report["texture_levels_made_by"], "vkCmdBlitImage");
    assert_report_snapshot("16-textures", report);
    assert_images_match(report, DEFAULT_TOLERANCE);
}

/// A folder of files for one scene, removed with the test.
struct Files(tempfile::TempDir);

impl Files {
    fn new() -> Self {
        Files(tempfile::tempdir().unwrap())
    }
    fn path(&self, name: &str) -> PathBuf {
        self.0.path().join(name)
    }
    fn write(&self, name: &str, text: &str) -> PathBuf {
        let path = self.path(name);
        std::fs::write(&path, text).unwrap();
        path
    }
    /// A picture of `w` x `h` pixels, each `pixel(x, y)`, in the format the name's extension says.
    fn picture(&self, name: &str, (w, h): (u32, u32), pixel: impl Fn(u32, u32) -> [u8; 4]) -> PathBuf {
        let path = self.path(name);
        image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(pixel(x, y))).save(&path).unwrap();
        path
    }
}

/// A textured ground 10 wide, a post at one corner up to height 2 (so that every variant has the
/// same bounds, camera and radius), and, if `plane` names a material, a plane 6 wide at height
/// 0.3 over the ground's middle drawn with it (within the occlusion radius, 5% of the diagonal).
fn plane_scene(files: &Files, name: &str, plane: Option<&str>, materials: &str) -> PathBuf {
    files.picture("grey.png", (8, 8), |_, _| [170, 170, 170, 255]);
    files.write(&format!("{name}.mtl"), materials);
    let mut obj = format!("mtllib {name}.mtl\n");
    obj.push_str("v -5 0 -5\nv 5 0 -5\nv 5 0 5\nv -5 0 5\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n");
    obj.push_str("o ground\nusemtl ground\nf 1/1 3/3 2/2\nf 1/1 4/4 3/3\n");
    obj.push_str("v -5 0 -5\nv -4.8 0 -5\nv -5 2 -5\no post\nusemtl plain\nf 5 6 7\n");
    if let Some(material) = plane {
        obj.push_str("v -3 0.3 -3\nv 3 0.3 -3\nv 3 0.3 3\nv -3 0.3 3\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n");
        obj.push_str(&format!("o plane\nusemtl {material}\nf 8/5 10/7 9/6\nf 8/5 11/8 10/7\n"));
    }
    files.write(&format!("{name}.obj"), &obj)
}

const MATERIALS: &str = "newmtl ground\nKd 1 1 1\nmap_Kd grey.png\nnewmtl plain\nKd 0.8 0.8 0.8\n\
                         newmtl clear\nKd 1 1 1\nmap_Kd grey.png\nmap_d clear.png\n\
                         newmtl solid\nKd 1 1 1\nmap_Kd grey.png\nmap_d solid.png\n\
                         newmtl colour\nKd 1 1 1\nmap_Kd grey.png\n\
                         newmtl checker\nKd 1 1 1\nmap_Kd grey.png\nmap_d checker.png\n\
                         newmtl half\nKd 1 1 1\nmap_Kd grey.png\nmap_d half.png\n";

fn run_scene(scene: &Path, extra: &[&str]) -> Run {
    let mut args =
        vec!["--size", "96x72", "--frames", "2", "--all-views", "--scene", scene.to_str().unwrap()];
    args.extend_from_slice(extra);
    if !extra.contains(&"--samples") {
        args.extend(["--samples", "8"]);
    }
    run_chapter(BIN, &args, &[])
}

/// The bytes of each picture a run wrote, by view ("final" for the picture without a view's
/// name after the scene's).
fn pictures(run: &Run, scene: &str) -> Vec<(String, Vec<u8>)> {
    let report = run.succeeded();
    let prefix = format!("{}-{scene}", report["chapter"].as_str().unwrap());
    let mut pictures: Vec<(String, Vec<u8>)> = report["images"]
        .as_array()
        .unwrap()
        .iter()
        .map(|i| {
            let name = i["name"].as_str().unwrap();
            let view = name.strip_prefix(&prefix).unwrap_or(name).trim_start_matches('-');
            let view = if view.is_empty() { "final" } else { view };
            (view.to_owned(), image::open(i["path"].as_str().unwrap()).unwrap().to_rgba8().into_raw())
        })
        .collect();
    pictures.sort();
    pictures
}

/// A plane whose cut-out is fully transparent leaves every picture as if it were not there, byte
/// for byte: GL discards all of it, and every ray passes through it. A fully opaque cut-out
/// draws as the same plane without one: the any-hit shader runs and accepts every hit. A plane
/// open over one half: the ground GL shows through the hole gets exactly the occlusion it has
/// without the plane where the plane's solid half is out of the rays' reach (further than the
/// radius), and more occlusion (less visibility) where the solid half is within it.
#[test]
fn ch16_cut_outs_are_seen_through_by_gl_and_the_rays_alike() {
    let files = Files::new();
    files.picture("clear.png", (16, 16), |_, _| [0, 0, 0, 255]);
    files.picture("solid.png", (16, 16), |_, _| [255, 255, 255, 255]);
    files.picture("half.png", (64, 1), |x, _| if x < 32 { [0, 0, 0, 255] } else { [255; 4] });
    let raw = ["--power", "1", "--blur", "0", "--samples", "16"]; // the AO view is the visibility
    let without = run_scene(&plane_scene(&files, "without", None, MATERIALS), &raw);
    let clear = run_scene(&plane_scene(&files, "clear", Some("clear"), MATERIALS), &raw);
    let clear_pictures = pictures(&clear, "clear");
    assert_eq!(clear_pictures.len(), 6, "the final picture and five views");
    let without_pictures = pictures(&without, "without");
    assert!(clear_pictures == without_pictures, "a fully transparent plane changed a picture");

    let solid = run_scene(&plane_scene(&files, "solid", Some("solid"), MATERIALS), &raw);
    let colour = run_scene(&plane_scene(&files, "colour", Some("colour"), MATERIALS), &raw);
    assert!(pictures(&solid, "solid") == pictures(&colour, "colour"), "an opaque cut-out draws otherwise");
    assert!(pictures(&solid, "solid") != without_pictures, "the solid plane must show");

    let half = run_scene(&plane_scene(&files, "half", Some("half"), MATERIALS), &raw);
    let radius = half.succeeded()["radius"].as_f64().unwrap();
    let views: std::collections::BTreeMap<String, Vec<u8>> = pictures(&half, "half").into_iter().collect();
    let alone: std::collections::BTreeMap<String, Vec<u8>> = without_pictures.into_iter().collect();
    // Ground pixels under the plane's open half (x from -3 to 0), away from its edges: the
    // position view shows the world position over the scene's box (x and z -5 to 5, y 0 to 2).
    let (position, ao, ao_alone) = (&views["position"], &views["ao"], &alone["ao"]);
    let world = |c: u8| c as f64 / 255.0 * 10.0 - 5.0;
    let (mut far, mut near) = (Vec::new(), Vec::new());
    for i in 0..position.len() / 4 {
        let p = &position[4 * i..4 * i + 3];
        let (x, z) = (world(p[0]), world(p[2]));
        // 0.1: two steps of the position view's 8 bits, for the rounding.
        if p[1] != 0 || !(x > -3.0 + radius + 0.1 && x < -0.1 && z.abs() < 3.0 - radius - 0.1) {
            continue;
        }
        if x < -radius - 0.1 { far.push(i) } else { near.push(i) }
    }
    assert!(
        far.len() > 10 && near.len() > 10,
        "ground seen through the hole: {} far, {} near",
        far.len(),
        near.len()
    );
    let differing: Vec<_> = far.iter().filter(|&&i| ao[4 * i] != ao_alone[4 * i]).collect();
    assert!(
        differing.is_empty(),
        "out of the solid half's reach, {} of {} pixels differ",
        differing.len(),
        far.len()
    );
    let mean = |pixels: &[usize], ao: &[u8]| {
        pixels.iter().map(|&i| ao[4 * i] as f64).sum::<f64>() / pixels.len() as f64
    };
    let (with_plane, alone) = (mean(&near, ao), mean(&near, ao_alone));
    assert!(
        with_plane < alone,
        "within the solid half's reach: {with_plane:.1} against {alone:.1} without it"
    );
}

/// A textured scene without cut-outs marks nothing and traces with the plain tracer; one with a
/// cut-out marks it.
#[test]
fn ch16_only_cut_outs_pay_for_the_any_hit_shader() {
    let files = Files::new();
    let colour = run_scene(&plane_scene(&files, "colour", Some("colour"), MATERIALS), &[]);
    let report = colour.succeeded();
    assert_eq!(report["cut_outs"], 0, "{report}");
    files.picture(
        "checker.png",
        (16, 16),
        |x, y| if (x / 4 + y / 4) % 2 == 0 { [255; 4] } else { [0, 0, 0, 255] },
    );
    let checker = run_scene(&plane_scene(&files, "checker", Some("checker"), MATERIALS), &[]);
    assert_eq!(checker.succeeded()["cut_outs"], 1);
}

/// The rays see the cut-outs only through the any-hit shader. With `--opaque-rays` a checker
/// plane occludes like a solid one: wherever both runs see the same point (the position views
/// agree), its occlusion is the solid plane's, byte for byte. With the any-hit shader the same
/// checker lets rays through, and the ground beside it is less occluded.
#[test]
fn ch16_opaque_rays_shadow_cut_outs_as_solid_planes() {
    let files = Files::new();
    files.picture("solid.png", (16, 16), |_, _| [255, 255, 255, 255]);
    files.picture(
        "checker.png",
        (16, 16),
        |x, y| if (x / 4 + y / 4) % 2 == 0 { [255; 4] } else { [0, 0, 0, 255] },
    );
    let raw = ["--power", "1", "--blur", "0", "--samples", "16"]; // the AO view is the visibility
    let solid = pictures(&run_scene(&plane_scene(&files, "solid", Some("solid"), MATERIALS), &raw), "solid");
    let checker_scene = plane_scene(&files, "checker", Some("checker"), MATERIALS);
    let through = pictures(&run_scene(&checker_scene, &raw), "checker");
    let opaque = pictures(&run_scene(&checker_scene, &[&raw[..], &["--opaque-rays"]].concat()), "checker");
    let view = |pictures: &[(String, Vec<u8>)], name: &str| {
        pictures.iter().find(|(view, _)| view == name).map(|(_, bytes)| bytes.clone()).unwrap()
    };
    let (position, ao_solid) = (view(&solid, "position"), view(&solid, "ao"));
    let (ao_opaque, ao_through) = (view(&opaque, "ao"), view(&through, "ao"));
    assert!(view(&opaque, "position") == view(&through, "position"), "GL drew the checker otherwise");
    let same: Vec<usize> = (0..position.len() / 4)
        .filter(|&i| position[4 * i..4 * i + 4] == view(&opaque, "position")[4 * i..4 * i + 4])
        .collect();
    let differing = same.iter().filter(|&&i| ao_opaque[4 * i] != ao_solid[4 * i]).count();
    assert_eq!(differing, 0, "of {} points both runs see, {differing} are occluded otherwise", same.len());
    let lighter = same.iter().filter(|&&i| ao_through[4 * i] > ao_solid[4 * i]).count();
    let darker = same.iter().filter(|&&i| ao_through[4 * i] < ao_solid[4 * i]).count();
    assert!(lighter > 10 && darker == 0, "through the cut-out: {lighter} points lighter, {darker} darker");
}

/// `--untextured` forgets the pictures: no texture made, no cut-out marked, the albedo each
/// material's plain colour; and every check still passes.
#[test]
fn ch16_untextured_draws_the_plain_colours() {
    let args = ["--size", "96x72", "--frames", "2", "--samples", "4", "--all-views"];
    let textured = run_chapter(BIN, &args, &[]);
    let plain = run_chapter(BIN, &[&args[..], &["--untextured"]].concat(), &[]);
    let report = plain.succeeded();
    assert_eq!((report["textures"].as_u64(), report["cut_outs"].as_u64()), (Some(0), Some(0)), "{report}");
    assert!(report.get("texture_mb_per_s").is_none(), "{report}");
    let albedo = |run: &Run| pictures(run, "").into_iter().find(|(v, _)| v.ends_with("albedo")).unwrap().1;
    assert!(albedo(&plain) != albedo(&textured), "the albedo view kept its pictures");
}

/// A scene with no picture draws what chapter 08 draws, view for view (08's final picture adds
/// its overlays, which this chapter does not draw): no texture, sampler or any-hit group made.
#[test]
fn ch16_a_scene_without_pictures_draws_what_chapter_08_draws() {
    let Some(ch08) = sibling("08-composite") else {
        return harness::skip(
            "ch16_a_scene_without_pictures_draws_what_chapter_08_draws",
            "08-composite is not built",
        );
    };
    let bunny = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/bunny.obj");
    let args = ["--size", "96x72", "--frames", "2", "--samples", "8", "--all-views", "--scene", bunny];
    let ours = run_chapter(BIN, &args, &[]);
    let theirs = run_chapter(ch08.to_str().unwrap(), &args, &[]);
    assert_eq!(ours.succeeded()["textures"], 0);
    let views = |run: &Run| {
        pictures(run, "bunny").into_iter().filter(|(view, _)| view != "final").collect::<Vec<_>>()
    };
    let (a, b) = (views(&ours), views(&theirs));
    assert_eq!(a.len(), 5, "five debug views");
    for ((view, ours), (_, theirs)) in a.iter().zip(&b) {
        assert!(ours == theirs, "the {view} view differs from chapter 08's");
    }
}

/// Another binary of the workspace's build, beside this package's.
fn sibling(name: &str) -> Option<PathBuf> {
    let path = Path::new(BIN).with_file_name(name);
    path.exists().then_some(path)
}

/// Pictures of every kind exporters write all arrive as the format the chapter shares (grey,
/// 16-bit, palette and RGB PNGs, JPEG, TGA); the broken ones are a warning naming the file and
/// the problem, and the material's plain colour. Paths written with backslashes or with spaces
/// are found.
#[test]
fn ch16_reads_every_kind_of_picture_and_names_the_broken_ones() {
    let files = Files::new();
    let rgba = |x: u32, y: u32| [(x * 40) as u8, (y * 40) as u8, 128, 255];
    image::GrayImage::from_fn(5, 3, |x, _| image::Luma([x as u8 * 50])).save(files.path("grey.png")).unwrap();
    image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(4, 4, |x, _| image::Rgb([x as u16 * 16000, 0, 65535]))
        .save(files.path("deep.png"))
        .unwrap();
    image::RgbImage::from_fn(6, 6, |x, y| image::Rgb([x as u8 * 40, y as u8 * 40, 0]))
        .save(files.path("photo.jpg"))
        .unwrap();
    files.picture("old.tga", (3, 7), rgba);
    std::fs::create_dir_all(files.path("sub folder")).unwrap();
    files.picture("sub folder/spaced name.png", (2, 2), rgba);
    // A palette PNG, written by hand: 2x1, two palette entries.
    std::fs::write(files.path("palette.png"), palette_png()).unwrap();
    files.write("corrupt.png", "\u{89}PNG\r\n\u{1a}\nnot a picture at all");
    let truncated = std::fs::read(files.picture("whole.png", (16, 16), rgba)).unwrap();
    std::fs::write(files.path("truncated.png"), &truncated[..truncated.len() / 2]).unwrap();
    std::fs::create_dir_all(files.path("a folder.png")).unwrap();
    let good = ["grey.png", "deep.png", "photo.jpg", "old.tga", "sub folder\\spaced name.png", "palette.png"];
    let bad = ["missing.png", "corrupt.png", "truncated.png", "a folder.png"];
    let mut mtl = String::new();
    let mut obj = String::from("mtllib kinds.mtl\n");
    for (i, map) in good.iter().chain(&bad).enumerate() {
        mtl.push_str(&format!("newmtl m{i}\nKd 1 1 1\nmap_Kd {map}\n"));
        let x = i as f32 * 1.5;
        obj.push_str(&format!("v {x} 0 0\nv {} 0 0\nv {x} 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n", x + 1.0));
        let v = 3 * i + 1;
        obj.push_str(&format!("o q{i}\nusemtl m{i}\nf {v}/{v} {}/{} {}/{}\n", v + 1, v + 1, v + 2, v + 2));
    }
    files.write("kinds.mtl", &mtl);
    let run = run_scene(&files.write("kinds.obj", &obj), &[]);
    let report = run.succeeded();
    // The good ones, and the white texel of the materials left plain.
    assert_eq!(report["textures"], good.len() + 1, "{}", run.stderr);
    for (name, problem) in [
        ("missing.png", "cannot open it"),
        ("corrupt.png", "not a picture this chapter reads"),
        ("truncated.png", "not a picture this chapter reads"),
        ("a folder.png", "is a directory"),
    ] {
        let warned = run
            .stderr
            .lines()
            .any(|l| l.contains(name) && l.contains(problem) && l.contains("using its plain colour"));
        assert!(warned, "no warning for {name} ({problem}):\n{}", run.stderr);
    }
    assert!(!run.stderr.contains("panicked"), "{}", run.stderr);
}

/// A 2x1 palette PNG (colour type 3), chunk by chunk.
fn palette_png() -> Vec<u8> {
    let mut encoder_out = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut encoder_out, 2, 1);
        encoder.set_color(png::ColorType::Indexed);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_palette(vec![255, 0, 0, 0, 0, 255]);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[0, 1]).unwrap();
    }
    encoder_out
}

/// Texture sizes from 1x1 to past the device's largest: each drawn with its whole chain and
/// checked level for level; the one past the largest halved until it fits, and said so.
#[test]
fn ch16_texture_sizes_from_one_texel_to_past_the_largest() {
    let files = Files::new();
    let largest = 16384; // lavapipe's and llvmpipe's largest side (Vulkan and GL alike)
    let sizes = [(1, 1), (3, 1), (37, 23), (4096, 1), (largest + 1, 1)];
    let mut mtl = String::new();
    let mut obj = String::from("mtllib sizes.mtl\n");
    for (i, &(w, h)) in sizes.iter().enumerate() {
        files.picture(&format!("p{i}.png"), (w, h), |x, y| [(x % 256) as u8, (y % 256) as u8, 200, 255]);
        mtl.push_str(&format!("newmtl m{i}\nmap_Kd p{i}.png\n"));
        let x = i as f32 * 1.5;
        obj.push_str(&format!("v {x} 0 0\nv {} 0 0\nv {x} 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n", x + 1.0));
        let v = 3 * i + 1;
        obj.push_str(&format!("o q{i}\nusemtl m{i}\nf {v}/{v} {}/{} {}/{}\n", v + 1, v + 1, v + 2, v + 2));
    }
    files.write("sizes.mtl", &mtl);
    let run = run_scene(&files.write("sizes.obj", &obj), &[]);
    let report = run.succeeded();
    let listed: Vec<&str> =
        report["texture_sizes"].as_array().unwrap().iter().map(|s| s.as_str().unwrap()).collect();
    assert_eq!(
        listed,
        ["1x1 (1 levels)", "3x1 (2 levels)", "37x23 (6 levels)", "4096x1 (13 levels)", "8192x1 (14 levels)"]
    );
    assert!(
        run.stderr.contains(&format!("p4.png is {}x1, larger than the {largest}", largest + 1)),
        "{}",
        run.stderr
    );
}

/// Where the format cannot be blitted, the levels are made on the CPU, and said so: GL still
/// reads Vulkan's chain level for level, and the picture is the same within tolerance.
#[test]
fn ch16_levels_made_on_the_cpu_where_blits_are_missing() {
    let args = ["--size", "160x120", "--frames", "2", "--samples", "4"];
    let run = run_chapter(BIN, &args, &[("VKGL_HIDE_FEATURES", "blit")]);
    let report = run.succeeded();
    assert_eq!(report["texture_levels_made_by"], "the CPU");
    assert!(run.stderr.contains("the levels are made on the CPU"), "{}", run.stderr);
    assert_images_match(report, DEFAULT_TOLERANCE);
}

/// A device without the descriptor-array features is skipped, the skip naming both, and the run
/// refused naming the device (exit 2, no panic).
#[test]
fn ch16_missing_texture_array_features_are_named() {
    let hide = "runtimeDescriptorArray,shaderSampledImageArrayNonUniformIndexing";
    let run = run_chapter(BIN, &["--size", "32x24", "--frames", "1"], &[("VKGL_HIDE_FEATURES", hide)]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(
        run.stderr.contains("lacks the Vulkan 1.2 feature runtimeDescriptorArray and shaderSampledImageArrayNonUniformIndexing"),
        "{}",
        run.stderr
    );
    assert!(!run.stderr.contains("panicked"), "{}", run.stderr);
}

/// 300 materials, each its own picture: one draw per mesh in GL, one array of 301 textures for
/// the rays (every one a cut-out), drawn and checked on lavapipe.
#[test]
fn ch16_three_hundred_materials() {
    let files = Files::new();
    let (mut mtl, mut obj) = (String::new(), String::from("mtllib many.mtl\n"));
    for i in 0..300u32 {
        files.picture(&format!("p{i}.png"), (4, 4), |x, y| {
            [(i % 256) as u8, (x * 60) as u8, (y * 60) as u8, if x == 0 { 0 } else { 255 }]
        });
        mtl.push_str(&format!("newmtl m{i}\nmap_Kd p{i}.png\n"));
        let (x, z) = ((i % 20) as f32, (i / 20) as f32);
        obj.push_str(&format!(
            "v {x} 0 {z}\nv {} 0 {z}\nv {x} 0 {}\nvt 0 0\nvt 1 0\nvt 0 1\n",
            x + 0.9,
            z + 0.9
        ));
        let v = 3 * i + 1;
        obj.push_str(&format!("o q{i}\nusemtl m{i}\nf {v}/{v} {}/{} {}/{}\n", v + 2, v + 2, v + 1, v + 1));
    }
    files.write("many.mtl", &mtl);
    let run = run_scene(&files.write("many.obj", &obj), &[]);
    let report = run.succeeded();
    assert_eq!(report["textures"], 300);
    assert_eq!(report["cut_outs"], 300);
}

/// Every shared image made anew at another size, over and over: nothing grows (fds, counted
/// resources, GL's objects), the textures are not remade.
#[test]
fn ch16_resizes_leave_nothing_behind() {
    let args = ["--size", "64x48", "--frames", "9", "--samples", "1", "--resize-every", "2"];
    let run = run_chapter(BIN, &args, &[]);
    let report = run.succeeded();
    assert_eq!(report["resizes"], 4);
}

/// A thousand resizes: what exists after the first exists after every later one (fds, counted
/// resources, GL's objects: `ResizeCensus`), so nothing grows.
#[test]
fn ch16_soak_1000_resizes() {
    let args = ["--size", "16x12", "--frames", "1001", "--samples", "1", "--resize-every", "1"];
    let report = run_chapter(BIN, &args, &[]).succeeded().clone();
    assert_eq!(report["resizes"], 1000);
    assert_eq!(report["checks"]["nothing_grows_across_resizes"], true, "{report}");
}

/// In a window (Xvfb): the frames drawn live, the same checks passing.
#[test]
fn ch16_draws_in_a_window_under_xvfb() {
    let Some(xvfb) = harness::Xvfb::start("ch16_draws_in_a_window_under_xvfb") else { return };
    let args = ["--size", "160x120", "--frames", "3", "--samples", "2"];
    let run = harness::run_chapter_with(BIN, &args, &[("DISPLAY", &xvfb.display)]);
    drop(xvfb);
    let report = run.succeeded();
    assert_eq!(report["window"], true, "{}", run.stderr);
    assert_eq!(report["frames"], 3);
    assert_eq!(report["checks"]["texture_levels_match_vulkan"], true);
}

/// Chapter 16 at every size the other chapters are walked through (`harness::sizes`).
#[test]
fn sizes_16() {
    harness::sizes::walk_sizes(
        "16-textures",
        BIN,
        &["--frames", "2", "--samples", "2"],
        "maxImageDimension2D 16384",
    );
}

/// Every numeric flag, offered what no flag means (`harness::flags`).
#[test]
fn ch16_every_numeric_flag_refuses_what_it_cannot_mean() {
    let table = harness::flags::numeric_flags_refuse_what_they_cannot_mean(&[BIN]);
    insta::with_settings!({
        snapshot_path => "../snapshots/flags",
        prepend_module_to_snapshot => false,
        omit_expression => true,
    }, {
        insta::assert_snapshot!("numeric-flags-16", table);
    });
}

/// Each fallible step, failed the first and the last time a run reaches it: exit 2 naming the
/// step, no panic, no validation message, nothing left alive, no fd left open beyond those a run
/// that fails nothing leaves (the driver's).
#[test]
fn ch16_every_fallible_step_fails_cleanly() {
    let args = ["--size", "32x24", "--frames", "3", "--samples", "1", "--resize-every", "2"];
    harness::every_fallible_step_fails_cleanly(BIN, &args, Some("a texture"));
}
