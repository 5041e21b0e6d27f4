//! `common` stands in one-way layers (the map is in `src/lib.rs`): a module uses only its own
//! layer and the layers below it. This test reads every source file, finds each path it names
//! through `crate::` or `super::`, and fails naming the file and line of any that reaches a
//! higher layer, or goes through the crate root (which only re-exports) instead of naming the
//! module. The acceleration structures and ray pipelines are Vulkan only: they may not name GL.
//! Inside a layer too, modules use each other one way: no two (or more) use each other in a circle.
//! The chapter folders are held to the same: no circle, no `#[path]`, and no module below a
//! chapter's `main.rs` reaching up into it (for its flags, its name or its sizes).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The layers, lowest first.
const LAYERS: [&str; 7] = ["instruments", "base", "clocks", "interop", "scene", "rt", "frame"];

/// Modules with nothing of GL in them (a GL type here would tie the builds to a GL context).
const VULKAN_ONLY: [&str; 2] = ["rt/accel/", "rt/raytrace.rs"];
const GL_NAMES: [&str; 3] = ["glow", "GlContext", "crate::base::gl"];

fn sources(dir: &Path, found: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, found);
        } else if path.extension().is_some_and(|e| e == "rs") {
            found.push(path);
        }
    }
}

/// The module a file defines, as path segments (`base/gl/mod.rs` -> `["base", "gl"]`).
fn module_of(relative: &Path) -> Vec<String> {
    let mut segments: Vec<String> =
        relative.iter().map(|s| s.to_string_lossy().trim_end_matches(".rs").to_owned()).collect();
    if matches!(segments.last().map(String::as_str), Some("mod" | "lib")) {
        segments.pop();
    }
    segments
}

/// The paths after `crate::` or `super::`: one, or each top-level item of a `{a, b::c}` group.
fn items(rest: &str) -> Vec<&str> {
    let Some(group) = rest.strip_prefix('{') else { return vec![rest] };
    // Split at commas outside nested braces, up to the group's closing brace.
    let (mut found, mut depth, mut item_start) = (Vec::new(), 0, 0);
    for (i, c) in group.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => {
                found.push(group[item_start..i].trim());
                break;
            }
            '}' => depth -= 1,
            ',' if depth == 0 => {
                found.push(group[item_start..i].trim());
                item_start = i + 1;
            }
            _ => {}
        }
    }
    found
}

/// Every path a line names from the crate's root: `crate::a::b`, each item of
/// `crate::{a, b::c}`, and `super::` paths (and groups) resolved against `module`.
fn paths_in(line: &str, module: &[String]) -> Vec<Vec<String>> {
    let mut paths = Vec::new();
    let ident = |s: &str| -> String { s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect() };
    let segments_from = |rest: &str| -> Vec<String> {
        let mut out = Vec::new();
        let mut rest = rest;
        loop {
            let name = ident(rest);
            if name.is_empty() {
                break;
            }
            rest = &rest[name.len()..];
            out.push(name);
            match rest.strip_prefix("::") {
                Some(more) => rest = more,
                None => break,
            }
        }
        out
    };
    for (start, prefix) in line.match_indices("crate::").map(|(i, p)| (i, p.len())) {
        let word_start = start == 0 || !line[..start].ends_with(|c: char| c.is_alphanumeric() || c == '_');
        if !word_start {
            continue;
        }
        paths.extend(items(&line[start + prefix..]).into_iter().map(segments_from));
    }
    for (start, _) in line.match_indices("super::") {
        if start > 0 && line[..start].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
            continue; // the second `super` of `super::super::`, handled with the first
        }
        let mut base: Vec<String> = module.to_vec();
        let mut rest = &line[start..];
        while let Some(more) = rest.strip_prefix("super::") {
            base.pop();
            rest = more;
        }
        for item in items(rest) {
            let mut path = base.clone();
            path.extend(segments_from(item));
            paths.push(path);
        }
    }
    paths.retain(|p| !p.is_empty());
    paths
}

/// What is wrong with the paths `text` names, as `file:line: why` lines.
fn violations(relative: &Path, text: &str) -> Vec<String> {
    let module = module_of(relative);
    let shown = relative.display();
    let mut found = Vec::new();
    let Some(layer) = module.first() else {
        // The crate root: declarations, re-exports and doc comments only. A `pub use` that rustfmt
        // wrapped (`pub use a::{\n b, c,\n};`) goes on until its `;`.
        let mut in_use = false;
        for (number, line) in text.lines().enumerate() {
            let code = line.trim_start();
            let continues = in_use;
            if code.starts_with("pub use ") || in_use {
                in_use = !code.ends_with(';');
            }
            let allowed = code.is_empty()
                || continues
                || code.starts_with("//")
                || code.starts_with("pub mod ")
                || code.starts_with("pub use ");
            if !allowed {
                found.push(format!(
                    "{shown}:{}: the crate root only declares and re-exports: {code}",
                    number + 1
                ));
            }
        }
        return found;
    };
    let rank = |name: &str| LAYERS.iter().position(|l| *l == name);
    let own =
        rank(layer).unwrap_or_else(|| panic!("{shown} is in no layer ({layer}); the layers: {LAYERS:?}"));
    let vulkan_only = VULKAN_ONLY.iter().any(|v| shown.to_string().starts_with(v));
    for (number, line) in logical_lines(text) {
        let line = line.as_str();
        let at = format!("{shown}:{}", number + 1);
        for path in paths_in(line, &module) {
            let named = path.join("::");
            match rank(&path[0]) {
                None => {
                    found.push(format!("{at}: `crate::{named}` goes through the crate root; name its module"))
                }
                Some(target) if target > own => found.push(format!(
                    "{at}: `crate::{named}` reaches up from {layer} to {} (layers, lowest first: {LAYERS:?})",
                    path[0]
                )),
                Some(_) => {}
            }
        }
        if let Some(name) = GL_NAMES.iter().find(|n| vulkan_only && line.contains(*n)) {
            found.push(format!("{at}: names `{name}` in a Vulkan-only module"));
        }
    }
    found
}

/// `text`'s lines, numbered from 0, with a `use` that rustfmt wrapped over several lines
/// (`use crate::{\n    a::B,\n    c::D,\n};`) joined into one, numbered as its first line: a
/// path on a continuation line must not escape the check.
fn logical_lines(text: &str) -> Vec<(usize, String)> {
    let mut out: Vec<(usize, String)> = Vec::new();
    let mut open = false;
    for (number, line) in text.lines().enumerate() {
        let code = line.trim();
        if open {
            let last = out.last_mut().expect("a use to continue");
            last.1.push_str(code);
        } else {
            out.push((number, line.to_string()));
        }
        let starts =
            code.starts_with("use ") || code.starts_with("pub use ") || code.starts_with("pub(crate) use ");
        if starts || open {
            open = !code.ends_with(';');
        }
    }
    out
}

/// Every source file of `common`, by its path under `src/`, with its text.
fn crate_sources() -> Vec<(PathBuf, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut paths = Vec::new();
    sources(&root, &mut paths);
    paths.sort();
    assert!(paths.len() > 20, "found only {} files under {}", paths.len(), root.display());
    paths
        .iter()
        .map(|p| (p.strip_prefix(&root).unwrap().to_path_buf(), std::fs::read_to_string(p).unwrap()))
        .collect()
}

#[test]
fn no_module_reaches_a_higher_layer() {
    let found: Vec<String> =
        crate_sources().iter().flat_map(|(relative, text)| violations(relative, text)).collect();
    assert!(found.is_empty(), "modules that break the layers:\n{}", found.join("\n"));
}

#[test]
fn the_check_sees_what_it_must_refuse() {
    let check = |file: &str, text: &str| violations(Path::new(file), text);
    // Down and sideways are fine, in every spelling.
    assert!(check("rt/ao.rs", "use crate::base::vulkan::VulkanContext;").is_empty());
    // A use rustfmt wrapped over lines is read whole.
    assert_eq!(
        check(
            "scene/gbuffer.rs",
            "use crate::{\n    base::vulkan::VulkanContext,\n    rt::ao::AoTracer,\n};"
        )
        .len(),
        1
    );
    assert!(check("rt/ao.rs", "use crate::{base::gl::GlContext, scene::gbuffer::GBuffers};").is_empty());
    assert!(check("frame/probe.rs", "use super::composite::Uniforms;").is_empty());
    assert!(check("base/gl/debug.rs", "use super::super::super::instruments::report::Report;").is_empty());
    // Up, through a group, through `super`, inline, and through the root.
    assert_eq!(check("scene/gbuffer.rs", "use crate::rt::ao::AoTracer;").len(), 1);
    assert_eq!(check("base/cli.rs", "use crate::{instruments::report, interop::handoff};").len(), 1);
    assert_eq!(check("instruments/report.rs", "use crate::base::vulkan::VulkanContext;").len(), 1);
    assert_eq!(check("base/gl/mod.rs", "use super::super::super::frame::Target;").len(), 1);
    assert_eq!(check("interop/import.rs", "let g = crate::scene::gbuffer::as_bytes(x);").len(), 1);
    assert_eq!(check("instruments/output.rs", "use crate::Report;").len(), 1);
    // GL in a Vulkan-only module; logic in the root.
    assert_eq!(check("rt/accel/build.rs", "gl: &glow::Context,").len(), 1);
    assert_eq!(check("lib.rs", "pub fn run() {}").len(), 1);
    // Words that merely contain `crate::` are not paths.
    assert!(check("base/cli.rs", "use mycrate::scene::Scene;").is_empty());
}

// ---------------------------------------------------------------------------------------------
// No circles between modules

/// Whether `text` defines or re-exports `name` publicly: `pub fn name`, `pub(crate) struct name`,
/// `pub use a::name;` or `pub use a::{b, name};`.
fn defines(text: &str, name: &str) -> bool {
    const KINDS: [&str; 9] = ["fn", "struct", "enum", "type", "const", "static", "trait", "mod", "union"];
    text.lines().any(|line| {
        let line = line.trim_start();
        let Some(rest) = line.strip_prefix("pub") else { return false };
        // Past the visibility: `pub `, `pub(crate) `, `pub(super) `.
        let rest = match rest.strip_prefix('(') {
            Some(inner) => inner.split_once(')').map_or("", |(_, after)| after),
            None => rest,
        };
        let mut words = rest.split(|c: char| !(c.is_alphanumeric() || c == '_')).filter(|w| !w.is_empty());
        match words.next() {
            Some("use") => words.any(|w| w == name),
            Some(kind) if KINDS.contains(&kind) => words.next() == Some(name),
            _ => false,
        }
    })
}

/// The module `path` (segments from the crate root) names: the longest prefix that is a module,
/// and, where the next segment is an item a folder re-exports (`pub use model::*;` in
/// `scene/mod.rs`), the module that defines it, so that `crate::scene::Vertex` counts as a use of
/// `scene/model.rs`, not of `scene/mod.rs`.
fn resolve(path: &[String], modules: &BTreeMap<Vec<String>, String>) -> Vec<String> {
    let at = (1..=path.len()).rev().find(|&k| modules.contains_key(&path[..k])).unwrap_or(0);
    let module = path[..at].to_vec();
    let (Some(name), Some(text)) = (path.get(at), modules.get(&module)) else { return module };
    for line in text.lines() {
        let Some(used) = line.trim_start().strip_prefix("pub use ") else { continue };
        let child = used.split("::").next().unwrap_or_default();
        let mut child_path = module.clone();
        child_path.push(child.to_owned());
        let Some(child_text) = modules.get(&child_path) else { continue };
        let glob = used.trim_end_matches(';').ends_with("::*");
        let listed = used.split(|c: char| !(c.is_alphanumeric() || c == '_')).skip(1).any(|w| w == name);
        if (glob && defines(child_text, name)) || listed {
            child_path.push(name.clone());
            return resolve(&child_path, modules);
        }
    }
    module
}

/// A file's lines, each with the module its paths are resolved against: inside an inline
/// `mod tests { ... }`, `super::` names the file's own module.
fn lines_with_modules(relative: &Path, text: &str) -> Vec<(usize, String, Vec<String>)> {
    let mut module = module_of(relative);
    let (mut depth, mut open): (i64, Vec<i64>) = (0, Vec::new());
    let mut out = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or_default();
        let words: Vec<&str> = code.split_whitespace().collect();
        out.push((number + 1, line.to_owned(), module.clone()));
        if let Some(i) = words.iter().position(|w| *w == "mod")
            && words.get(i + 2) == Some(&"{")
        {
            module.push(words[i + 1].to_owned());
            open.push(depth);
        }
        depth += code.matches('{').count() as i64 - code.matches('}').count() as i64;
        while open.last().is_some_and(|d| *d >= depth) {
            open.pop();
            module.pop();
        }
    }
    out
}

/// Every use of one module by another, as `(user, used) -> "file:line"` (the first such line).
fn uses(files: &[(PathBuf, String)]) -> BTreeMap<(Vec<String>, Vec<String>), String> {
    let modules: BTreeMap<Vec<String>, String> =
        files.iter().map(|(relative, text)| (module_of(relative), text.clone())).collect();
    let mut found = BTreeMap::new();
    for (relative, text) in files {
        let user = module_of(relative);
        for (number, line, module) in lines_with_modules(relative, text) {
            // A doc comment's link is no use of the module it names.
            if line.trim_start().starts_with("//") {
                continue;
            }
            let mut paths = paths_in(&line, &module);
            // A folder's own `use child::...` (not its re-exports, which `resolve` follows).
            if let Some(used) = line.trim_start().strip_prefix("use ") {
                let mut child = user.clone();
                child.extend(used.split("::").next().map(str::to_owned));
                if modules.contains_key(&child) {
                    child.extend(used.split("::").nth(1).map(|s| s.trim_end_matches(';').to_owned()));
                    paths.push(child);
                }
            }
            for path in paths {
                let used = resolve(&path, &modules);
                if !used.is_empty() && used != user {
                    let at = format!("{}:{number}", relative.display());
                    found.entry((user.clone(), used)).or_insert(at);
                }
            }
        }
    }
    found
}

/// Every circle of modules that use each other, as `a -> b (file:line) -> ... -> a` lines, each
/// circle once.
fn cycles(files: &[(PathBuf, String)]) -> Vec<String> {
    let uses = uses(files);
    let mut next: BTreeMap<&Vec<String>, Vec<&Vec<String>>> = BTreeMap::new();
    for (user, used) in uses.keys() {
        next.entry(user).or_default().push(used);
    }
    let name = |m: &Vec<String>| if m.is_empty() { "lib".to_owned() } else { m.join("::") };
    let mut seen = std::collections::BTreeSet::new();
    let mut found = Vec::new();
    for (from, to) in uses.keys() {
        // The shortest way back from `to` to `from`, breadth first.
        let mut came_from: BTreeMap<&Vec<String>, &Vec<String>> = BTreeMap::new();
        let mut queue = std::collections::VecDeque::from([to]);
        while let Some(at) = queue.pop_front() {
            if at == from {
                break;
            }
            for step in next.get(at).into_iter().flatten() {
                if !came_from.contains_key(step) && *step != to {
                    came_from.insert(step, at);
                    queue.push_back(step);
                }
            }
        }
        if from != to && !came_from.contains_key(from) {
            continue;
        }
        let mut circle = vec![from];
        let mut at = from;
        while at != to {
            at = came_from[at];
            circle.push(at);
        }
        circle[1..].reverse();
        let mut key: Vec<_> = circle.iter().map(|m| name(m)).collect();
        key.sort();
        if !seen.insert(key) {
            continue;
        }
        let mut text = name(circle[0]);
        for (i, m) in circle.iter().enumerate() {
            let after = circle[(i + 1) % circle.len()];
            text += &format!(" -> {} ({})", name(after), uses[&((*m).clone(), after.clone())]);
        }
        found.push(text);
    }
    found
}

/// Modules use each other in one direction only, inside a layer as between layers: a circle
/// (`memory` uses `structure`, which uses `memory`) means neither can be read, tested or moved
/// without the other, and the layers' order says nothing about which comes first.
#[test]
fn no_modules_use_each_other() {
    let files = crate_sources();
    assert!(uses(&files).len() > 50, "found only {} uses between modules", uses(&files).len());
    let found = cycles(&files);
    assert!(found.is_empty(), "modules that use each other, in a circle:\n{}", found.join("\n"));
}

#[test]
fn the_circle_check_sees_what_it_must_refuse() {
    // Each case: its files, and how many circles they make.
    let cases: [(&[(&str, &str)], usize); 3] = [
        // Two files naming each other, through `super::`.
        (
            &[
                ("rt/accel/memory.rs", "pub struct Memory;\nfn f() { super::structure::properties(); }"),
                ("rt/accel/structure.rs", "use super::memory::Memory;\npub fn properties() {}"),
            ],
            1,
        ),
        // Three, one reached through its folder's re-export (`crate::scene::load_obj`).
        (
            &[
                ("scene/mod.rs", "mod builtin;\nmod model;\nmod obj;\npub use model::*;\npub use obj::*;"),
                ("scene/builtin.rs", "use super::model::Scene;\npub enum SceneKind {}"),
                ("scene/model.rs", "use crate::scene::load_obj;\npub struct Scene;"),
                ("scene/obj.rs", "pub fn load_obj() {}\nfn g(k: super::builtin::SceneKind) {}"),
            ],
            1,
        ),
        // One way only, a test module's `super::*` (its own file), and a layer below: none.
        (
            &[
                ("scene/mod.rs", "mod model;\nmod obj;\npub use model::*;\npub use obj::*;"),
                ("scene/model.rs", "pub struct Scene;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}"),
                ("scene/obj.rs", "use crate::scene::Scene;\nuse crate::base::Report;"),
                ("base/mod.rs", "pub struct Report;"),
            ],
            0,
        ),
    ];
    for (list, circles) in cases {
        let files: Vec<(PathBuf, String)> =
            list.iter().map(|(p, t)| (PathBuf::from(p), t.to_string())).collect();
        assert_eq!(cycles(&files).len(), circles, "{list:?}: {:?}", cycles(&files));
    }
}

/// What each layer holds, for the picture (lowest first, as [`LAYERS`]).
const ROLES: [&str; 7] = [
    "the report and its checks, counts of what is alive, failure injection, files written",
    "contexts and their owners, commands, flags, windows (chapters 01-04)",
    "GPU time: Vulkan's timestamps, GL's pass timers, the two APIs on one timeline",
    "memory Vulkan exports and GL imports, the hand-off between them, CUDA's import",
    "meshes, instances, OBJ files, the camera; the G-buffers GL draws (chapter 05)",
    "acceleration structures and ray pipelines (Vulkan only), the AO tracer (06-07)",
    "the composite, overlay lines, pixel probes; the frames of 08, 12 and 13",
];

/// The modules of one layer as the picture names them: files, and folders with a slash.
fn modules_of(layer: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(layer)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.file_name().is_some_and(|n| n != "mod.rs"))
        .map(|path| {
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if path.is_dir() { format!("{name}/") } else { name.trim_end_matches(".rs").to_owned() }
        })
        .collect();
    names.sort();
    names
}

/// The layers as an SVG: one band a layer, the highest on top, each naming its modules (on as
/// many lines as they need), and an arrow down the side for the one direction a module may look.
fn layers_picture(root: &Path) -> String {
    let (width, gap, left, line) = (760, 14, 40, 18);
    // A 12 px monospace character is about 7.2 px wide: this many fit inside a band.
    let per_line = ((width - 2 * left - 24) as f64 / 7.2) as usize;
    let bands: Vec<(&str, &str, Vec<String>)> = LAYERS
        .iter()
        .zip(ROLES)
        .rev()
        .map(|(layer, role)| (*layer, role, wrap(&modules_of(&root.join(layer)), per_line)))
        .collect();
    let band_height = |lines: usize| 64 + line * (lines - 1);
    let height = bands.iter().map(|(_, _, lines)| band_height(lines.len()) + gap).sum::<usize>() + gap;
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" \
         viewBox=\"0 0 {width} {height}\" font-family=\"sans-serif\" font-size=\"13\">\n\
         <rect width=\"{width}\" height=\"{height}\" fill=\"white\"/>\n"
    );
    let mut y = gap;
    let (mut top, mut bottom) = (0, 0);
    for (row, (layer, role, lines)) in bands.iter().enumerate() {
        let band = band_height(lines.len());
        svg += &format!(
            "<rect x=\"{left}\" y=\"{y}\" width=\"{}\" height=\"{band}\" rx=\"6\" fill=\"#eef3fb\" stroke=\"#5b7db1\"/>\n\
             <text x=\"{}\" y=\"{}\" font-weight=\"bold\">{layer}</text>\n\
             <text x=\"{}\" y=\"{}\" fill=\"#333\">{role}</text>\n",
            width - left - 10,
            left + 12,
            y + 20,
            left + 110,
            y + 20,
        );
        for (i, text) in lines.iter().enumerate() {
            svg += &format!(
                "<text x=\"{}\" y=\"{}\" font-family=\"monospace\" font-size=\"12\" fill=\"#1a3d6e\">{text}</text>\n",
                left + 12,
                y + 46 + i * line,
            );
        }
        if row == 0 {
            top = y + band / 2;
        }
        bottom = y + band / 2;
        y += band + gap;
    }
    svg += &format!(
        "<line x1=\"20\" y1=\"{top}\" x2=\"20\" y2=\"{}\" stroke=\"#5b7db1\" stroke-width=\"2\"/>\n\
         <polygon points=\"14,{} 26,{} 20,{bottom}\" fill=\"#5b7db1\"/>\n\
         <text x=\"16\" y=\"{}\" transform=\"rotate(-90 16 {})\" font-size=\"11\" fill=\"#5b7db1\" text-anchor=\"middle\">uses</text>\n\
         </svg>\n",
        bottom - 10,
        bottom - 12,
        bottom - 12,
        height / 2,
        height / 2,
    );
    svg
}

/// `names`, two spaces apart, in lines of at most `width` characters.
fn wrap(names: &[String], width: usize) -> Vec<String> {
    let mut lines = vec![String::new()];
    for name in names {
        let last = lines.last_mut().expect("never empty");
        if !last.is_empty() && last.len() + 2 + name.len() > width {
            lines.push(name.clone());
        } else {
            if !last.is_empty() {
                last.push_str("  ");
            }
            last.push_str(name);
        }
    }
    lines
}

/// The book's picture of the layers is drawn from the folders as they are: a module added,
/// moved or removed fails this test until the picture is made again
/// (`VKGL_UPDATE_IMAGES=1 cargo test -p common --test layers`).
#[test]
fn the_books_picture_shows_the_layers_as_they_are() {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let drawn = layers_picture(&manifest.join("src"));
    let picture = manifest.join("../book/src/images/common-layers.svg");
    if std::env::var_os("VKGL_UPDATE_IMAGES").is_some() {
        std::fs::write(&picture, &drawn).unwrap();
    }
    let committed = std::fs::read_to_string(&picture).unwrap_or_default();
    assert!(
        committed == drawn,
        "{} does not show common/src as it is; draw it again with \
         VKGL_UPDATE_IMAGES=1 cargo test -p common --test layers",
        picture.display()
    );
}

// ---------------------------------------------------------------------------------------------
// Chapter folders

/// What chapter folders still break, each with the rule (`#[path]`, `reaches up`, `circle`) and
/// where. Empty this list as they are mended: an entry whose folder no longer breaks its rule
/// fails too, so that the list cannot stay longer than it must.
const CHAPTERS_PENDING: [(&str, &str, &str); 0] = [];

/// A chapter folder's files, `main.rs` standing as the root of its modules (the crate root, as
/// `lib.rs` stands in `common`).
fn chapter_sources(dir: &Path) -> Vec<(PathBuf, String)> {
    let mut paths = Vec::new();
    sources(dir, &mut paths);
    paths.sort();
    paths
        .iter()
        .map(|p| {
            let relative = p.strip_prefix(dir).unwrap();
            let relative =
                if relative == Path::new("main.rs") { PathBuf::from("lib.rs") } else { relative.into() };
            (relative, std::fs::read_to_string(p).unwrap())
        })
        .collect()
}

/// What is wrong with one chapter folder's modules: a `#[path]` (code two chapters share lives
/// in `common`, a child module in a file named for it), a module below `main.rs` that names
/// `main.rs`'s own items through `crate::` or `super::` (it takes what it needs as arguments),
/// and every circle of modules.
fn chapter_errors(files: &[(PathBuf, String)]) -> Vec<(&'static str, String)> {
    let mut found = Vec::new();
    let modules: BTreeMap<Vec<String>, String> =
        files.iter().map(|(relative, text)| (module_of(relative), text.clone())).collect();
    for (relative, text) in files {
        let shown = if relative == Path::new("lib.rs") { PathBuf::from("main.rs") } else { relative.clone() };
        for (number, line, module) in lines_with_modules(relative, text) {
            let at = format!("{}:{number}", shown.display());
            let code = line.trim_start();
            if code.starts_with("//") {
                continue;
            }
            if code.contains("#[path") {
                found.push((
                    "#[path]",
                    format!("{at}: #[path] mounts a file that is not the module's own: {code}"),
                ));
            }
            if module.is_empty() {
                continue; // main.rs itself
            }
            for path in paths_in(&line, &module) {
                if resolve(&path, &modules).is_empty() {
                    let why =
                        format!("{at}: `{}` reaches up into main.rs; pass it in instead", path.join("::"));
                    found.push(("reaches up", why));
                }
            }
        }
    }
    found.extend(cycles(files).into_iter().map(|c| ("circle", format!("modules that use each other: {c}"))));
    found
}

#[test]
fn chapter_folders_read_one_way() {
    let chapters = Path::new(env!("CARGO_MANIFEST_DIR")).join("../chapters");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&chapters)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.is_dir() && p.file_name().unwrap().to_string_lossy().starts_with(|c: char| c.is_ascii_digit())
        })
        .collect();
    dirs.sort();
    assert!(dirs.len() >= 14, "found only {} chapter folders in {}", dirs.len(), chapters.display());
    let mut found = Vec::new();
    for dir in &dirs {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let errors = chapter_errors(&chapter_sources(dir));
        let pending = |rule: &str| CHAPTERS_PENDING.iter().any(|(c, r, _)| *c == name && *r == rule);
        for (rule, error) in &errors {
            if !pending(rule) {
                found.push(format!("chapters/{name}/{error}"));
            }
        }
        for (_, rule, why) in CHAPTERS_PENDING.iter().filter(|(c, _, _)| *c == name) {
            if !errors.iter().any(|(r, _)| r == rule) {
                found.push(format!(
                    "chapters/{name} no longer breaks `{rule}` ({why}): take it off CHAPTERS_PENDING"
                ));
            }
        }
    }
    assert!(found.is_empty(), "chapter folders that do not read one way:\n{}", found.join("\n"));
}

#[test]
fn the_chapter_check_sees_what_it_must_refuse() {
    let check = |list: &[(&str, &str)]| {
        let files: Vec<(PathBuf, String)> =
            list.iter().map(|(p, t)| (PathBuf::from(p), t.to_string())).collect();
        chapter_errors(&files)
    };
    // Two modules that use each other (the flags naming the path's kinds, the path the flags).
    let circle = check(&[
        ("lib.rs", "mod path;\nmod settings;\nuse settings::Args;"),
        ("path.rs", "pub enum PathKind {}\npub fn new(a: &crate::settings::Args) {}"),
        ("settings.rs", "use crate::path::PathKind;\npub struct Args;"),
    ]);
    assert_eq!(circle.len(), 1, "{circle:?}");
    // A child reaching up for the chapter's name, its sizes, its resize; and a #[path].
    let up = check(&[
        ("lib.rs", "const CHAPTER: &str = \"13\";\nmod walk;\n#[path = \"../12/overlap.rs\"]\nmod overlap;"),
        ("walk.rs", "fn f() { let s = crate::SMALLEST.width; crate::resize(); let c = super::CHAPTER; }"),
        ("overlap.rs", "pub fn g() {}"),
    ]);
    assert_eq!(up.len(), 4, "{up:?}");
    // Down only, arguments passed in, test modules' `super::*`: nothing to say.
    let fine = check(&[
        ("lib.rs", "mod walk;\nuse walk::headless;\nconst CHAPTER: &str = \"13\";"),
        ("walk.rs", "pub fn headless(chapter: &str) {}\n#[cfg(test)]\nmod tests {\n    use super::*;\n}"),
    ]);
    assert!(fine.is_empty(), "{fine:?}");
}
