//! The workshop kit keeps its promises: every worked solution (`book/src/workshop/*.diff`) applies
//! to a copy of the repository, builds, and runs headless on the software stack with all of its
//! chapter's checks passing and with what the patch adds visible in the run (and not in the
//! chapter as it is, run with the same flags); every chapter in the kit's time table has a
//! challenge; every chapter page ends with the sections the kit tells teachers to expect.
//!
//! The solutions are built once, all patches in one copy where none touches what another does,
//! into this test's own target directory: the registry dependencies the tests were built with
//! are reused, and only the workspace's crates (`common`, the chapters) compile again. The copy's
//! binaries are renamed `workshop-NN-slug`, so that they never replace the chapters the other
//! tests run. The copy lives at one fixed path under `CARGO_TARGET_TMPDIR`, for every group of
//! patches in turn, and is rewritten only where its files change: a second run builds nothing
//! that has not changed.

mod harness;

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// A worked solution, and how to see it at work in a headless run on the software stack.
struct Solution {
    patch: &'static str,
    chapter: &'static str,
    /// After `--json --out DIR`: small sizes and few rays, so that lavapipe is quick.
    args: &'static [&'static str],
    proof: Proof,
}

/// What shows that the run was the patched chapter's: the patched run must show it, the chapter
/// as it is must not.
enum Proof {
    /// A check only the patched chapter makes: it must be in the report, and pass.
    Check(&'static str),
    /// A report field only the patched chapter writes.
    Field(&'static str),
    /// A flag only the patched chapter takes (clap refuses an unknown flag with exit code 2); the
    /// run passes it.
    Flag(&'static str),
    /// An image only the patched chapter writes (the report's `images[].name`).
    Image(&'static str),
    /// Nothing a headless run can show, and why; the run still proves it builds and passes.
    Unseen(&'static str),
}

const SOLUTIONS: &[Solution] = &[
    Solution {
        patch: "01-second-export.diff",
        chapter: "01-exportable-memory",
        args: &["--headless"],
        proof: Proof::Check("second_export_is_a_new_fd"),
    },
    Solution {
        patch: "02-second-import.diff",
        chapter: "02-gl-buffer-import",
        args: &["--headless", "--size", "64x48"],
        proof: Proof::Check("second_import_writes_the_same_memory"),
    },
    Solution {
        patch: "03-square-size.diff",
        chapter: "03-semaphores",
        args: &["--headless", "--size", "16x16", "--square", "1", "--frames", "8"],
        proof: Proof::Flag("--square"),
    },
    Solution {
        patch: "04-pause.diff",
        chapter: "04-compute-triangle",
        args: &["--headless", "--size", "160x120", "--time", "0", "--frames", "4"],
        proof: Proof::Unseen("Space pauses a window's animation; headless runs take their time from --time"),
    },
    Solution {
        patch: "05-depth-view.diff",
        chapter: "05-g-buffers",
        args: &["--headless", "--size", "96x72"],
        proof: Proof::Image("05-g-buffers-depth"),
    },
    Solution {
        patch: "06-silhouette.diff",
        chapter: "06-blas-tlas",
        args: &["--headless", "--size", "96x64"],
        proof: Proof::Field("silhouette_pixels"),
    },
    Solution {
        patch: "07-histogram.diff",
        chapter: "07-ao-ray-pipeline",
        args: &["--headless", "--size", "96x72", "--samples", "8", "--frames", "2"],
        proof: Proof::Field("visibility_histogram"),
    },
    Solution {
        patch: "08-depth-tolerance.diff",
        chapter: "08-composite",
        args: &[
            "--headless",
            "--size",
            "96x72",
            "--frames",
            "2",
            "--samples",
            "4",
            "--depth-tolerance",
            "0.002",
        ],
        proof: Proof::Flag("--depth-tolerance"),
    },
    Solution {
        patch: "09-hop.diff",
        chapter: "09-animated-instances",
        args: &["--headless", "--size", "96x72", "--frames", "3", "--samples", "4", "--hop", "0.6"],
        proof: Proof::Flag("--hop"),
    },
    Solution {
        patch: "10-gl-readback.diff",
        chapter: "10-vertex-animation",
        args: &["--headless", "--size", "96x72", "--frames", "3", "--samples", "4", "--rings", "32"],
        proof: Proof::Check("gl_sees_the_moved_vertices"),
    },
    Solution {
        // CUDA where it can run; elsewhere (CI, lavapipe) the chapter's CPU tracer, which feeds
        // the same two paths into the GL code the patch changes.
        patch: "11-hidden-lines.diff",
        chapter: "11-cuda-depth-composite",
        args: &["--headless", "--size", "96x72", "--hidden-alpha", "0.4"],
        proof: Proof::Flag("--hidden-alpha"),
    },
    Solution {
        patch: "12-which-triangle.diff",
        chapter: "12-fast-frame",
        args: &["--headless", "--size", "96x72", "--frames", "2", "--samples", "4"],
        proof: Proof::Check("decoded_triangles_cover_their_pixels"),
    },
    Solution {
        patch: "13-history-age.diff",
        chapter: "13-temporal-reuse",
        args: &["--headless", "--size", "96x72", "--frames", "8", "--cut-at", "4", "--instances", "400"],
        proof: Proof::Check("history_holds_no_more_rays_than_were_traced"),
    },
    Solution {
        // Two processes: the viewer's check comes back in the renderer's report, renamed.
        patch: "14-skipped-frame.diff",
        chapter: "14-two-processes",
        args: &["--headless", "--size", "64x48", "--frames", "8"],
        proof: Proof::Check("viewer_frames_follow_one_another"),
    },
    Solution {
        // A package of its own (wgpu): built with `-p chapter-15-wgpu`.
        patch: "15-edge-count.diff",
        chapter: "15-wgpu",
        args: &["--headless", "--size", "64x48", "--frames", "2"],
        proof: Proof::Check("wgpu_counted_the_edges"),
    },
    Solution {
        // A package of its own (the picture decoders): built with `-p chapter-16-textures`.
        patch: "16-cutoff.diff",
        chapter: "16-textures",
        args: &["--headless", "--size", "64x48", "--frames", "2", "--samples", "2", "--cutoff", "0.9"],
        proof: Proof::Flag("--cutoff"),
    },
];

/// The chapters that are packages of their own, with the package's name: the rest are the root
/// package's binaries.
const OWN_PACKAGES: &[(&str, &str)] =
    &[("15-wgpu", "chapter-15-wgpu"), ("16-textures", "chapter-16-textures")];

/// The package whose binary `chapter` is.
fn package_of(chapter: &str) -> &'static str {
    OWN_PACKAGES.iter().find(|(c, _)| *c == chapter).map_or("vkgl-interop", |(_, package)| package)
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn workshop_dir() -> PathBuf {
    root().join("book/src/workshop")
}

/// The files a patch changes, from its `--- a/...` and `+++ b/...` lines.
fn touched_files(diff: &str) -> BTreeSet<String> {
    diff.lines()
        .filter_map(|l| l.strip_prefix("--- a/").or_else(|| l.strip_prefix("+++ b/")))
        .map(|path| path.trim_end().to_owned())
        .collect()
}

/// `NN-slug` when every file is under `chapters/NN-slug/`.
fn chapter_of(files: &BTreeSet<String>) -> Option<String> {
    let folders: BTreeSet<&str> = files
        .iter()
        .map(|f| f.strip_prefix("chapters/").and_then(|f| f.split('/').next()).unwrap_or(""))
        .collect();
    match folders.into_iter().collect::<Vec<_>>()[..] {
        [folder] if !folder.is_empty() => Some(folder.to_owned()),
        _ => None,
    }
}

/// Is `file` part of a chapter's library (chapters 12 and 13: a module its `lib.rs` declares), which
/// other chapters and the tools build on?
fn in_a_chapter_library(file: &str) -> bool {
    let path = Path::new(file);
    let (Some(folder), Some(stem)) = (path.parent(), path.file_stem().and_then(|s| s.to_str())) else {
        return false;
    };
    let Ok(lib) = std::fs::read_to_string(root().join(folder).join("lib.rs")) else { return false };
    stem == "lib" || lib.lines().any(|l| l.trim().trim_start_matches("pub ") == format!("mod {stem};"))
}

/// Groups patches (by index) into copies of the repository: none in a group touches a file
/// another in it touches, and a patch that changes anything outside one chapter's folder
/// (`common/`, `shaders/`) or a chapter's library gets a copy of its own, since it would change
/// the others' chapters.
fn batches(touched: &[BTreeSet<String>]) -> Vec<Vec<usize>> {
    struct Batch {
        members: Vec<usize>,
        files: BTreeSet<String>,
        alone: bool,
    }
    let mut batches: Vec<Batch> = Vec::new();
    for (i, files) in touched.iter().enumerate() {
        let alone = chapter_of(files).is_none() || files.iter().any(|f| in_a_chapter_library(f));
        match batches.iter_mut().find(|b| !alone && !b.alone && b.files.is_disjoint(files)) {
            Some(batch) => {
                batch.members.push(i);
                batch.files.extend(files.iter().cloned());
            }
            None => batches.push(Batch { members: vec![i], files: files.clone(), alone }),
        }
    }
    batches.into_iter().map(|b| b.members).collect()
}

#[test]
fn patches_that_touch_the_same_file_or_common_code_get_copies_of_their_own() {
    let set = |files: &[&str]| files.iter().map(|f| f.to_string()).collect::<BTreeSet<_>>();
    let touched = [
        set(&["chapters/01-a/main.rs"]),
        set(&["chapters/02-b/main.rs", "chapters/02-b/x.rs"]),
        set(&["chapters/01-a/main.rs"]),
        set(&["common/src/lib.rs", "chapters/03-c/main.rs"]),
        set(&["chapters/03-c/main.rs"]),
    ];
    assert_eq!(batches(&touched), [vec![0, 1, 4], vec![2], vec![3]]);
    let diff = "diff --git a/chapters/09-x/ring.rs b/chapters/09-x/ring.rs\n--- a/chapters/09-x/ring.rs\n+++ b/chapters/09-x/ring.rs\n@@ -1 +1 @@\n-a\n+b\n";
    assert_eq!(touched_files(diff), set(&["chapters/09-x/ring.rs"]));
    assert_eq!(chapter_of(&touched_files(diff)).as_deref(), Some("09-x"));
    // Chapter 12's library, which chapter 13 and the tools build on, gets a copy of its own; a
    // module only its program declares (a workshop's new file) does not.
    let library = [
        set(&["chapters/12-fast-frame/trace.rs"]),
        set(&["chapters/12-fast-frame/main.rs", "chapters/12-fast-frame/decode.rs"]),
        set(&["chapters/13-temporal-reuse/main.rs"]),
    ];
    assert_eq!(batches(&library), [vec![0], vec![1, 2]]);
}

/// The repository's files as they are on disk (tracked, and untracked but not ignored), copied to
/// `dest`; symbolic links stay links.
fn copy_working_tree(dest: &Path) {
    let listed = Command::new("git")
        .current_dir(root())
        .args(["ls-files", "-z", "--cached", "--others", "--exclude-standard"])
        .output()
        .unwrap_or_else(|e| panic!("cannot run git ({e}): the workshop test copies the repository with it"));
    assert!(listed.status.success(), "git ls-files: {}", String::from_utf8_lossy(&listed.stderr));
    for name in listed.stdout.split(|&b| b == 0).filter(|n| !n.is_empty()) {
        let name = std::str::from_utf8(name).expect("file names are UTF-8");
        let (from, to) = (root().join(name), dest.join(name));
        let Ok(meta) = std::fs::symlink_metadata(&from) else { continue }; // deleted, not committed
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        if meta.file_type().is_symlink() {
            std::os::unix::fs::symlink(std::fs::read_link(&from).unwrap(), &to).unwrap();
        } else if meta.is_file() {
            std::fs::copy(&from, &to).unwrap_or_else(|e| panic!("copying {name}: {e}"));
        }
    }
}

/// Every `[[bin]]` renamed `workshop-<name>`: built into the tests' target directory, the copy's
/// binaries must not replace the chapters that other tests run.
fn rename_bins(manifest: &str) -> String {
    let mut out = String::new();
    let mut in_bin = false;
    for line in manifest.lines() {
        if line.starts_with('[') {
            in_bin = line.trim() == "[[bin]]";
        }
        match line.strip_prefix("name = \"") {
            Some(rest) if in_bin => out.push_str(&format!("name = \"workshop-{rest}")),
            _ => out.push_str(line),
        }
        out.push('\n');
    }
    out
}

/// Makes `dest` hold exactly the files of `source` (its `.git` aside), writing only those whose
/// bytes differ: what did not change keeps its time stamp, and cargo does not rebuild it.
fn sync(source: &Path, dest: &Path) {
    fn walk(dir: &Path, base: &Path, found: &mut BTreeSet<PathBuf>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let path = entry.path();
            let relative = path.strip_prefix(base).unwrap().to_owned();
            if relative == Path::new(".git") {
                continue;
            }
            let kind = entry.file_type().unwrap();
            if kind.is_dir() {
                walk(&path, base, found);
            } else {
                found.insert(relative);
            }
        }
    }
    let (mut wanted, mut present) = (BTreeSet::new(), BTreeSet::new());
    walk(source, source, &mut wanted);
    walk(dest, dest, &mut present);
    for stale in present.difference(&wanted) {
        std::fs::remove_file(dest.join(stale)).unwrap();
    }
    for file in &wanted {
        let (from, to) = (source.join(file), dest.join(file));
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        if std::fs::symlink_metadata(&from).unwrap().file_type().is_symlink() {
            let target = std::fs::read_link(&from).unwrap();
            if std::fs::read_link(&to).ok() != Some(target.clone()) {
                let _ = std::fs::remove_file(&to);
                std::os::unix::fs::symlink(target, &to).unwrap();
            }
        } else {
            let bytes = std::fs::read(&from).unwrap();
            if std::fs::symlink_metadata(&to).is_ok_and(|m| m.file_type().is_symlink()) {
                std::fs::remove_file(&to).unwrap();
            }
            if std::fs::read(&to).ok().as_ref() != Some(&bytes) {
                std::fs::write(&to, &bytes).unwrap();
            }
        }
    }
}

/// The tests' own target directory and profile, from where this test binary was built:
/// `<target>/<profile dir>/deps/workshop-<hash>`, or `<target>/<triple>/<profile dir>/deps/...`.
/// Returns the target directory, the profile's name, the flags that choose it, and where its
/// binaries land.
fn target_and_profile() -> (PathBuf, String, Vec<String>, PathBuf) {
    let target =
        Path::new(env!("CARGO_TARGET_TMPDIR")).parent().expect("CARGO_TARGET_TMPDIR is <target>/tmp");
    let exe = std::env::current_exe().unwrap();
    let relative: Vec<String> = exe
        .strip_prefix(target)
        .unwrap_or_else(|_| panic!("{} is not under {}", exe.display(), target.display()))
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let (triple, profile_dir) = match &relative[..] {
        [profile, deps, _] if deps == "deps" => (None, profile.clone()),
        [triple, profile, deps, _] if deps == "deps" => (Some(triple.clone()), profile.clone()),
        other => panic!("unexpected test binary path {other:?}"),
    };
    let profile = match profile_dir.as_str() {
        "debug" => "dev".to_owned(),
        other => other.to_owned(),
    };
    let mut flags = vec!["--profile".to_owned(), profile.clone()];
    let mut out = target.to_owned();
    if let Some(triple) = triple {
        flags.extend(["--target".to_owned(), triple.clone()]);
        out.push(triple);
    }
    out.push(profile_dir);
    (target.to_owned(), profile, flags, out)
}

impl Proof {
    fn describe(&self) -> String {
        match self {
            Proof::Check(name) => format!("the check `{name}`, passing"),
            Proof::Field(name) => format!("the report's field `{name}`"),
            Proof::Flag(flag) => format!("the flag {flag}, accepted"),
            Proof::Image(name) => format!("the image `{name}`"),
            Proof::Unseen(why) => format!("nothing ({why})"),
        }
    }
}

/// Whether `run` shows what the patch adds. The chapter as it is must not: the test runs it too,
/// so that a proof that shows nothing fails.
fn proof_holds(proof: &Proof, run: &harness::Run) -> bool {
    let report = run.report.as_ref();
    match *proof {
        Proof::Check(name) => report.is_some_and(|r| r["checks"][name] == true),
        Proof::Field(name) => report.is_some_and(|r| r.get(name).is_some()),
        // clap refuses an unknown flag with exit code 2 and no report.
        Proof::Flag(_) => run.output.status.code() != Some(2) || report.is_some(),
        Proof::Image(name) => report
            .and_then(|r| r["images"].as_array())
            .is_some_and(|images| images.iter().any(|i| i["name"] == name)),
        Proof::Unseen(_) => true,
    }
}

/// Why a solution's run does not count, or `None` when it passed and showed what the patch adds.
fn judge(solution: &Solution, run: &harness::Run) -> Option<String> {
    let status = run.output.status;
    let Some(report) = &run.report else {
        return Some(format!("exited with {status} and printed no report"));
    };
    let mut problems = Vec::new();
    if !status.success() {
        problems.push(format!("exited with {status}"));
    }
    let checks = report["checks"].as_object().cloned().unwrap_or_default();
    if checks.is_empty() {
        problems.push("the report has no checks".to_owned());
    }
    let failed: Vec<&String> =
        checks.iter().filter(|(_, ok)| **ok != Value::Bool(true)).map(|(n, _)| n).collect();
    if !failed.is_empty() {
        problems.push(format!("checks failed: {failed:?}"));
    }
    if report["validation"]["errors"] != 0 {
        problems.push(format!("validation errors: {}", report["validation"]["errors"]));
    }
    if std::env::var_os("CI").is_some() && report["validation"]["layer"] != true {
        problems.push("CI must run with VK_LAYER_KHRONOS_validation".to_owned());
    }
    if !proof_holds(&solution.proof, run) {
        problems.push(format!("the run does not show what the patch adds: {}", solution.proof.describe()));
    }
    (!problems.is_empty()).then(|| problems.join("; "))
}

#[test]
fn every_workshop_solution_builds_and_passes_its_chapters_checks() {
    let started = Instant::now();
    // The table and the folder agree: a new patch needs a row (how to run it), a row a patch.
    let on_disk: BTreeSet<String> = std::fs::read_dir(workshop_dir())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".diff"))
        .collect();
    let listed: BTreeSet<String> = SOLUTIONS.iter().map(|s| s.patch.to_owned()).collect();
    assert_eq!(
        on_disk, listed,
        "book/src/workshop/*.diff and this test's SOLUTIONS must name the same patches"
    );
    let mut touched = Vec::new();
    for solution in SOLUTIONS {
        let diff = std::fs::read_to_string(workshop_dir().join(solution.patch)).unwrap();
        let files = touched_files(&diff);
        assert_eq!(
            chapter_of(&files).as_deref().unwrap_or(solution.chapter),
            solution.chapter,
            "{} changes {files:?}, not chapter {}",
            solution.patch,
            solution.chapter
        );
        if let Proof::Flag(flag) = solution.proof {
            assert!(solution.args.contains(&flag), "{}: the run must pass {flag}", solution.patch);
        }
        touched.push(files);
    }

    let (target, profile, profile_flags, bin_dir) = target_and_profile();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut failures = Vec::new();
    let mut timings = Vec::new();
    for (number, members) in batches(&touched).iter().enumerate() {
        // 1. A copy of the working tree with the patches applied, staged in a temporary
        //    directory, then synchronised into the copy cargo builds.
        let phase = Instant::now();
        let stage = tempfile::tempdir().unwrap();
        copy_working_tree(stage.path());
        // Its own repository, so that `git apply` patches it even when the temporary directory
        // lies inside another repository.
        let init = Command::new("git").current_dir(stage.path()).args(["init", "-q"]).status().unwrap();
        assert!(init.success(), "git init in {}", stage.path().display());
        for &i in members {
            let applied = Command::new("git")
                .current_dir(stage.path())
                .arg("apply")
                .arg(workshop_dir().join(SOLUTIONS[i].patch))
                .output()
                .unwrap();
            assert!(
                applied.status.success(),
                "{} (chapter {}) does not apply: {}",
                SOLUTIONS[i].patch,
                SOLUTIONS[i].chapter,
                String::from_utf8_lossy(&applied.stderr)
            );
        }
        let own = OWN_PACKAGES.iter().map(|(chapter, _)| format!("chapters/{chapter}/Cargo.toml"));
        for manifest in std::iter::once("Cargo.toml".to_owned()).chain(own) {
            let manifest = stage.path().join(manifest);
            std::fs::write(&manifest, rename_bins(&std::fs::read_to_string(&manifest).unwrap())).unwrap();
        }
        // One path for every group: cargo names a workspace crate's artifacts by its place in its
        // workspace, the same in every copy, and records the sources it read by their paths. A
        // second path would find the first one's artifacts, judged by the first one's files.
        let copy = Path::new(env!("CARGO_TARGET_TMPDIR")).join("workshop-solutions");
        std::fs::create_dir_all(&copy).unwrap();
        sync(stage.path(), &copy);
        drop(stage);
        timings.push(format!("copy {number}: {:.1} s", phase.elapsed().as_secs_f64()));

        // 2. Build the patched chapters, once, into the tests' target directory.
        let phase = Instant::now();
        let build = |chapters: &[&str]| {
            let mut build = Command::new(&cargo);
            build.args(["build", "--locked", "--offline", "--manifest-path"]).arg(copy.join("Cargo.toml"));
            build.args(&profile_flags).env("CARGO_TARGET_DIR", &target);
            // Without debug information: a debug chapter links to about 185 MB with it, 10 without,
            // and what it does is the same. Only these packages change; the dependencies are the
            // tests' own, reused as built. It also keeps the copy's `common` apart from the tests'
            // own, which has the same name and place in its workspace (so, with the same profile,
            // the same artifacts).
            let packages: BTreeSet<&str> = chapters.iter().map(|c| package_of(c)).collect();
            for package in packages.iter().chain(&["common"]) {
                build.arg("--config").arg(format!("profile.{profile}.package.{package}.debug=false"));
            }
            for package in &packages {
                build.arg("--config").arg(format!("profile.{profile}.package.{package}.strip=\"debuginfo\""));
                build.args(["-p", package]);
            }
            for chapter in chapters {
                build.args(["--bin", &format!("workshop-{chapter}")]);
            }
            let built = build.output().unwrap_or_else(|e| panic!("cannot run cargo ({e})"));
            (built.status.success(), String::from_utf8_lossy(&built.stderr).into_owned())
        };
        let chapters: Vec<&str> = members.iter().map(|&i| SOLUTIONS[i].chapter).collect();
        let (built, log) = build(&chapters);
        if !built {
            // Which solutions fail, one chapter at a time (what built already is not built again).
            let broken: Vec<String> = members
                .iter()
                .map(|&i| (&SOLUTIONS[i], build(&[SOLUTIONS[i].chapter])))
                .filter(|(_, (built, _))| !built)
                .map(|(s, (_, log))| format!("{} (chapter {}) does not build:\n{log}", s.patch, s.chapter))
                .collect();
            panic!("workshop solutions that do not build (copy {}):\n{}", copy.display(), broken.join("\n"));
        }
        let compiled: Vec<&str> = log
            .lines()
            .filter_map(|l| l.trim().strip_prefix("Compiling "))
            .map(|l| l.split(' ').next().unwrap())
            .collect();
        timings.push(format!(
            "build {number} ({} patches): {:.1} s, compiled {compiled:?}",
            members.len(),
            phase.elapsed().as_secs_f64()
        ));

        // 3. Run each patched chapter headless on the software stack.
        for &i in members {
            let solution = &SOLUTIONS[i];
            let phase = Instant::now();
            let bin = bin_dir.join(format!("workshop-{}", solution.chapter));
            let bin = bin.to_str().unwrap();
            let run = std::panic::catch_unwind(|| harness::run_chapter_with(bin, solution.args, &[]));
            let verdict = match &run {
                Ok(run) => judge(solution, run),
                Err(_) => {
                    Some("could not run it, or its output was not a report (see the panic above)".to_owned())
                }
            };
            // The chapter as it is, with the same flags: it must not show what the patch adds.
            let original = bin_dir.join(solution.chapter);
            let original = original.to_str().unwrap();
            let unpatched =
                std::panic::catch_unwind(|| harness::run_chapter_with(original, solution.args, &[]));
            let verdict = match (verdict, unpatched) {
                (None, Ok(unpatched))
                    if !matches!(solution.proof, Proof::Unseen(_))
                        && proof_holds(&solution.proof, &unpatched) =>
                {
                    Some(format!(
                        "{original}, unpatched, shows {} too: the run proves nothing about the patch",
                        solution.proof.describe()
                    ))
                }
                (verdict, _) => verdict,
            };
            if let Some(why) = verdict {
                let stderr = run.as_ref().map(|r| r.stderr.as_str()).unwrap_or("");
                let tail: Vec<&str> =
                    stderr.lines().rev().take(30).collect::<Vec<_>>().into_iter().rev().collect();
                failures.push(format!(
                    "{} (chapter {}, {}): {why}\n  {}",
                    solution.patch,
                    solution.chapter,
                    solution.args.join(" "),
                    tail.join("\n  ")
                ));
            } else if let Proof::Unseen(why) = solution.proof {
                eprintln!("{}: built and passed; the run cannot show what it adds: {why}", solution.patch);
            }
            timings.push(format!("run {}: {:.1} s", solution.chapter, phase.elapsed().as_secs_f64()));
        }
    }
    eprintln!(
        "workshop solutions, {:.1} s in all:\n  {}",
        started.elapsed().as_secs_f64(),
        timings.join("\n  ")
    );
    assert!(failures.is_empty(), "workshop solutions that fail:\n{}", failures.join("\n"));
}

/// The kit's time table lists the chapters a workshop runs; each of them has a challenge with a
/// worked solution, and the kit links every solution.
#[test]
fn every_chapter_in_the_time_table_has_a_challenge_and_its_solution() {
    let page = std::fs::read_to_string(root().join("book/src/workshop.md")).unwrap();
    let table: Vec<&str> = page
        .lines()
        .skip_while(|l| !l.starts_with("## A time budget"))
        .take_while(|l| !l.starts_with("## Lavapipe"))
        .filter(|l| l.starts_with("| ["))
        .collect();
    let chapters: Vec<&str> = table
        .iter()
        .filter_map(|row| row.strip_prefix("| [")?.split(']').next())
        .filter(|n| n.len() == 2 && n.bytes().all(|b| b.is_ascii_digit()))
        .collect();
    assert!(chapters.len() >= 11, "the time table lists {chapters:?}");
    let mut patches: BTreeMap<String, String> = BTreeMap::new();
    for entry in std::fs::read_dir(workshop_dir()).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.ends_with(".diff") {
            patches.insert(name[..2].to_owned(), name);
        }
    }
    let mut problems = Vec::new();
    for chapter in &chapters {
        match patches.get(*chapter) {
            None => problems.push(format!(
                "chapter {chapter} is in the time table, but has no workshop/{chapter}-*.diff"
            )),
            Some(patch) => {
                if !page.contains(&format!("](workshop/{patch})")) {
                    problems.push(format!("workshop.md does not link its solution workshop/{patch}"));
                }
                if !page.contains(&format!("**{chapter} · ")) {
                    problems.push(format!("workshop.md has no challenge headed **{chapter} · ...**"));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// "Each chapter page ends with Checks and Try this", the kit tells teachers: every chapter page
/// has the template's closing sections.
#[test]
fn every_chapter_page_has_the_templates_sections() {
    const SECTIONS: [&str; 5] =
        ["## What you should see", "## Checks", "## Try this", "## Recap", "## Specifications and sources"];
    let mut problems = Vec::new();
    let mut pages = 0;
    for entry in std::fs::read_dir(root().join("book/src")).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        // A chapter's `-deeper` page holds what its page moved out; the template is the page's.
        if !(name.ends_with(".md") && name.as_bytes()[..2].iter().all(u8::is_ascii_digit))
            || name.ends_with("-deeper.md")
        {
            continue;
        }
        pages += 1;
        let text = std::fs::read_to_string(entry.path()).unwrap();
        let headings: Vec<&str> = text.lines().filter(|l| l.starts_with("## ")).map(str::trim).collect();
        let found: Vec<usize> =
            SECTIONS.iter().filter_map(|s| headings.iter().position(|h| h == s)).collect();
        for section in SECTIONS.iter().filter(|s| !headings.contains(s)) {
            problems.push(format!("{name} has no `{section}`"));
        }
        if found.len() == SECTIONS.len() && !found.is_sorted() {
            problems.push(format!("{name}: the closing sections are not in the order {SECTIONS:?}"));
        }
    }
    assert!(pages >= 12, "only {pages} chapter pages in book/src");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
