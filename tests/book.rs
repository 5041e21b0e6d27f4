//! The book never drifts from the code: every `{{#include}}` names a file that exists and, where it
//! names an anchor or a line range, something non-empty in it. (mdBook itself silently includes
//! an empty string for a missing anchor.)

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

fn pages(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).flatten() {
        let path = entry.path();
        if path.is_dir() {
            found.extend(pages(&path));
        } else if path.extension().is_some_and(|e| e == "md") {
            found.push(path);
        }
    }
    found
}

#[test]
fn every_include_in_the_book_resolves() {
    let book = Path::new(env!("CARGO_MANIFEST_DIR")).join("book/src");
    let mut count = 0;
    let mut broken = Vec::new();
    for page in pages(&book) {
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
