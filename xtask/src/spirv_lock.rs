//! `shaders/spirv.lock`: which GLSL each committed SPIR-V was built from. `xtask` writes it and
//! `tests/shaders.rs` checks it, both compiling this one file, so they cannot hash differently.
//!
//! A shader's hash is the SHA-256 of its source's text followed by the text of every file it
//! `#include`s, depth-first in order of appearance, each file once. CRLF is read as LF, so a
//! Windows checkout with `core.autocrlf` does not look stale.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};

/// Extensions glslc compiles for Vulkan; other files (`gl/`, `#include`d helpers) are not shaders.
pub const VULKAN_STAGES: &[&str] = &["comp", "rgen", "rmiss", "rchit", "rahit", "vert", "frag"];
pub const LOCK_FILE: &str = "spirv.lock";
pub const EDITED: &str = "source (or an include) changed since its SPIR-V was built";

/// Names (relative to `dir`) of the Vulkan shader sources directly in `dir`, sorted.
pub fn vulkan_sources(dir: &Path) -> Result<Vec<String>> {
    let entries = fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
    let mut names: Vec<String> =
        entries.filter_map(|entry| entry.ok()?.file_name().into_string().ok()).collect();
    names.retain(|name| name.rsplit_once('.').is_some_and(|(_, stage)| VULKAN_STAGES.contains(&stage)));
    names.sort();
    Ok(names)
}

/// Hex SHA-256 of `dir/name` and everything it includes (scheme in the module docs).
pub fn source_hash(dir: &Path, name: &str) -> Result<String> {
    let mut hasher = Sha256::new();
    hash_file(dir, &dir.join(name), &mut hasher, &mut BTreeSet::new())?;
    Ok(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

fn hash_file(root: &Path, file: &Path, hasher: &mut Sha256, seen: &mut BTreeSet<PathBuf>) -> Result<()> {
    let text = fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    // Canonical, so `a.glsl` and `./a.glsl` count as one file (and include cycles end).
    if !seen.insert(file.canonicalize()?) {
        return Ok(());
    }
    let text = text.replace("\r\n", "\n");
    hasher.update(text.as_bytes());
    for line in text.lines() {
        let Some(directive) = line.trim_start().strip_prefix('#') else { continue };
        let Some(target) = directive.trim_start().strip_prefix("include") else { continue };
        let name = target.trim().trim_matches(['"', '<', '>']);
        // Where glslc looks: beside the including file, then in the -I directory (shaders/).
        let beside = file.parent().unwrap().join(name);
        let included = if beside.is_file() { beside } else { root.join(name) };
        hash_file(root, &included, hasher, seen)
            .with_context(|| format!("following `#include {name}` in {}", file.display()))?;
    }
    Ok(())
}

/// The lock file's text for the sources in `dir`: `<hash> <name>` per line, sorted by name.
pub fn render_lock(dir: &Path) -> Result<String> {
    let mut lock = String::new();
    for name in vulkan_sources(dir)? {
        lock += &format!("{} {name}\n", source_hash(dir, &name)?);
    }
    Ok(lock)
}

/// The lock in `dir` as name -> hash.
pub fn read_lock(dir: &Path) -> Result<BTreeMap<String, String>> {
    let path = dir.join(LOCK_FILE);
    let text = fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    // A malformed line names no shader, so its shader shows up as not in the lock.
    Ok(text.lines().filter_map(|l| l.split_once(' ')).map(|(h, n)| (n.into(), h.into())).collect())
}

/// Every way the committed SPIR-V in `dir` disagrees with its sources, one line each naming the
/// shader; empty when all is up to date.
pub fn stale(dir: &Path) -> Result<Vec<String>> {
    let mut lock = read_lock(dir)?;
    let mut problems = Vec::new();
    for name in vulkan_sources(dir)? {
        if !dir.join(format!("{name}.spv")).is_file() {
            problems.push(format!("{name}: {name}.spv is missing"));
        }
        match lock.remove(&name) {
            None => problems.push(format!("{name}: not in {LOCK_FILE}")),
            Some(hash) if hash != source_hash(dir, &name)? => problems.push(format!("{name}: {EDITED}")),
            Some(_) => {}
        }
    }
    // Whatever is left in the lock has no source any more.
    problems.extend(lock.keys().map(|name| format!("{name}: in {LOCK_FILE} but the source is gone")));
    Ok(problems)
}
