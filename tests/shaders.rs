//! The committed SPIR-V still matches its GLSL. `cargo build` never runs glslc, so this is what
//! notices a shader edited without `cargo run -p xtask -- shaders`.

// The same hashing code the xtask writes the lock with.
#[path = "../xtask/src/spirv_lock.rs"]
mod spirv_lock;

mod harness;

use std::path::PathBuf;
use std::process::Command;

const REBUILD: &str = "run `cargo run -p xtask -- shaders` and commit shaders/";
const SPIRV_MAGIC: u32 = 0x0723_0203;

fn shaders_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("shaders")
}

fn sources() -> Vec<String> {
    let sources = spirv_lock::vulkan_sources(&shaders_dir()).unwrap();
    assert!(!sources.is_empty(), "no Vulkan shaders found in {}", shaders_dir().display());
    sources
}

#[test]
fn every_vulkan_shader_has_spirv_and_a_lock_line() {
    let lock = spirv_lock::read_lock(&shaders_dir()).unwrap();
    for name in sources() {
        assert!(
            shaders_dir().join(format!("{name}.spv")).is_file(),
            "shaders/{name}.spv is missing: {REBUILD}"
        );
        assert!(lock.contains_key(&name), "shaders/{name} has no line in shaders/spirv.lock: {REBUILD}");
    }
    let gone: Vec<_> = lock.keys().filter(|name| !sources().contains(name)).collect();
    assert!(gone.is_empty(), "shaders/spirv.lock lists shaders that no longer exist: {gone:?}: {REBUILD}");
}

#[test]
fn locked_hashes_match_the_sources() {
    let lock = spirv_lock::read_lock(&shaders_dir()).unwrap();
    // Collect them all, so one run names every stale shader.
    let stale: Vec<String> = sources()
        .into_iter()
        .filter(|name| lock.get(name) != Some(&spirv_lock::source_hash(&shaders_dir(), name).unwrap()))
        .collect();
    assert!(stale.is_empty(), "GLSL changed since its SPIR-V was built: {stale:?}: {REBUILD}");
}

#[test]
fn spirv_files_are_spirv() {
    for name in sources() {
        let spv = std::fs::read(shaders_dir().join(format!("{name}.spv"))).unwrap();
        // SPIR-V is a stream of 32-bit words, after a 5-word header that opens with the magic
        // number. glslc writes host-endian words, and every host we target is little-endian.
        assert!(
            spv.len() >= 20 && spv.len() % 4 == 0,
            "shaders/{name}.spv is {} bytes, not whole words",
            spv.len()
        );
        let magic = u32::from_le_bytes(spv[..4].try_into().unwrap());
        assert_eq!(magic, SPIRV_MAGIC, "shaders/{name}.spv does not start with the SPIR-V magic number");
    }
}

#[test]
fn sources_still_compile() {
    if let Err(error) = Command::new("glslc").arg("--version").output() {
        // A skip outside CI (counted as one by `bash .ci/test`), a failure in CI.
        let why = format!("glslc could not be started ({error}): apt-get install glslc, or bash .ci/deps");
        return harness::skip("sources_still_compile", &why);
    }
    let out = tempfile::tempdir().unwrap();
    for name in sources() {
        // The xtask's flags, but writing to a temp dir so the committed .spv stay untouched.
        let output = Command::new("glslc")
            .current_dir(shaders_dir())
            .args(["--target-env=vulkan1.3", "-O", "-g", "-I", "."])
            .arg("-o")
            .arg(out.path().join(format!("{name}.spv")))
            .arg(&name)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "glslc could not compile shaders/{name}:\n{}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
}

/// A missing tool (glslc, Xvfb) skips its test on a workstation, counted as a skip, and fails it
/// in CI.
#[test]
fn a_missing_tool_fails_only_in_ci() {
    let skip = harness::skip_line(false, "sources_still_compile", "no glslc").expect("outside CI: a skip");
    assert_eq!(skip, "sources_still_compile: no glslc");
    let fail = harness::skip_line(true, "sources_still_compile", "no glslc").expect_err("in CI: a failure");
    assert!(fail.contains("must not be skipped") && fail.contains(".ci/deps"), "{fail}");
}

/// The lock check itself, on a throwaway shaders dir: fresh after locking, stale after an edit to
/// the source or to a file it includes, but not after a CRLF checkout of the same text.
#[test]
fn lock_check_reports_edits_after_locking() {
    use spirv_lock::{LOCK_FILE, render_lock, stale};
    use std::fs::write;
    let dir = tempfile::tempdir().unwrap();
    let dir = dir.path();
    std::fs::create_dir(dir.join("gl")).unwrap();
    write(dir.join("util.glsl"), "const float k = 1.0;\n").unwrap();
    write(dir.join("a.comp"), "#version 460\n#include \"util.glsl\"\nvoid main() {}\n").unwrap();
    write(dir.join("a.comp.spv"), b"").unwrap();
    write(dir.join("gl/b.frag"), "#version 450 core\n").unwrap(); // Never locked: GL only.
    let lock = || write(dir.join(LOCK_FILE), render_lock(dir).unwrap()).unwrap();
    let fresh = Vec::<String>::new();
    let edited = vec![format!("a.comp: {}", spirv_lock::EDITED)];

    lock();
    assert_eq!(stale(dir).unwrap(), fresh);
    write(dir.join("a.comp"), "#version 460\n#include \"util.glsl\"\nvoid main() { }\n").unwrap();
    assert_eq!(stale(dir).unwrap(), edited);

    lock();
    write(dir.join("util.glsl"), "const float k = 2.0;\n").unwrap();
    assert_eq!(stale(dir).unwrap(), edited);

    lock();
    write(dir.join("util.glsl"), "const float k = 2.0;\r\n").unwrap();
    assert_eq!(stale(dir).unwrap(), fresh);
    std::fs::remove_file(dir.join("a.comp.spv")).unwrap();
    assert_eq!(stale(dir).unwrap(), vec!["a.comp: a.comp.spv is missing".to_owned()]);
}

/// The committed PTX still matches its CUDA source (`cargo run -p xtask -- cuda` rebuilds it).
#[test]
fn ptx_is_locked_to_its_cuda_source() {
    let dir = shaders_dir().join("cuda");
    let lock = std::fs::read_to_string(dir.join("ptx.lock")).unwrap();
    let lock: std::collections::BTreeMap<&str, &str> =
        lock.lines().filter_map(|l| l.split_once(' ')).map(|(h, n)| (n, h)).collect();
    let mut kernels = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        let Some(stem) = name.strip_suffix(".cu") else { continue };
        kernels += 1;
        let hash = spirv_lock::source_hash(&dir, &name).unwrap();
        assert_eq!(
            lock.get(name.as_str()),
            Some(&hash.as_str()),
            "shaders/cuda/{name} changed since its PTX was built: run `cargo run -p xtask -- cuda`"
        );
        let ptx = std::fs::read_to_string(dir.join(format!("{stem}.ptx"))).unwrap();
        // compute_75: what CUDA 13 drivers still JIT (and every GPU since Turing runs).
        assert!(ptx.contains(".target sm_75"), "shaders/cuda/{stem}.ptx targets compute_75");
        assert!(ptx.contains(".visible .entry"), "shaders/cuda/{stem}.ptx has a kernel");
    }
    assert!(kernels > 0 && lock.len() == kernels, "one lock line per kernel");
}
