//! The book never drifts from the code: every `{{#include}}` names a file that exists and, where it
//! names an anchor or a line range, something non-empty in it. (mdBook itself silently includes
//! an empty string for a missing anchor.) And the rendered book builds with no warning, and every
//! relative link and image in its HTML points at something that is there.

mod harness;

use std::path::{Path, PathBuf};

/// One `{{#include path[:anchor | :start[:end]]}}` found in a page.
#[derive(Debug)]
struct Include {
    page: PathBuf,
    line: usize,
    target: String,
}

fn includes_in(page: &Path, text: &str) -> Vec<Include> {
    let mut found = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let mut rest = line;
        while let Some(start) = rest.find("{{#") {
            let after = &rest[start + 3..];
            let Some(end) = after.find("}}") else { break };
            let directive = after[..end].trim();
            if let Some(target) =
                directive.strip_prefix("include ").or_else(|| directive.strip_prefix("rustdoc_include "))
            {
                found.push(Include {
                    page: page.to_owned(),
                    line: number + 1,
                    target: target.trim().to_owned(),
                });
            }
            rest = &after[end + 2..];
        }
    }
    found
}

/// What an include pulls in, or why it pulls in nothing.
fn resolve(include: &Include) -> Result<String, String> {
    let (path, selector) = match include.target.split_once(':') {
        Some((path, selector)) => (path, Some(selector)),
        None => (include.target.as_str(), None),
    };
    let file = include.page.parent().unwrap().join(path);
    let text = std::fs::read_to_string(&file).map_err(|e| format!("{}: {e}", file.display()))?;
    let lines: Vec<&str> = text.lines().collect();
    let body: Vec<&str> = match selector {
        None => lines,
        Some(selector) if selector.chars().next().is_some_and(|c| c.is_ascii_digit() || c == ':') => {
            let mut bounds = selector.splitn(2, ':');
            let start: usize = bounds.next().and_then(|s| s.parse().ok()).unwrap_or(1);
            let end: usize = bounds.next().and_then(|s| s.parse().ok()).unwrap_or(lines.len());
            lines.get(start.saturating_sub(1)..end.min(lines.len())).unwrap_or_default().to_vec()
        }
        Some(anchor) => {
            let is_marker = |line: &str, marker: &str| {
                line.trim_start().trim_start_matches("//").trim_start_matches('#').trim()
                    == format!("{marker}: {anchor}")
            };
            let start = lines
                .iter()
                .position(|l| is_marker(l, "ANCHOR"))
                .ok_or_else(|| format!("{} has no `ANCHOR: {anchor}`", file.display()))?;
            let end = lines[start..].iter().position(|l| is_marker(l, "ANCHOR_END")).ok_or_else(|| {
                format!("{} has no `ANCHOR_END: {anchor}` after its ANCHOR", file.display())
            })?;
            lines[start + 1..start + end].to_vec()
        }
    };
    let content: Vec<&str> =
        body.into_iter().filter(|l| !l.contains("ANCHOR:") && !l.contains("ANCHOR_END:")).collect();
    if content.iter().all(|l| l.trim().is_empty()) {
        return Err(format!("{} includes nothing", include.target));
    }
    Ok(content.join("\n"))
}

#[test]
fn every_include_in_the_book_resolves() {
    let book = Path::new(env!("CARGO_MANIFEST_DIR")).join("book/src");
    let mut count = 0;
    let mut broken = Vec::new();
    // The book's own pages: `book/src/chapters`, `common` and `shaders` are links to the sources
    // (so that the rendered book carries them), not pages.
    for page in harness::files_ending(&book, "md") {
        let text = std::fs::read_to_string(&page).unwrap();
        for include in includes_in(&page, &text) {
            count += 1;
            if let Err(why) = resolve(&include) {
                broken.push(format!("{}:{}: {why}", include.page.display(), include.line));
            }
        }
    }
    assert!(broken.is_empty(), "broken includes in the book:\n{}", broken.join("\n"));
    assert!(count > 0, "the book includes no code at all: was book/src moved?");
}

#[test]
fn the_checker_catches_what_mdbook_would_hide() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("code.rs"),
        "fn a() {}\n// ANCHOR: good\nfn b() {}\n// ANCHOR_END: good\n// ANCHOR: empty\n\n// ANCHOR_END: empty\n",
    )
    .unwrap();
    let page = dir.path().join("page.md");
    let text = "{{#include code.rs:good}}\n{{#include code.rs:gone}} {{#include code.rs:empty}}\n\
                {{#include missing.rs}}\n{{#rustdoc_include code.rs:1:1}}\n{{#include code.rs:40:50}}\n";
    let results: Vec<Result<String, String>> = includes_in(&page, text).iter().map(resolve).collect();
    assert_eq!(results.len(), 6);
    assert_eq!(results[0], Ok("fn b() {}".to_owned()));
    assert!(results[1].as_ref().unwrap_err().contains("no `ANCHOR: gone`"));
    assert!(results[2].as_ref().unwrap_err().contains("includes nothing"));
    assert!(results[3].is_err(), "a missing file");
    assert_eq!(results[4], Ok("fn a() {}".to_owned()));
    assert!(results[5].is_err(), "a line range past the end of the file");
}

/// mdBook as `.ci/deps --tests` installs it (0.5.4): on the PATH, or where `cargo install` puts it.
fn mdbook() -> PathBuf {
    let on_path = std::process::Command::new("mdbook").arg("--version").output().is_ok();
    let cargo_home = std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|home| Path::new(&home).join(".cargo")));
    match cargo_home.map(|home| home.join("bin/mdbook")) {
        Some(installed) if !on_path && installed.is_file() => installed,
        _ => PathBuf::from("mdbook"),
    }
}

/// Every `href="..."` and `src="..."` value in an HTML page, with its line.
fn links_in(html: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    for (number, line) in html.lines().enumerate() {
        for attribute in ["href=\"", "src=\""] {
            let mut rest = line;
            while let Some(start) = rest.find(attribute) {
                let after = &rest[start + attribute.len()..];
                let Some(end) = after.find('"') else { break };
                found.push((number + 1, after[..end].to_owned()));
                rest = &after[end..];
            }
        }
    }
    found
}

/// Why a link in `page` (a file under `root`) points at nothing, if it does. Links are resolved as
/// a web server would resolve them (a `..` above the root stays at the root), so the check holds
/// for `mdbook serve` as well as for the files opened from disk.
fn broken_link(root: &Path, page: &Path, link: &str) -> Option<String> {
    let lower = link.to_ascii_lowercase();
    if link.is_empty() {
        return Some("an empty link".to_owned());
    }
    if lower.contains("://")
        || lower.starts_with("mailto:")
        || lower.starts_with("data:")
        || link.starts_with("javascript:")
    {
        return None;
    }
    let (path, fragment) = match link.split_once('#') {
        Some((path, fragment)) => (path, Some(fragment)),
        None => (link, None),
    };
    let path = path.split('?').next().unwrap_or_default();
    let mut target: Vec<String> = if path.starts_with('/') {
        Vec::new()
    } else {
        let dir = page.parent().unwrap().strip_prefix(root).unwrap();
        dir.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect()
    };
    if path.is_empty() {
        target.push(page.file_name().unwrap().to_string_lossy().into_owned());
    }
    for part in path.split('/') {
        match part {
            "" | "." => {}
            ".." => {
                target.pop();
            }
            part => target.push(part.to_owned()),
        }
    }
    let mut file = root.to_path_buf();
    file.extend(&target);
    if file.is_dir() {
        file.push("index.html");
    }
    if !file.is_file() {
        return Some(format!("{link}: {} does not exist", file.display()));
    }
    if let Some(fragment) = fragment.filter(|f| !f.is_empty())
        && file.extension().is_some_and(|e| e == "html")
    {
        let html = std::fs::read_to_string(&file).unwrap();
        if !html.contains(&format!("id=\"{fragment}\"")) {
            return Some(format!("{link}: {} has no element with id {fragment:?}", file.display()));
        }
    }
    None
}

/// Runs `mdbook build` (as CI does) into a temporary folder, and fails on any warning it prints,
/// then on any link or image in the rendered pages that points at nothing.
#[test]
fn the_rendered_book_builds_without_warnings_and_its_links_resolve() {
    let book = Path::new(env!("CARGO_MANIFEST_DIR")).join("book");
    let out = tempfile::tempdir().unwrap();
    let built = std::process::Command::new(mdbook())
        .arg("build")
        .arg(&book)
        .arg("--dest-dir")
        .arg(out.path())
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run mdbook ({e}): install it with `bash .ci/deps --tests` (cargo install mdbook --version 0.5.4 --locked)")
        });
    let log = String::from_utf8_lossy(&built.stderr).into_owned() + &String::from_utf8_lossy(&built.stdout);
    assert!(built.status.success(), "mdbook build failed:\n{log}");
    let warnings: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("WARN") || l.contains("ERROR") || l.to_lowercase().contains("warning"))
        .collect();
    assert!(warnings.is_empty(), "mdbook build warned:\n{}", warnings.join("\n"));

    let mut broken = Vec::new();
    let mut checked = 0;
    let pages = harness::files_ending(out.path(), "html");
    for page in &pages {
        let html = std::fs::read_to_string(page).unwrap();
        for (line, link) in links_in(&html) {
            checked += 1;
            if let Some(why) = broken_link(out.path(), page, &link) {
                broken.push(format!("{}:{line}: {why}", page.strip_prefix(out.path()).unwrap().display()));
            }
        }
    }
    assert!(
        broken.is_empty(),
        "{} broken links or images in the rendered book:\n{}",
        broken.len(),
        broken.join("\n")
    );
    assert!(
        pages.len() > 8 && checked > 100,
        "the rendered book is nearly empty: {} pages, {checked} links",
        pages.len()
    );
}

#[test]
fn the_link_checker_catches_what_a_reader_would_hit() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    std::fs::create_dir_all(root.join("images")).unwrap();
    std::fs::create_dir_all(root.join("chapters/01")).unwrap();
    std::fs::write(root.join("images/a.png"), b"").unwrap();
    std::fs::write(root.join("chapters/01/main.rs"), b"").unwrap();
    std::fs::write(root.join("other.html"), "<h2 id=\"there\">").unwrap();
    let page = root.join("page.html");
    std::fs::write(&page, "<a href=\"#\">").unwrap();
    let html = "<img src=\"images/a.png\"> <img src=\"images/gone.png\">\n\
                <a href=\"../../chapters/01/main.rs\">x</a> <a href=\"../../chapters/02/main.rs\">\n\
                <a href=\"other.html#there\"> <a href=\"other.html#nowhere\"> <a href=\"https://example.com/x\">\n\
                <a href=\"\">";
    let links = links_in(html);
    assert_eq!(links.len(), 8);
    let results: Vec<bool> = links.iter().map(|(_, link)| broken_link(root, &page, link).is_some()).collect();
    // links_in lists each line's hrefs, then its srcs.
    assert_eq!(links[0].1, "images/a.png");
    assert_eq!(results, [false, true, false, true, false, true, false, true]);
}

/// The workshop's worked solutions are patches against the chapters: each must still apply, or
/// the workshop page sends participants to a patch that fails.
#[test]
fn every_workshop_solution_applies() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("book/src/workshop");
    let mut patches: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "diff"))
        .collect();
    patches.sort();
    assert!(!patches.is_empty(), "no solutions in {}", dir.display());
    let mut failed = Vec::new();
    for patch in &patches {
        let checked = std::process::Command::new("git")
            .current_dir(root)
            .args(["apply", "--check"])
            .arg(patch)
            .output()
            .unwrap_or_else(|e| panic!("cannot run git ({e}): it checks the workshop's patches"));
        if !checked.status.success() {
            failed.push(format!("{}: {}", patch.display(), String::from_utf8_lossy(&checked.stderr).trim()));
        }
    }
    assert!(failed.is_empty(), "workshop solutions that no longer apply:\n{}", failed.join("\n"));
}
