//! The facts a page quotes from the code stay true: the checks a transcript or a "Checks" table
//! names and the counts it states agree with the chapters' reports (`tests/snapshots/*.snap`,
//! written by the chapter tests from real runs); the report keys, Rust names and command-line
//! flags a page quotes exist, with the defaults and ranges their programs' `--help` and value
//! parsers give; no page runs a `./bin/` that does not exist or cites a tracker's "issue N" that
//! the reader cannot see. Text, and `--help` alone: no GPU, no chapter run, a few seconds.

mod harness;

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// One page of the book: its file name (`03-semaphores.md`), and its text split into prose lines
/// and fenced blocks, each line with its number.
struct Page {
    name: String,
    prose: Vec<(usize, String)>,
    blocks: Vec<Block>,
}

struct Block {
    /// The fence's info string: `sh`, `text`, `console`, `rust` ...
    info: String,
    lines: Vec<(usize, String)>,
    /// The lines of the fences that open and close it.
    fences: (usize, usize),
    /// Whether its lines come from a generated transcript (`{{#include transcripts/...}}`).
    transcript: bool,
}

impl Page {
    fn parse(name: &str, text: &str) -> Page {
        let (mut prose, mut blocks) = (Vec::new(), Vec::new());
        let mut open: Option<Block> = None;
        for (number, line) in text.lines().enumerate() {
            let number = number + 1;
            let fence = line.trim_start().starts_with("```");
            match (&mut open, fence) {
                (None, true) => {
                    let info = line.trim_start().trim_start_matches('`').trim().to_owned();
                    open =
                        Some(Block { info, lines: Vec::new(), fences: (number, number), transcript: false });
                }
                (Some(block), true) => {
                    block.fences.1 = number;
                    blocks.push(open.take().unwrap());
                }
                // A generated transcript (`book/src/transcripts/`): its lines, at the include's.
                (Some(block), false) if line.trim().starts_with("{{#include transcripts/") => {
                    let file = line.trim().trim_start_matches("{{#include ").trim_end_matches("}}");
                    let path = root().join("book/src").join(file);
                    let included =
                        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    block.lines.extend(included.lines().map(|l| (number, l.to_owned())));
                    block.transcript = true;
                }
                (Some(block), false) => block.lines.push((number, line.to_owned())),
                (None, false) => prose.push((number, line.to_owned())),
            }
        }
        Page { name: name.to_owned(), prose, blocks }
    }

    /// `03-semaphores` for a chapter's page and for its deeper page (`03-semaphores-deeper.md`),
    /// `None` for the others.
    fn chapter(&self) -> Option<&str> {
        let stem = self.name.strip_suffix(".md")?;
        let stem = stem.strip_suffix("-deeper").unwrap_or(stem);
        stem.as_bytes().get(..2)?.iter().all(u8::is_ascii_digit).then_some(stem)
    }

    /// Blocks that show a program's output or a command to type (not code listings).
    fn output_blocks(&self) -> impl Iterator<Item = &Block> {
        self.blocks.iter().filter(|b| matches!(b.info.as_str(), "" | "text" | "console" | "sh" | "bash"))
    }
}

/// Every page under `book/src`, by name; `chapters`, `common` and `shaders` there are links to
/// the sources, not pages.
fn pages() -> Vec<Page> {
    let mut files = harness::files_ending(&root().join("book/src"), "md");
    files.sort();
    assert!(files.len() > 10, "book/src has only {} pages: was it moved?", files.len());
    files
        .iter()
        .map(|f| {
            let name = f.strip_prefix(root().join("book/src")).unwrap().to_string_lossy().into_owned();
            Page::parse(&name, &std::fs::read_to_string(f).unwrap())
        })
        .collect()
}

/// Every report snapshot (`tests/snapshots/*.snap`): the JSON after insta's header.
fn snapshots() -> Vec<(String, Value)> {
    let dir = root().join("tests/snapshots");
    let mut found = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_none_or(|e| e != "snap") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let json =
            text.splitn(3, "---\n").nth(2).unwrap_or_else(|| panic!("{}: no insta header", path.display()));
        let report: Value =
            serde_json::from_str(json).unwrap_or_else(|e| panic!("{}: not JSON: {e}", path.display()));
        found.push((path.file_name().unwrap().to_string_lossy().into_owned(), report));
    }
    assert!(found.len() > 10, "only {} report snapshots in {}", found.len(), dir.display());
    found
}

/// What the reports say about each chapter's checks.
struct Checks {
    /// Per chapter: the checks every one of its snapshots has (reported on every run).
    always: BTreeMap<String, BTreeSet<String>>,
    /// Per chapter: the number of checks each of its snapshots has.
    counts: BTreeMap<String, BTreeSet<usize>>,
    /// Every check name a report or the code knows (the conditional ones are string literals in
    /// the sources, e.g. `no_fd_growth_across_resizes`).
    known: BTreeSet<String>,
    /// The names that are checks for sure: a report's, or a `check("name"` in the sources.
    named: BTreeSet<String>,
}

fn checks(snapshots: &[(String, Value)], sources: &Sources) -> Checks {
    let mut always: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut counts: BTreeMap<String, BTreeSet<usize>> = BTreeMap::new();
    let mut known = sources.literals.clone();
    let mut named: BTreeSet<String> = sources
        .text
        .values()
        .flat_map(|text| text.split("check(\"").skip(1))
        .filter_map(|rest| rest.split('"').next())
        .filter(|name| is_check_name(name))
        .map(str::to_owned)
        .collect();
    for (_, report) in snapshots {
        let Some(chapter) = report["chapter"].as_str() else { continue };
        let names: BTreeSet<String> =
            report["checks"].as_object().map(|c| c.keys().cloned().collect()).unwrap_or_default();
        known.extend(names.iter().cloned());
        named.extend(names.iter().cloned());
        counts.entry(chapter.to_owned()).or_default().insert(names.len());
        always.entry(chapter.to_owned()).and_modify(|a| a.retain(|n| names.contains(n))).or_insert(names);
    }
    Checks { always, counts, known, named }
}

/// The Rust sources: every identifier, and every string literal that looks like a name.
struct Sources {
    words: BTreeSet<String>,
    literals: BTreeSet<String>,
    /// Per folder (`chapters/03-semaphores`, `common`): the text of its `.rs` files.
    text: BTreeMap<String, String>,
}

fn sources() -> Sources {
    fn walk(dir: &Path, found: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(&path, found);
            } else if path.extension().is_some_and(|e| e == "rs") {
                found.push(path);
            }
        }
    }
    let mut files = Vec::new();
    for dir in ["chapters", "common", "xtask", "tests"] {
        walk(&root().join(dir), &mut files);
    }
    let (mut words, mut literals, mut text) =
        (BTreeSet::new(), BTreeSet::new(), BTreeMap::<String, String>::new());
    for file in files {
        let source = std::fs::read_to_string(&file).unwrap();
        let relative = file.strip_prefix(root()).unwrap();
        let mut parts = relative.components().map(|c| c.as_os_str().to_string_lossy().into_owned());
        let first = parts.next().unwrap();
        let folder = if first == "chapters" { format!("chapters/{}", parts.next().unwrap()) } else { first };
        words.extend(identifiers(&source));
        for piece in source.split('"').skip(1).step_by(2) {
            if !piece.is_empty()
                && piece.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
            {
                literals.insert(piece.to_owned());
            }
        }
        let entry = text.entry(folder).or_default();
        entry.push_str(&source);
        entry.push('\n');
    }
    assert!(words.contains("HandOver") || words.len() > 1000, "the sources look empty");
    Sources { words, literals, text }
}

fn identifiers(text: &str) -> impl Iterator<Item = String> + '_ {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| !w.is_empty())
        .map(str::to_owned)
}

/// The inline code spans (`...`) of a prose line.
fn code_spans(line: &str) -> Vec<&str> {
    line.split('`').skip(1).step_by(2).collect()
}

fn is_check_name(s: &str) -> bool {
    s.contains('_')
        && s.starts_with(|c: char| c.is_ascii_lowercase())
        && s.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
}

/// `six` -> 6: the counts pages spell out.
fn count_of(word: &str) -> Option<usize> {
    const WORDS: [&str; 17] = [
        "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven",
        "twelve", "thirteen", "fourteen", "fifteen", "sixteen",
    ];
    word.parse().ok().or_else(|| WORDS.iter().position(|w| w.eq_ignore_ascii_case(word)))
}

/// Where a page's output block disagrees with what the chapter reports. A block that ends a run
/// (`NN-slug: all N checks passed`, or `error: K check(s) failed: ...`) lists every check the
/// chapter reports on every run, and as many as it says; every check it names exists.
fn transcript_errors(page: &Page, checks: &Checks) -> Vec<String> {
    let mut errors = Vec::new();
    for block in page.output_blocks() {
        let mut listed = Vec::new();
        let mut chapter = page.chapter().map(str::to_owned);
        let mut ends_a_run = false;
        for (line_number, line) in &block.lines {
            let at = format!("{}:{line_number}", page.name);
            let line = line.trim();
            // A transcript of several runs: each run lists its own checks.
            if line.starts_with("$ ") {
                errors.extend(left_out(
                    page,
                    &block.lines,
                    (ends_a_run, chapter.as_deref()),
                    &listed,
                    checks,
                ));
                (listed, ends_a_run) = (Vec::new(), false);
            }
            if let Some(name) = line.strip_prefix("[ ok ] ").or_else(|| line.strip_prefix("[FAIL] ")) {
                listed.push(name.trim().to_owned());
            } else if let Some((slug, rest)) = line.split_once(": all ")
                && let Some(count) = rest.strip_suffix(" checks passed")
            {
                let count = count_of(count).unwrap_or(usize::MAX);
                if count != listed.len() {
                    errors
                        .push(format!("{at}: says {count} checks passed, but lists {} above", listed.len()));
                }
                // A second process of the chapter's own run (chapter 14's viewer, `<chapter>
                // viewer`) prints its summary first: its checks, each known, come back in the
                // chapter's report under other names, and the chapter's list starts again.
                if let Some(of) = slug.strip_suffix(" viewer")
                    && checks.counts.contains_key(of)
                {
                    errors.extend(left_out(page, &block.lines, (false, None), &listed, checks));
                    listed = Vec::new();
                    continue;
                }
                ends_a_run = true;
                chapter = Some(slug.to_owned());
                match checks.counts.get(slug) {
                    Some(counts) if counts.iter().any(|c| count >= *c) => {}
                    Some(counts) => {
                        errors.push(format!("{at}: {slug} reports {counts:?} checks, not {count}"))
                    }
                    None => errors.push(format!("{at}: no report snapshot for {slug}")),
                }
            } else if let Some(rest) = line.strip_prefix("error: ")
                && let Some((count, names)) = rest.split_once(" check(s) failed: ")
            {
                ends_a_run = true;
                let names: Vec<&str> = names.split(", ").map(str::trim).collect();
                if count_of(count) != Some(names.len()) {
                    errors.push(format!("{at}: says {count} check(s) failed and names {}", names.len()));
                }
                for name in names {
                    if !checks.known.contains(name) {
                        errors.push(format!("{at}: `{name}` failed, but no report or source has that check"));
                    }
                }
            }
        }
        errors.extend(left_out(page, &block.lines, (ends_a_run, chapter.as_deref()), &listed, checks));
    }
    errors
}

/// What is wrong with the checks one run of a transcript `listed`: a name no report or source
/// has, and, where the run ended (`ends_a_run`), a check its chapter reports on every run.
fn left_out(
    page: &Page,
    lines: &[(usize, String)],
    (ends_a_run, chapter): (bool, Option<&str>),
    listed: &[String],
    checks: &Checks,
) -> Vec<String> {
    let mut errors = Vec::new();
    let first = lines.first().map_or(0, |l| l.0);
    for name in listed {
        if !checks.known.contains(name) {
            errors.push(format!(
                "{}:{first}: the transcript shows `{name}`, which no report or source has",
                page.name
            ));
        }
    }
    if ends_a_run && let Some(always) = chapter.and_then(|c| checks.always.get(c)) {
        for name in always.iter().filter(|n| !listed.contains(n)) {
            errors.push(format!(
                "{}:{first}: the run's transcript leaves out `{name}`, which {} reports on every run",
                page.name,
                chapter.unwrap()
            ));
        }
    }
    errors
}

#[test]
fn transcripts_show_the_checks_the_chapters_report() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    let errors: Vec<String> = pages().iter().flat_map(|p| transcript_errors(p, &checks)).collect();
    assert!(errors.is_empty(), "transcripts that no longer match the chapters:\n{}", errors.join("\n"));
}

/// The paragraph that introduces a transcript says what its run shows: a check it names passes
/// in it (`[ ok ] name`), or fails in it (`[FAIL] name`) where the sentence naming it says it
/// fails. So a page's command makes the checks the page names, and a "try this" that says a check
/// fails makes it fail (the transcripts themselves are runs, `tests/transcripts.rs`). Only the
/// names of checks count: those a report has, or a `check("name", ...)` in the sources.
fn transcript_claim_errors(page: &Page, checks: &Checks) -> Vec<String> {
    let mut errors = Vec::new();
    for block in page.blocks.iter().filter(|b| b.transcript) {
        // The prose paragraph that ends just before the block's opening fence, past the blank
        // line between them.
        let mut at = block.fences.0 - 1;
        while at > 0 && page.prose.iter().any(|(n, l)| *n == at && l.trim().is_empty()) {
            at -= 1;
        }
        let mut lines = Vec::new();
        while let Some((n, line)) = page.prose.iter().find(|(n, _)| *n == at) {
            if line.trim().is_empty() || line.starts_with('#') {
                break;
            }
            lines.push((*n, line.as_str()));
            at -= 1;
        }
        lines.reverse();
        let Some(&(number, _)) = lines.first() else { continue };
        let paragraph: Vec<&str> = lines.iter().map(|(_, l)| *l).collect();
        let shows =
            |mark: &str, name: &str| block.lines.iter().any(|(_, l)| l.trim() == format!("{mark} {name}"));
        // One sentence at a time: "fails" speaks of the checks of its own sentence.
        for sentence in paragraph.join(" ").split(". ") {
            let fails = sentence.contains("fails") || sentence.contains("failed");
            for name in code_spans(sentence).into_iter().filter(|n| checks.named.contains(*n)) {
                let (mark, said) = if fails { ("[FAIL]", "fails") } else { ("[ ok ]", "passes") };
                if !shows(mark, name) {
                    errors.push(format!(
                        "{}:{number}: says `{name}` {said} in the run it shows next, whose transcript has no \
                         `{mark} {name}`",
                        page.name
                    ));
                }
            }
        }
    }
    errors
}

#[test]
fn the_runs_a_page_shows_make_the_checks_it_names() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    let errors: Vec<String> = pages().iter().flat_map(|p| transcript_claim_errors(p, &checks)).collect();
    assert!(errors.is_empty(), "pages that say a run makes a check it does not:\n{}", errors.join("\n"));
}

#[test]
fn the_claim_check_sees_what_it_must_refuse() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    // A paragraph on line 1, the transcript's fences on lines 3 and 5.
    let page = |before: &str| Page {
        name: "99-test.md".into(),
        prose: vec![(1, before.to_owned()), (2, String::new())],
        blocks: vec![Block {
            info: "console".into(),
            lines: ["$ run", "  [ ok ] no_fd_leaked", "  [FAIL] ao_within_0_and_1"]
                .map(|l| (4, l.to_owned()))
                .into(),
            fences: (3, 5),
            transcript: true,
        }],
    };
    let errors = |before: &str| transcript_claim_errors(&page(before), &checks).len();
    // Said and shown; said to pass but failed; said to fail but passed.
    assert_eq!(errors("It checks `no_fd_leaked`. Then `ao_within_0_and_1` fails."), 0);
    assert_eq!(errors("Here `ao_within_0_and_1` holds."), 1);
    assert_eq!(errors("Here `no_fd_leaked` fails."), 1);
}

/// A chapter page's "## Checks" table lists every check its report always has, and only checks
/// that exist.
fn checks_table_errors(page: &Page, checks: &Checks) -> Vec<String> {
    let Some(chapter) = page.chapter() else { return Vec::new() };
    let Some(start) = page.prose.iter().position(|(_, l)| l.trim() == "## Checks") else { return Vec::new() };
    let mut listed = BTreeSet::new();
    let mut errors = Vec::new();
    for (number, line) in page.prose[start + 1..].iter().take_while(|(_, l)| !l.starts_with("## ")) {
        let Some(first_cell) = line.strip_prefix('|').and_then(|l| l.split('|').next()) else { continue };
        for name in code_spans(first_cell).into_iter().filter(|n| is_check_name(n)) {
            if !checks.known.contains(name) {
                errors.push(format!(
                    "{}:{number}: `{name}` is in the Checks table, but no report or source has it",
                    page.name
                ));
            }
            listed.insert(name.to_owned());
        }
    }
    for name in checks.always.get(chapter).into_iter().flatten().filter(|n| !listed.contains(*n)) {
        errors.push(format!(
            "{}: the Checks table leaves out `{name}`, which {chapter} reports on every run",
            page.name
        ));
    }
    errors
}

#[test]
fn checks_tables_list_every_check_the_report_has() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    let pages = pages();
    let tables =
        pages.iter().filter(|p| p.chapter().is_some() && p.prose.iter().any(|(_, l)| l == "## Checks"));
    assert!(tables.count() >= 8, "chapter pages 01-08 each have a ## Checks table");
    let errors: Vec<String> = pages.iter().flat_map(|p| checks_table_errors(p, &checks)).collect();
    assert!(errors.is_empty(), "Checks tables that disagree with the reports:\n{}", errors.join("\n"));
}

/// "all six checks pass" in a page's prose: the count its chapter reports. The chapter is the
/// page's own, or on other pages the last `NN-slug` named before it in the paragraph.
fn stated_count_errors(page: &Page, checks: &Checks) -> Vec<String> {
    let mut errors = Vec::new();
    let mut named: Option<String> = None;
    for (number, line) in &page.prose {
        if line.trim().is_empty() {
            named = None;
        }
        let words: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || matches!(c, '`' | ',' | '.' | ':' | '(' | ')'))
            .filter(|w| !w.is_empty())
            .collect();
        for (i, word) in words.iter().enumerate() {
            if checks.counts.contains_key(*word) {
                named = Some((*word).to_owned());
            }
            if word.eq_ignore_ascii_case("all")
                && let (Some(count), Some(next)) =
                    (words.get(i + 1).and_then(|w| count_of(w)), words.get(i + 2))
                && next.starts_with("check")
            {
                let Some(chapter) = page.chapter().map(str::to_owned).or_else(|| named.clone()) else {
                    continue;
                };
                let counts = &checks.counts[&chapter];
                if !counts.contains(&count) {
                    errors.push(format!(
                        "{}:{number}: says {chapter} has {count} checks; its reports have {counts:?}",
                        page.name
                    ));
                }
            }
        }
    }
    errors
}

#[test]
fn counts_of_checks_in_the_prose_match_the_reports() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    let errors: Vec<String> = pages().iter().flat_map(|p| stated_count_errors(p, &checks)).collect();
    assert!(errors.is_empty(), "counts of checks that disagree with the reports:\n{}", errors.join("\n"));
}

/// Does `path` (`validation.layer`) lead somewhere in `report`? Arrays: in any element.
fn has_path(value: &Value, path: &[&str]) -> bool {
    match (path.split_first(), value) {
        (None, _) => true,
        (Some((first, rest)), Value::Object(map)) => map.get(*first).is_some_and(|v| has_path(v, rest)),
        (Some(_), Value::Array(items)) => items.iter().any(|v| has_path(v, path)),
        _ => false,
    }
}

fn all_keys(value: &Value, into: &mut BTreeSet<String>) {
    match value {
        Value::Object(map) => {
            for (key, value) in map {
                into.insert(key.clone());
                all_keys(value, into);
            }
        }
        Value::Array(items) => items.iter().for_each(|v| all_keys(v, into)),
        _ => {}
    }
}

/// Report keys a page quotes: `validation.layer` (a path into an object of the report), `"sync":`
/// (a key), `raster_median` (a timing): each exists in a report, or (for timings and keys only
/// some runs have) in the code that writes it.
fn report_key_errors(page: &Page, snapshots: &[(String, Value)], sources: &Sources) -> Vec<String> {
    let mut keys = BTreeSet::new();
    let mut timings = BTreeSet::new();
    for (_, report) in snapshots {
        all_keys(report, &mut keys);
        if let Some(t) = report["timings_ms"].as_object() {
            timings.extend(t.keys().map(|k| k.rsplit('.').next().unwrap().to_owned()));
        }
    }
    // Top-level fields that hold objects: a dotted span starting with one is a path into it.
    let objects: BTreeSet<&str> = snapshots
        .iter()
        .flat_map(|(_, r)| r.as_object().unwrap().iter())
        .filter(|(_, v)| v.is_object() || v.is_array())
        .map(|(k, _)| k.as_str())
        .collect();
    let mut errors = Vec::new();
    for (number, line) in &page.prose {
        for span in code_spans(line) {
            let at = format!("{}:{number}", page.name);
            let path: Vec<&str> = span.split('.').collect();
            let file = ["rs", "md", "json", "png", "svg", "spv"].contains(path.last().unwrap());
            if path.len() > 1
                && !file
                && objects.contains(path[0])
                && path.iter().all(|p| {
                    !p.is_empty()
                        && p.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
                })
                && !snapshots.iter().any(|(_, r)| has_path(r, &path))
            {
                errors.push(format!("{at}: `{span}` is not in any chapter's report"));
            }
            if let Some(key) = span.strip_prefix('"').and_then(|s| s.split_once("\":")).map(|(k, _)| k)
                && !keys.contains(key)
                && !sources.literals.contains(key)
            {
                errors.push(format!("{at}: `{span}`: no report has the key {key:?}"));
            }
            if is_check_name(span)
                && (span.ends_with("_median") || span.ends_with("_p95"))
                && !timings.contains(span)
                && !sources.words.contains(span)
            {
                errors.push(format!("{at}: `{span}` is not a timing any report has"));
            }
        }
    }
    errors
}

#[test]
fn report_keys_the_pages_quote_exist() {
    let (snapshots, sources) = (snapshots(), sources());
    let errors: Vec<String> =
        pages().iter().flat_map(|p| report_key_errors(p, &snapshots, &sources)).collect();
    assert!(errors.is_empty(), "report keys the book quotes that no report has:\n{}", errors.join("\n"));
}

/// Names the sources never spell that way, but that pages rightly quote: the specification's and
/// other crates' spellings.
const NAMES_FROM_ELSEWHERE: &[&str] = &[
    // Vulkan's names for ash's `ACCELERATION_STRUCTURE_READ_KHR`, `BuildAccelerationStructureModeKHR::UPDATE` ...
    "ACCELERATION_STRUCTURE_READ",
    "ACCELERATION_STRUCTURE_WRITE",
    "BUILD_MODE_UPDATE",
    "COLOR_ATTACHMENT_OUTPUT",
    "DMA_BUF",
    "OPAQUE_WIN32",
    // An environment variable of Mesa's.
    "DRI_PRIME",
    // GLSL's ray flag `gl_RayFlagsTerminateOnFirstHitEXT`.
    "TerminateOnFirstHit",
    // glow's own type names (the sources use its aliases `glow::Buffer`, `glow::Texture`).
    "NativeBuffer",
    "NativeTexture",
];

/// Rust names a page quotes: `common::interop::handoff::HandOver`, `Sync::hand_over`, `SharedImage`,
/// `BUFFER_IMPORT_SLACK`. Each part must be an identifier the sources use (or a name from the
/// specification, `Vk...`, or from the list above).
fn rust_name_errors(page: &Page, sources: &Sources) -> Vec<String> {
    let mut errors = Vec::new();
    for (number, line) in &page.prose {
        for span in code_spans(line) {
            let span = span.trim().trim_end_matches("()");
            if span.is_empty() || !span.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let parts: Vec<&str> = span.split("::").collect();
            if parts.iter().any(|p| p.is_empty()) {
                continue;
            }
            let camel = |p: &&str| {
                p.starts_with(|c: char| c.is_ascii_uppercase()) && p.chars().any(|c| c.is_ascii_lowercase())
            };
            let screaming = |p: &&str| {
                p.contains('_')
                    && p.chars().all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
                    && !["GL_", "VK_", "EGL_"].iter().any(|prefix| p.starts_with(prefix))
            };
            let rust =
                parts[0] == "common" || parts.iter().any(camel) || (parts.len() == 1 && screaming(&parts[0]));
            // Spec names (`VkExportMemoryAllocateInfo`, `GL_EXT_external_objects`) are not Rust names.
            let spec = |p: &&str| ["Vk", "GL_", "VK_", "EGL_"].iter().any(|prefix| p.starts_with(prefix));
            if !rust || parts.iter().any(spec) {
                continue;
            }
            for part in &parts {
                // `glow::`, `ash::`, `std::` ... : crates the sources use by those names.
                if !sources.words.contains(*part) && !NAMES_FROM_ELSEWHERE.contains(part) {
                    errors.push(format!("{}:{number}: `{span}`: the sources have no `{part}`", page.name));
                }
            }
        }
    }
    errors
}

#[test]
fn rust_names_the_pages_quote_exist() {
    let sources = sources();
    let errors: Vec<String> = pages().iter().flat_map(|p| rust_name_errors(p, &sources)).collect();
    assert!(errors.is_empty(), "names the book quotes that the code does not have:\n{}", errors.join("\n"));
}

/// Every `cargo run` a page prints (in a block or inline) names a binary of the workspace, and
/// every flag after its `--` is one that binary's folder or `common` declares (a clap field of
/// that name, or `long = "..."`); `cargo test --test NAME` names a file in `tests/`. No page runs
/// anything from a `bin/` folder, which does not exist.
fn command_errors(page: &Page, bins: &BTreeSet<String>, sources: &Sources) -> Vec<String> {
    let mut errors = Vec::new();
    let mut commands: Vec<(usize, String)> = Vec::new();
    for block in page.output_blocks() {
        for (number, line) in &block.lines {
            commands.push((*number, line.trim().trim_start_matches("$ ").to_owned()));
        }
    }
    // The other programs the page's commands run (`convergence`, where a page measures its
    // chapter's frame with the tool): a flag the page quotes alone may be one of theirs.
    let others: BTreeSet<String> = commands
        .iter()
        .filter_map(|(_, c)| c.split_whitespace().skip_while(|w| *w != "--bin").nth(1).map(str::to_owned))
        .filter(|b| Some(b.as_str()) != page.chapter())
        .collect();
    for (number, line) in &page.prose {
        for span in code_spans(line) {
            // A chapter page quoting its own flags alone (`--headless --size 320x240`): as if typed
            // after its `cargo run --bin NN-slug --`.
            match page.chapter() {
                Some(bin) if span.starts_with("--") => {
                    commands.push((*number, format!("cargo run --bin {bin} -- {span}")))
                }
                _ => commands.push((*number, span.to_owned())),
            }
        }
    }
    for (number, command) in commands {
        let at = format!("{}:{number}", page.name);
        if command.contains("./bin/") {
            errors.push(format!(
                "{at}: `{command}` runs from ./bin/, which does not exist: use cargo run --release --bin"
            ));
        }
        let words: Vec<&str> = command.split_whitespace().collect();
        for (i, pair) in words.windows(2).enumerate() {
            if pair == ["cargo", "run"] || pair == ["cargo", "test"] {
                let rest = &words[i + 2..];
                let end = rest
                    .iter()
                    .position(|w| matches!(*w, "&&" | "||" | ";" | "|" | ">" | "2>" | "#"))
                    .unwrap_or(rest.len());
                let rest = &rest[..end];
                let value =
                    |flag: &str| rest.iter().position(|w| *w == flag).and_then(|p| rest.get(p + 1)).copied();
                if let Some(bin) = value("--bin") {
                    if !bin.chars().all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-') {
                        continue; // a placeholder: `--bin NAME`, `--bin …`
                    }
                    if !bins.contains(bin) {
                        errors.push(format!("{at}: `--bin {bin}`: the workspace has no such binary"));
                        continue;
                    }
                    let Some(dashes) = rest.iter().position(|w| *w == "--") else { continue };
                    let mut texts = sources_of(bin, sources);
                    // A flag quoted alone on a chapter page: the chapter's, or a program's whose
                    // command the page prints.
                    if Some(bin) == page.chapter() && !command.starts_with("cargo run --release") {
                        texts.extend(others.iter().flat_map(|other| sources_of(other, sources)));
                    }
                    for flag in rest[dashes + 1..].iter().filter_map(|w| w.strip_prefix("--")) {
                        let flag = flag.split('=').next().unwrap();
                        if flag.is_empty()
                            || !flag.chars().all(|c| c.is_ascii_lowercase() || c == '-')
                            || FLAGS_OF_OTHER_TOOLS.contains(&flag)
                        {
                            continue;
                        }
                        let field = flag.replace('-', "_");
                        let declared = texts.iter().any(|text| {
                            text.contains(&format!("long = \"{flag}\"")) || declares_field(text, &field)
                        });
                        if !declared {
                            errors.push(format!(
                                "{at}: `--{flag}`: {bin} declares no such flag (chapters/{bin}/ or common/)"
                            ));
                        }
                    }
                }
                if let Some(test) = value("--test")
                    && !root().join("tests").join(format!("{test}.rs")).is_file()
                {
                    errors.push(format!("{at}: `--test {test}`: there is no tests/{test}.rs"));
                }
            }
        }
    }
    errors
}

/// Options a chapter page quotes for another tool: NVRTC's (chapter 11 compiles its CUDA with them).
const FLAGS_OF_OTHER_TOOLS: &[&str] = &["gpu-architecture", "fmad"];

/// Does `text` declare `--name` as a clap flag: a field `name: ...` under an `#[arg(long ...)]`
/// (between them only doc comments and other attributes)?
fn declares_field(text: &str, name: &str) -> bool {
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    lines.iter().enumerate().any(|(i, line)| {
        let field = line.strip_prefix("pub ").unwrap_or(line);
        field.strip_prefix(name).is_some_and(|rest| rest.starts_with(':') && !rest.starts_with("::"))
            && lines[..i]
                .iter()
                .rev()
                .take_while(|l| l.starts_with("#[") || l.starts_with("//"))
                .any(|l| l.starts_with("#[arg(") && l.contains("long"))
    })
}

/// The sources a binary is built from: its folder, the files of other chapters it includes with
/// `#[path = "../NN-slug/..."]`, the chapters' libraries it uses (and theirs), and `common`.
fn sources_of<'a>(bin: &str, sources: &'a Sources) -> Vec<&'a str> {
    let own = sources.text.get(&format!("chapters/{bin}")).map_or("", String::as_str);
    let mut found = vec![own, sources.text.get("common").map_or("", String::as_str)];
    for piece in own.split("#[path = \"../").skip(1) {
        if let Some(folder) = piece.split('/').next()
            && let Some(text) = sources.text.get(&format!("chapters/{folder}"))
        {
            found.push(text);
        }
    }
    let mut folders: Vec<&str> = Vec::new();
    let mut uses: Vec<&str> = vec![own];
    while let Some(text) = uses.pop() {
        for (library, folder) in chapter_libraries() {
            if text.contains(&format!("{library}::")) && !folders.contains(&folder) {
                folders.push(folder);
                if let Some(library_text) = sources.text.get(&format!("chapters/{folder}")) {
                    found.push(library_text);
                    uses.push(library_text);
                }
            }
        }
    }
    found
}

/// The chapters that are libraries too, as the top-level Cargo.toml depends on them:
/// (`fast_frame`, `12-fast-frame`) for `fast_frame = { package = "...", path = "chapters/12-fast-frame" }`.
fn chapter_libraries() -> Vec<(&'static str, &'static str)> {
    static LIBRARIES: std::sync::OnceLock<Vec<(&'static str, &'static str)>> = std::sync::OnceLock::new();
    LIBRARIES
        .get_or_init(|| {
            let manifest = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
            let found: Vec<(&'static str, &'static str)> = manifest
                .lines()
                .filter_map(|line| {
                    let (name, rest) = line.split_once(" = {")?;
                    let folder = rest.split("path = \"chapters/").nth(1)?.split('"').next()?;
                    Some((&*name.trim().to_owned().leak(), &*folder.to_owned().leak()))
                })
                .collect();
            assert!(
                found.iter().any(|(name, _)| *name == "fast_frame"),
                "chapter libraries in Cargo.toml: {found:?}"
            );
            found
        })
        .clone()
}

#[test]
fn printed_commands_name_real_binaries_and_flags() {
    // The root package's binaries, and chapter 15's and 16's (packages of their own: they build
    // wgpu and the picture decoders).
    let mut manifest = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    manifest += &std::fs::read_to_string(root().join("chapters/15-wgpu/Cargo.toml")).unwrap();
    manifest += &std::fs::read_to_string(root().join("chapters/16-textures/Cargo.toml")).unwrap();
    let bins: BTreeSet<String> = manifest
        .split("[[bin]]")
        .skip(1)
        .filter_map(|section| section.split("name = \"").nth(1)?.split('"').next().map(str::to_owned))
        .collect();
    assert!(bins.contains("01-exportable-memory") && bins.len() >= 11, "binaries in Cargo.toml: {bins:?}");
    let sources = sources();
    let errors: Vec<String> = pages().iter().flat_map(|p| command_errors(p, &bins, &sources)).collect();
    assert!(errors.is_empty(), "commands the book prints that cannot run as printed:\n{}", errors.join("\n"));
}

/// The crates running.md says the release profile leaves unoptimised (`Cargo.toml`'s table,
/// included by anchor) are in the build: after an update that drops or renames one, cargo only
/// warns that the name matches nothing, and the page would name a crate the build no longer has.
#[test]
fn unoptimised_crates_are_in_the_build() {
    let manifest = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let lock = std::fs::read_to_string(root().join("Cargo.lock")).unwrap();
    let table = manifest.split("# ANCHOR: unoptimised").nth(1).and_then(|t| t.split("# ANCHOR_END").next());
    let table = table.expect("Cargo.toml's table of unoptimised crates (anchor `unoptimised`)");
    let names: Vec<&str> = table.lines().filter_map(|l| l.split_once(" = {")).map(|(name, _)| name).collect();
    assert!(names.len() >= 8, "crates in the table: {names:?}");
    let missing: Vec<_> = names.iter().filter(|n| !lock.contains(&format!("name = \"{n}\"\n"))).collect();
    assert!(missing.is_empty(), "Cargo.toml leaves {missing:?} unoptimised, which Cargo.lock does not have");
}

/// "issue 10": the reader has no issue tracker; a page says what the goal or field is instead.
fn issue_errors(page: &Page) -> Vec<String> {
    let mut errors = Vec::new();
    let lines = page.prose.iter().chain(page.blocks.iter().flat_map(|b| b.lines.iter()));
    for (number, line) in lines {
        let lower = line.to_ascii_lowercase();
        let words: Vec<&str> =
            lower.split(|c: char| !c.is_ascii_alphanumeric() && c != '#').filter(|w| !w.is_empty()).collect();
        for pair in words.windows(2) {
            let numbered = pair[1].trim_start_matches('#');
            if (pair[0] == "issue" || pair[0] == "issues")
                && !numbered.is_empty()
                && numbered.chars().all(|c| c.is_ascii_digit())
            {
                errors.push(format!(
                    "{}:{number}: cites \"{} {}\": say what it is instead",
                    page.name, pair[0], pair[1]
                ));
            }
        }
    }
    errors
}

#[test]
fn no_page_cites_an_issue_number() {
    let errors: Vec<String> = pages().iter().flat_map(issue_errors).collect();
    assert!(errors.is_empty(), "pages that cite an issue the reader cannot see:\n{}", errors.join("\n"));
}

/// Where prose cites another chapter ("chapter 08", "Chapter 07's") without linking it: a
/// reader should be one click from what the page builds on. Headings, code, pictures' alt text
/// and a table row's label ("| chapter 08, zero-copy |", a row of measurements) are not
/// citations; a page's own chapter needs no link.
fn unlinked_chapter_errors(page: &Page) -> Vec<String> {
    let own = page.chapter().map(|c| &c[..2]);
    let mut errors = Vec::new();
    for (number, line) in &page.prose {
        let trimmed = line.trim_start();
        if trimmed.starts_with('#') || trimmed.starts_with("![") || trimmed.starts_with("| chapter ") {
            continue;
        }
        // Outside code spans and links: the even pieces between backticks, then the text
        // outside `[...](...)`.
        for (i, piece) in line.split('`').enumerate() {
            if i % 2 == 1 {
                continue;
            }
            let mut text = String::new();
            let mut rest = piece;
            while let Some(start) = rest.find('[') {
                text.push_str(&rest[..start]);
                match rest[start..]
                    .find("](")
                    .and_then(|mid| rest[start + mid..].find(')').map(|end| start + mid + end))
                {
                    Some(end) => rest = &rest[end + 1..],
                    None => {
                        rest = &rest[start + 1..];
                    }
                }
            }
            text.push_str(rest);
            let words: Vec<&str> = text.split_whitespace().collect();
            for pair in words.windows(2) {
                let cited = pair[1].get(..2).filter(|n| n.chars().all(|c| c.is_ascii_digit()));
                let followed = pair[1][cited.map_or(0, |_| 2)..].chars().next();
                if pair[0].eq_ignore_ascii_case("chapter")
                    && let Some(n) = cited
                    && !followed.is_some_and(|c| c.is_ascii_digit())
                    && Some(n) != own
                {
                    errors.push(format!("{}:{number}: cites \"chapter {n}\" without a link", page.name));
                }
            }
        }
    }
    errors
}

/// The pages that link every chapter they cite. (Chapter 12's two pages so far; a page joins the
/// list once its citations are links.)
const PAGES_THAT_LINK_CHAPTERS: &[&str] = &["12-fast-frame.md", "12-fast-frame-deeper.md"];

#[test]
fn cited_chapters_are_links() {
    let pages = pages();
    let mut errors = Vec::new();
    for name in PAGES_THAT_LINK_CHAPTERS {
        let page = pages.iter().find(|p| p.name == *name).unwrap_or_else(|| panic!("no page {name}"));
        errors.extend(unlinked_chapter_errors(page));
    }
    assert!(errors.is_empty(), "chapters cited without a link:\n{}", errors.join("\n"));
}

#[test]
fn the_chapter_link_check_catches_a_bare_citation() {
    let text = "As [chapter 08](08-composite.md) does, and as chapter 07's shader does.\n\
                `chapter 05` in code, chapter 12 itself.\n## As in chapter 09\n| chapter 08, zero-copy | 1 ms |\n";
    let errors = unlinked_chapter_errors(&Page::parse("12-fast-frame.md", text));
    assert_eq!(errors, ["12-fast-frame.md:1: cites \"chapter 07\" without a link"]);
}

/// The introduction's "eleven small programs": one for each chapter folder.
#[test]
fn the_introduction_counts_the_chapters() {
    let chapters = std::fs::read_dir(root().join("chapters"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().as_bytes()[..2].iter().all(u8::is_ascii_digit))
        .count();
    let intro = std::fs::read_to_string(root().join("book/src/introduction.md")).unwrap();
    let stated = intro
        .split_once(" small programs")
        .and_then(|(before, _)| before.split_whitespace().last())
        .and_then(count_of)
        .expect("the introduction says how many small programs the book builds");
    assert_eq!(
        stated, chapters,
        "the introduction counts {stated} programs; chapters/ has {chapters} chapters"
    );
}

/// The README's run command installs only what a chapter needs (`bash .ci/deps`, no mdBook); its
/// test command installs what the tests need too (`--tests`) and runs `.ci/test` (formatting,
/// clippy, every test), and CI (`.ci/run`) runs that test command verbatim.
#[test]
fn the_readme_run_command_installs_only_what_chapters_need() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let deps = std::fs::read_to_string(root().join(".ci/deps")).unwrap();
    let ci = std::fs::read_to_string(root().join(".ci/run")).unwrap();
    let commands: Vec<&str> = readme.lines().filter(|l| l.starts_with("bash .ci/deps")).collect();
    let run = commands.iter().find(|l| l.contains("cargo run")).expect("the README's run command");
    let test = commands.iter().find(|l| l.contains(".ci/test")).expect("the README's test command");
    assert!(run.starts_with("bash .ci/deps && "), "the run command installs more than chapters need: {run}");
    assert!(
        test.starts_with("bash .ci/deps --tests && "),
        "the test command must install mdBook and g++: {test}"
    );
    assert!(
        ci.lines().any(|l| l.starts_with(*test)),
        ".ci/run does not run the README's test command `{test}`"
    );
    assert!(deps.contains("--tests)"), ".ci/deps takes no --tests");
    let checks = std::fs::read_to_string(root().join(".ci/test")).unwrap();
    for check in [
        "cargo fmt --all --check",
        "cargo clippy --workspace --all-targets --locked -- -D warnings",
        "cargo test --workspace --locked",
    ] {
        assert!(checks.lines().any(|l| l.starts_with(check)), ".ci/test does not run `{check}`");
    }
    // mdBook only with --tests: every call to install it is guarded.
    let unguarded: Vec<&str> = deps
        .lines()
        .filter(|l| l.contains("install_mdbook") && !l.contains("install_mdbook()") && !l.contains("$tests"))
        .collect();
    assert!(unguarded.is_empty(), ".ci/deps installs mdBook without --tests: {unguarded:?}");
}

/// snake_case names a page quotes that are neither in the sources nor in a report, rightly: other
/// projects' and crates' names, and names a page quotes as history.
const SNAKE_NAMES_FROM_ELSEWHERE: &[&str] = &[
    "memfd_create",           // Linux
    "gl_vk_raytrace_interop", // NVIDIA's sample
    "gl_vk_simple_interop",   // NVIDIA's sample
    "create_vertex_array",    // glow's, the call chapter 02 warns against
    "look_at",                // glam's family of functions
    "sm_90",                  // CUDA's architecture name
    "raster_gpu",             // 05: the timing's name before `GlPassTimer`
    "offset_ray",             // 07: Ray Tracing Gems' function, the shader's before the fix
];

/// Every snake_case name a page quotes in prose (`hand_over_layouts_agree`, `memory_row_0`,
/// `timings_ms`) is an identifier of the sources or shaders, or a key of a report.
#[test]
fn snake_case_names_the_pages_quote_exist() {
    let (snapshots, sources) = (snapshots(), sources());
    let mut known = sources.words.clone();
    for (_, report) in &snapshots {
        all_keys(report, &mut known);
    }
    let mut shaders = Vec::new();
    for entry in std::fs::read_dir(root().join("shaders")).unwrap().flatten() {
        let path = entry.path();
        let files: Vec<PathBuf> = if path.is_dir() {
            std::fs::read_dir(&path).unwrap().flatten().map(|e| e.path()).collect()
        } else {
            vec![path]
        };
        shaders.extend(files.into_iter().filter(|f| f.extension().is_none_or(|e| e != "spv")));
    }
    for shader in shaders {
        if let Ok(text) = std::fs::read_to_string(&shader) {
            known.extend(identifiers(&text));
        }
    }
    let mut errors = Vec::new();
    for page in pages() {
        for (number, line) in &page.prose {
            for span in code_spans(line) {
                // A prefix (`pbo_`, `zero_copy_`: chapter 11's checks) is not a name.
                if is_check_name(span)
                    && !span.ends_with('_')
                    && !known.contains(span)
                    && !SNAKE_NAMES_FROM_ELSEWHERE.contains(&span)
                {
                    errors
                        .push(format!("{}:{number}: `{span}` is in no source, shader or report", page.name));
                }
            }
        }
    }
    assert!(errors.is_empty(), "names the book quotes that nothing has:\n{}", errors.join("\n"));
}

/// The interop cheat sheet's table names every GL entry point `common` loads for sharing memory
/// and semaphores (the `MemoryObjectFns` and `SemaphoreFns` of `base/gl/mod.rs`), so that a
/// call added there cannot be missing from the page a reader looks it up on.
#[test]
fn the_cheat_sheet_names_every_interop_entry_point() {
    let gl = std::fs::read_to_string(root().join("common/src/base/gl/mod.rs")).unwrap();
    let page = std::fs::read_to_string(root().join("book/src/interop-cheat-sheet.md")).unwrap();
    let table: String = page.lines().filter(|l| l.starts_with('|')).collect::<Vec<_>>().join("\n");
    let mut names = Vec::new();
    for block in ["MemoryObjectFns {", "SemaphoreFns {"] {
        let start = gl.find(block).unwrap_or_else(|| panic!("{block} in base/gl/mod.rs"));
        let body = &gl[start + block.len()..];
        let body = &body[..body.find('}').unwrap()];
        for line in body.lines().map(str::trim).filter(|l| l.contains(": fn(")) {
            names.push(format!("gl{}", &line[..line.find(':').unwrap()]));
        }
    }
    assert!(names.len() >= 15, "found only {names:?}");
    let missing: Vec<_> = names.iter().filter(|name| !table.contains(&format!("`{name}"))).collect();
    assert!(missing.is_empty(), "interop-cheat-sheet.md's table does not name {missing:?}");
}

/// The most words a chapter's page may hold: what a 40-minute workshop slot can cover.
const CORE_WORDS: usize = 3_000;

/// The words of a page as the reader reads them: every whitespace-separated word with a letter or
/// digit in it (so not `|`, `#` or `-`), outside fenced blocks: headings, prose, lists and tables,
/// but no `{{#include}}` line. Code and transcripts are not counted: they are what the words
/// explain.
fn words(page: &Page) -> usize {
    let lines = page.prose.iter().filter(|(_, l)| !l.trim().starts_with("{{#"));
    lines.flat_map(|(_, l)| l.split_whitespace()).filter(|w| w.chars().any(char::is_alphanumeric)).count()
}

/// Each chapter's page holds the core path (what to type, what to see, why) in at most
/// [`CORE_WORDS`] words; the measurements, edge cases and history go to its `-deeper` page.
#[test]
fn chapter_pages_fit_a_workshop_slot() {
    let pages = pages();
    let chapters: Vec<&Page> =
        pages.iter().filter(|p| p.chapter().is_some() && !p.name.ends_with("-deeper.md")).collect();
    assert!(chapters.len() >= 12, "only {} chapter pages", chapters.len());
    let mut too_long = Vec::new();
    for page in &chapters {
        let count = words(page);
        eprintln!("{:>6} words  {}", count, page.name);
        if count > CORE_WORDS {
            too_long.push(format!(
                "{}: {count} words, more than {CORE_WORDS}: move measurements, edge cases and history to {}",
                page.name,
                page.name.replace(".md", "-deeper.md")
            ));
        }
    }
    assert!(too_long.is_empty(), "{}", too_long.join("\n"));
}

/// A chapter's deeper page is read as the page is, and held to the same length: what does not
/// fit is a table (with its command) rather than prose.
#[test]
fn deeper_pages_fit_a_reading_too() {
    let pages = pages();
    let deeper: Vec<&Page> = pages.iter().filter(|p| p.name.ends_with("-deeper.md")).collect();
    assert!(deeper.len() >= 10, "only {} deeper pages", deeper.len());
    let too_long: Vec<String> = deeper
        .iter()
        .map(|page| (page, words(page)))
        .filter(|(_, count)| *count > CORE_WORDS)
        .map(|(page, count)| format!("{}: {count} words, more than {CORE_WORDS}", page.name))
        .collect();
    assert!(too_long.is_empty(), "{}", too_long.join("\n"));
}

/// The count is the one stated: words outside code, tables and headings included.
#[test]
fn words_count_prose_not_code() {
    let page = Page::parse(
        "99-test.md",
        "# Title here\n\nTwo words.\n\n```rust\n{{#include x.rs:a}}\nlet x = 1;\n```\n\n| a | b |\n{{#include y.md}}\n",
    );
    assert_eq!(words(&page), 2 + 2 + 2);
}

/// The README is a newcomer's first screen: what it is, the picture and the command that runs
/// a chapter within [`README_FIRST_SCREEN`] words, and all of it in [`README_WORDS`]; the rest
/// is the book's (running.md holds the timings, the requirements, the tests).
#[test]
fn readme_is_a_first_screen() {
    let text = std::fs::read_to_string(root().join("README.md")).unwrap();
    let readme = Page::parse("README.md", &text);
    let run = readme.blocks.iter().find(|b| b.lines.iter().any(|(_, l)| l.contains("cargo run")));
    let run_line = run.expect("the README's run command").fences.0;
    let total = words(&readme);
    let prose_before_run = readme.prose.iter().filter(|(n, _)| *n < run_line).cloned().collect();
    let first = words(&Page { prose: prose_before_run, ..readme });
    assert!(total <= README_WORDS, "README.md: {total} words, more than {README_WORDS}: move it to the book");
    assert!(
        first <= README_FIRST_SCREEN,
        "README.md: {first} words before the run command, more than {README_FIRST_SCREEN}"
    );
}

/// The most words in the README, outside code.
const README_WORDS: usize = 800;
/// The most words before the README's run command.
const README_FIRST_SCREEN: usize = 200;

/// What an `{{#include path[:anchor]}}` in `page` (a file under `book/src`) pulls in, as mdBook
/// shows it (every ANCHOR line left out), or `None` when it names nothing (tests/book.rs fails
/// on that).
fn included(page: &Path, target: &str) -> Option<(PathBuf, String)> {
    let (path, anchor) = match target.split_once(':') {
        Some((path, anchor)) => (path, Some(anchor)),
        None => (target, None),
    };
    let file = page.parent()?.join(path);
    let text = std::fs::read_to_string(&file).ok()?;
    let lines: Vec<&str> = text.lines().collect();
    let body = match anchor {
        None => &lines[..],
        Some(anchor) => {
            let marker = |line: &str, kind: &str| {
                line.trim_start().trim_start_matches("//").trim_start_matches('#').trim()
                    == format!("{kind}: {anchor}")
            };
            let start = lines.iter().position(|l| marker(l, "ANCHOR"))?;
            let end = start + lines[start..].iter().position(|l| marker(l, "ANCHOR_END"))?;
            &lines[start + 1..end]
        }
    };
    let kept: Vec<&str> =
        body.iter().copied().filter(|l| !l.contains("ANCHOR:") && !l.contains("ANCHOR_END:")).collect();
    Some((file, kept.join("\n")))
}

/// Every `{{#include}}` of every page: (page name, line, the file, what it pulls in).
fn includes() -> Vec<(String, usize, PathBuf, String)> {
    let mut found = Vec::new();
    let src = root().join("book/src");
    for file in harness::files_ending(&src, "md") {
        let name = file.strip_prefix(&src).unwrap().to_string_lossy().into_owned();
        for (number, line) in std::fs::read_to_string(&file).unwrap().lines().enumerate() {
            let Some(target) = line.trim().strip_prefix("{{#include ").and_then(|t| t.strip_suffix("}}"))
            else {
                continue;
            };
            if let Some((path, text)) = included(&file, target.trim()) {
                found.push((name.clone(), number + 1, path, text));
            }
        }
    }
    found
}

/// The comment of a source line (after `//`), if it has one.
fn comment_of(line: &str) -> Option<&str> {
    line.find("//").map(|at| &line[at + 2..])
}

/// Every `common::a::b` a text names (`common::{...}` and `common::*` are imports, not names).
fn common_paths(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("common::") {
        let before = rest[..at].chars().next_back();
        let after = &rest[at..];
        rest = &rest[at + "common::".len()..];
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/') {
            continue;
        }
        let end =
            after.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':')).unwrap_or(after.len());
        let path = after[..end].trim_end_matches(':');
        if path != "common" {
            found.push(path.to_owned());
        }
    }
    found
}

/// A module of `common`: its file, and the folder its child modules live in.
struct Module {
    file: PathBuf,
    text: String,
}

impl Module {
    fn at(file: PathBuf) -> Module {
        let text = std::fs::read_to_string(&file).unwrap_or_default();
        Module { file, text }
    }

    /// `pub mod name;` here (a private module is no path a reader can write).
    fn child(&self, name: &str) -> Option<Module> {
        let lines = || self.text.lines().map(str::trim);
        // `pub mod layout { ... }`: a module inside this file.
        if lines().any(|l| l == format!("pub mod {name} {{")) {
            return Some(Module::at(self.file.clone()));
        }
        if !lines().any(|l| l == format!("pub mod {name};")) {
            return None;
        }
        let stem = self.file.file_stem().unwrap().to_string_lossy();
        let dir = if stem == "lib" || stem == "mod" {
            self.file.parent().unwrap().to_owned()
        } else {
            self.file.with_extension("")
        };
        [dir.join(format!("{name}.rs")), dir.join(name).join("mod.rs")]
            .into_iter()
            .find(|f| f.is_file())
            .map(Module::at)
    }

    /// The module a `use` path starting here leads to (`crate::a::b`, or `a::b` below this one).
    fn module_at(&self, path: &[&str]) -> Option<Module> {
        let (mut module, path) = match path.split_first() {
            Some((&"crate", rest)) => (Module::at(root().join("common/src/lib.rs")), rest),
            Some((&"self", rest)) => (Module::at(self.file.clone()), rest),
            _ => (Module::at(self.file.clone()), path),
        };
        for part in path {
            module = module.child_any(part)?;
        }
        Some(module)
    }

    /// A child module, public or not (for `use` paths inside the crate).
    fn child_any(&self, name: &str) -> Option<Module> {
        let declared = self.text.lines().map(str::trim).any(|l| {
            l == format!("mod {name};")
                || l == format!("pub mod {name};")
                || l == format!("pub(crate) mod {name};")
        });
        if !declared {
            return None;
        }
        let stem = self.file.file_stem().unwrap().to_string_lossy();
        let dir = if stem == "lib" || stem == "mod" {
            self.file.parent().unwrap().to_owned()
        } else {
            self.file.with_extension("")
        };
        [dir.join(format!("{name}.rs")), dir.join(name).join("mod.rs")]
            .into_iter()
            .find(|f| f.is_file())
            .map(Module::at)
    }

    /// The module defining item `name`, here or through a `pub use`.
    fn item(&self, name: &str, depth: usize) -> Option<Module> {
        if depth > 8 {
            return None;
        }
        const KINDS: [&str; 8] = ["fn", "struct", "enum", "trait", "const", "static", "type", "macro_rules!"];
        let defines = self.text.lines().any(|line| {
            let words: Vec<&str> = line
                .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '!'))
                .filter(|w| !w.is_empty())
                .collect();
            words.windows(2).any(|w| KINDS.contains(&w[0]) && w[1] == name)
        });
        if defines {
            return Some(Module::at(self.file.clone()));
        }
        // Each `pub use ...;`, on one line or wrapped over several (`pub use a::{\n b, c,\n};`).
        let statements: Vec<String> = self
            .text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.trim_start().starts_with("pub use "))
            .filter_map(|(i, _)| {
                let rest = self.text.lines().skip(i).collect::<Vec<_>>().join("\n");
                let statement = rest.trim_start().strip_prefix("pub use ")?;
                Some(statement[..statement.find(';')?].to_owned())
            })
            .map(|s| {
                let joined = s.split_whitespace().collect::<Vec<_>>().join(" ");
                joined.replace("{ ", "{").replace(", }", "}").replace(" }", "}").replace(",}", "}")
            })
            .collect();
        for used in &statements {
            let used = used.as_str();
            let (path, names): (&str, Vec<&str>) = match used.split_once("::{") {
                Some((path, names)) => {
                    (path, names.trim_end_matches('}').split(',').map(str::trim).collect())
                }
                None => match used.rsplit_once("::") {
                    Some((path, name)) => (path, vec![name]),
                    None => continue,
                },
            };
            let parts: Vec<&str> = path.split("::").collect();
            if (names.contains(&name) || names.contains(&"*"))
                && let Some(module) = self.module_at(&parts)
                && let Some(found) = module.item(name, depth + 1)
            {
                return Some(found);
            }
        }
        None
    }
}

/// Why `common::a::b::C` names nothing in `common/src`, if it does: each part a public module,
/// then an item of the last module (defined there or re-exported), then names inside that
/// item's file (a method, a variant).
fn unresolved(path: &str) -> Option<String> {
    let parts: Vec<&str> = path.split("::").skip(1).collect();
    let mut module = Module::at(root().join("common/src/lib.rs"));
    let mut trail = String::from("common");
    let mut rest = &parts[..];
    while let Some((first, tail)) = rest.split_first() {
        match module.child(first) {
            Some(child) => {
                module = child;
                trail = format!("{trail}::{first}");
                rest = tail;
            }
            None => break,
        }
    }
    let (item, inner) = rest.split_first()?;
    let Some(defined) = module.item(item, 0) else {
        return Some(format!("{trail} has no public module or item `{item}`"));
    };
    let words: BTreeSet<String> = identifiers(&defined.text).collect();
    for name in inner {
        if !words.contains(*name) {
            return Some(format!("`{item}` ({}) has no `{name}`", defined.file.display()));
        }
    }
    None
}

/// The sources whose comments may name `common::` paths: every file of `chapters/`,
/// `common/src/` and `shaders/` (not the compiled `.spv` and `.ptx`).
fn commented_sources() -> Vec<PathBuf> {
    fn walk(dir: &Path, found: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                walk(&path, found);
            } else if path.extension().is_none_or(|e| e != "spv" && e != "ptx" && e != "lock") {
                found.push(path);
            }
        }
    }
    let mut found = Vec::new();
    for dir in ["chapters", "common/src", "shaders"] {
        walk(&root().join(dir), &mut found);
    }
    found
}

/// Every `common::...` path the book names, in its prose, in the comments of the code it
/// includes, and in any comment of the chapters, `common` and the shaders, is a module or item
/// of `common/src`, reachable as written: `common::clocks::timing::PassTimes`, not
/// `common::timing::PassTimes`.
#[test]
fn common_paths_the_book_and_comments_name_exist() {
    let mut named: Vec<(String, String)> = Vec::new();
    for page in pages() {
        for (number, line) in &page.prose {
            named.extend(common_paths(line).into_iter().map(|p| (format!("{}:{number}", page.name), p)));
        }
    }
    for (page, line, file, text) in includes() {
        for comment in text.lines().filter_map(comment_of) {
            named.extend(
                common_paths(comment)
                    .into_iter()
                    .map(|p| (format!("{page}:{line} (from {})", file.display()), p)),
            );
        }
    }
    for file in commented_sources() {
        let Ok(text) = std::fs::read_to_string(&file) else { continue };
        let name = file.strip_prefix(root()).unwrap().display().to_string();
        for (number, line) in text.lines().enumerate() {
            if let Some(comment) = comment_of(line) {
                named
                    .extend(common_paths(comment).into_iter().map(|p| (format!("{name}:{}", number + 1), p)));
            }
        }
    }
    assert!(named.len() > 20, "only {} common:: paths found: did the pages move?", named.len());
    let errors: Vec<String> = named
        .iter()
        .filter_map(|(at, path)| unresolved(path).map(|why| format!("{at}: `{path}`: {why}")))
        .collect();
    assert!(errors.is_empty(), "paths into common that do not exist:\n{}", errors.join("\n"));
}

#[test]
fn the_path_checker_catches_a_wrong_path() {
    assert_eq!(unresolved("common::clocks::timing::PassTimes"), None);
    assert_eq!(unresolved("common::rt::ao::AoTracer::trace"), None);
    assert_eq!(unresolved("common::interop::import_memory"), None); // through `pub use import::*`
    assert_eq!(unresolved("common::connect"), None); // through the crate root's re-export
    assert_eq!(unresolved("common::frame::Composite"), None);
    assert_eq!(unresolved("common::interop::exportable::Dedicated::No"), None);
    for wrong in [
        "common::timing::PassTimes",
        "common::ao::AoTracer",
        "common::gl::layout",
        "common::interop::import::import_memory", // a private module
        "common::rt::ao::AoTracer::frobnicate",
    ] {
        assert!(unresolved(wrong).is_some(), "{wrong} resolved");
    }
    assert_eq!(
        common_paths("use common::{A, B}; (`common::base::gl::program`), vk_common::x"),
        vec!["common::base::gl::program"]
    );
}

/// Every file of the project (not `target/`, `.git/`, the built book or the links in
/// `book/src` to the sources), relative to the root.
fn project_files() -> Vec<String> {
    fn walk(dir: &Path, found: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let path = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if entry.file_type().is_ok_and(|t| t.is_symlink()) || name == "target" || name == ".git" {
                continue;
            }
            if path.is_dir() {
                if path != root().join("book/book") {
                    walk(&path, found);
                }
            } else {
                found.push(path);
            }
        }
    }
    let mut found = Vec::new();
    walk(root(), &mut found);
    found.iter().map(|f| f.strip_prefix(root()).unwrap().to_string_lossy().into_owned()).collect()
}

/// The kinds of file a page or a comment names by name.
const FILE_KINDS: &[&str] = &[
    "rs", "md", "txt", "glsl", "rgen", "rmiss", "rchit", "comp", "vert", "frag", "cu", "ptx", "spv", "json",
    "toml", "diff", "obj", "snap", "lock",
];

/// `base/gl/mod.rs` in `span` (`base/commands.rs:29` -> `base/commands.rs`), if it names a file.
fn file_name(span: &str) -> Option<&str> {
    let span = span.trim().trim_start_matches("../../").trim_end_matches(['.', ',', ')', ':']);
    let span = match span.split_once(".rs:") {
        Some((file, line)) if line.chars().all(|c| c.is_ascii_digit()) => &span[..file.len() + 3],
        _ => span,
    };
    let (_, extension) = span.rsplit_once('.')?;
    let plain = span.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/'));
    (plain && FILE_KINDS.contains(&extension) && !span.starts_with('.') && !span.contains("NN"))
        .then_some(span)
}

/// Does `name` name a file of the project? A path with a `/` is one relative to the root, to
/// `book/src`, or the end of one (`rt/ao.rs`, `base/gl/mod.rs`); a bare name (`trace.rs`) is a
/// file in one of `folders`, or, with no folders given, anywhere.
fn file_exists(files: &[String], name: &str, folders: &[String]) -> bool {
    if name.contains('/') {
        return files.iter().any(|f| {
            f == name || f.strip_prefix("book/src/") == Some(name) || f.ends_with(&format!("/{name}"))
        });
    }
    files.iter().any(|f| {
        let (folder, file) = f.rsplit_once('/').unwrap_or(("", f));
        file == name
            && (folders.is_empty() || folders.iter().any(|d| format!("{folder}/").starts_with(d.as_str())))
    })
}

/// Every file a page names in its prose (`gl.rs`, `common/src/rt/ao.rs`, `shaders/ao.rgen`), and
/// every file the comments of the code it includes name, exists. A chapter's page names a bare
/// file of its own folder (or of the folders every chapter shares: `common`, `shaders`,
/// `tests`, `xtask`, the book); other pages, and comments, a file anywhere.
#[test]
fn files_the_book_names_exist() {
    let files = project_files();
    assert!(files.len() > 100, "only {} files found", files.len());
    let shared: Vec<String> = ["common/", "shaders/", "tests/", "xtask/", "book/", "assets/"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let mut errors = Vec::new();
    let mut checked = 0;
    for page in pages() {
        let folders: Vec<String> = match page.chapter() {
            Some(chapter) => {
                let mut folders = shared.clone();
                folders.push(format!("chapters/{chapter}"));
                // The folders of other chapters it builds from (`#[path = "../NN-slug/..."]`).
                let own =
                    std::fs::read_dir(root().join("chapters").join(chapter)).into_iter().flatten().flatten();
                for file in own {
                    let text = std::fs::read_to_string(file.path()).unwrap_or_default();
                    for piece in text.split("#[path = \"../").skip(1) {
                        folders.push(format!("chapters/{}", piece.split('/').next().unwrap()));
                    }
                }
                folders
            }
            None => Vec::new(),
        };
        for (number, line) in &page.prose {
            for name in code_spans(line).into_iter().filter_map(file_name) {
                checked += 1;
                if !file_exists(&files, name, &folders) {
                    errors.push(format!("{}:{number}: `{name}`: no such file", page.name));
                }
            }
        }
    }
    for (page, line, file, text) in includes() {
        for comment in text.lines().filter_map(comment_of) {
            let words =
                comment.split(|c: char| c.is_whitespace() || matches!(c, '`' | '(' | ')' | ',' | ';'));
            for name in words.filter_map(file_name) {
                checked += 1;
                if !file_exists(&files, name, &[]) {
                    errors.push(format!(
                        "{page}:{line}: the comment in {} names `{name}`: no such file",
                        file.display()
                    ));
                }
            }
        }
    }
    assert!(checked > 50, "only {checked} file names found in the book");
    assert!(errors.is_empty(), "files the book names that do not exist:\n{}", errors.join("\n"));
}

#[test]
fn the_file_checker_catches_a_missing_file() {
    let files: Vec<String> = ["common/src/base/gl/mod.rs", "chapters/11-x/scene.rs", "book/src/images/a.png"]
        .map(String::from)
        .into();
    assert!(file_exists(&files, "base/gl/mod.rs", &[]));
    assert!(!file_exists(&files, "gl.rs", &[]));
    assert!(file_exists(&files, "scene.rs", &[]));
    assert!(!file_exists(&files, "scene.rs", &["chapters/05-y".to_owned(), "common/".to_owned()]));
    assert_eq!(file_name("base/commands.rs:29"), Some("base/commands.rs"));
    assert_eq!(file_name("NN-slug.png"), None);
    assert_eq!(file_name("vk::Format"), None);
}

/// One number on one page: the first number right after `before` (on one line) that is followed
/// by `after`.
struct Quoted {
    page: &'static str,
    before: &'static str,
    after: &'static str,
}

/// The number quoted, as written (`10.9`), if the page has it.
fn quoted(quote: &Quoted) -> Option<String> {
    let text = std::fs::read_to_string(root().join("book/src").join(quote.page)).ok()?;
    let mut rest = text.as_str();
    while let Some(at) = rest.find(quote.before) {
        rest = &rest[at + quote.before.len()..];
        let end = rest.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(rest.len());
        let number = rest[..end].trim_end_matches('.');
        if !number.is_empty() && rest[number.len()..].starts_with(quote.after) {
            return Some(number.to_owned());
        }
    }
    None
}

/// Measurements quoted on more than one page, each with the table it comes from: the
/// performance page's tables (each carries its run and date) or, for chapter 12's own
/// ablation, the deeper page's. A general test (any number, any two pages) cannot tell "the same
/// measurement" from two that share a value and a unit, so this is an explicit list, made from
/// the quantities once quoted with different numbers; add to it when a page quotes a table.
/// Numbers that come from different runs on purpose (chapter 12's pattern table, 60 frames,
/// beside `bench`'s ablation, 30 frames) are not listed: each page names its run and date.
const SAME_MEASUREMENT: &[(&str, Quoted, &[Quoted])] = &[
    (
        "chapter 08's trace, 4K, 16 rays (bench on the H200, 2026-11-28)",
        Quoted {
            page: "12-fast-frame-deeper.md",
            before: "| [chapter 08](08-composite.md) (zero-copy) | 26.90 | 8.99 | ",
            after: " |",
        },
        &[Quoted { page: "12-fast-frame-deeper.md", before: "9.0 ms of G-buffers, ", after: " ms of rays" }],
    ),
    (
        "chapter 08's frame, 4K, 16 rays (bench on the H200, 2026-11-28)",
        Quoted {
            page: "12-fast-frame-deeper.md",
            before: "| [chapter 08](08-composite.md), zero-copy | ",
            after: " ms |",
        },
        &[
            Quoted { page: "12-fast-frame-deeper.md", before: "frame takes ", after: " ms: " },
            Quoted {
                page: "12-fast-frame-deeper.md",
                before: "| [chapter 08](08-composite.md) (zero-copy) | ",
                after: " | 8.99",
            },
        ],
    ),
    (
        "chapter 08's G-buffers, 4K (bench on the H200, 2026-11-28)",
        Quoted {
            page: "12-fast-frame-deeper.md",
            before: "| [chapter 08](08-composite.md) (zero-copy) | 26.90 | ",
            after: " |",
        },
        &[Quoted { page: "12-fast-frame-deeper.md", before: "26.9 ms: ", after: " ms of G-buffers" }],
    ),
    (
        "chapter 12's frame, 4K, 16 rays (bench on the H200, 2026-11-28)",
        Quoted { page: "12-fast-frame-deeper.md", before: "| chapter 12 | ", after: " ms |" },
        &[
            Quoted { page: "12-fast-frame-deeper.md", before: "Chapter 12's takes ", after: " ms, " },
            Quoted {
                page: "12-fast-frame-deeper.md",
                before: "| + 4x4 blocks of one run (chapter 12) | ",
                after: " | 2.50",
            },
        ],
    ),
    (
        "chapter 12's trace of the ceiling scene, 4K, 16 rays (bench, 2026-11-25)",
        Quoted {
            page: "performance.md",
            before: "| ceiling | 3840×2160 | 12.76 ms | 3.06 ms | 1.71 / 6.83 | ",
            after: " / ",
        },
        &[Quoted { page: "12-fast-frame-deeper.md", before: "trace takes ", after: " ms at 4K" }],
    ),
    (
        "a flat BLAS, per-pixel pattern, 16 rays, in bench's ablation (H200, 2026-11-28)",
        Quoted {
            page: "12-fast-frame-deeper.md",
            before: "| + one flat BLAS | 12.93 | 2.50 | ",
            after: " |",
        },
        &[Quoted { page: "12-fast-frame-deeper.md", before: "10.98 → ", after: " ms" }],
    ),
    (
        "the gain of a flat BLAS for chapter 08's trace (first sweep, 2026-11-23)",
        Quoted { page: "performance.md", before: "**A flat BLAS traces ", after: "% faster" },
        &[Quoted { page: "12-fast-frame-deeper.md", before: "flat BLAS traces about ", after: "% faster" }],
    ),
    (
        "chapter 08's hand-over, 4K, 16 rays (first sweep, 2026-11-23)",
        Quoted {
            page: "performance.md",
            before: "| zero-copy | default | 3840x2160 | 16 | 26.87 | 26.98 | 8.99 | ",
            after: " |",
        },
        &[Quoted { page: "performance.md", before: "**missed**: ", after: " ms in the first sweep" }],
    ),
    (
        "the best combination's frame, 4K, 16 rays (second run, 2026-11-23)",
        Quoted {
            page: "performance.md",
            before: "| zero-copy | default | 3840x2160 | 16 | ",
            after: " | 25.07 |",
        },
        &[Quoted {
            page: "performance.md",
            before: "26.9 ms, ",
            after: " ms with the pre-pass and a flat BLAS",
        }],
    ),
];

/// `10.93` as a page with `decimals` decimals writes it.
fn rounded(value: &str, decimals: usize) -> String {
    format!("{:.decimals$}", value.parse::<f64>().unwrap() + 1e-9)
}

/// A measurement quoted on several pages has one value, its source table's, rounded as each
/// page writes it.
#[test]
fn a_measurement_quoted_twice_has_one_value() {
    let mut errors = Vec::new();
    for (what, source, quotes) in SAME_MEASUREMENT {
        let Some(value) = quoted(source) else {
            errors.push(format!(
                "{what}: {} no longer has `{}<n>{}`",
                source.page, source.before, source.after
            ));
            continue;
        };
        for quote in quotes.iter() {
            match quoted(quote) {
                None => errors.push(format!(
                    "{what}: {} no longer quotes it as `{}<n>{}`: update SAME_MEASUREMENT with the page",
                    quote.page, quote.before, quote.after
                )),
                Some(number) => {
                    let decimals = number.split_once('.').map_or(0, |(_, d)| d.len());
                    if rounded(&value, decimals) != number {
                        errors.push(format!(
                            "{what}: {} says {number}, but its source, {}, says {value}",
                            quote.page, source.page
                        ));
                    }
                }
            }
        }
    }
    assert!(errors.is_empty(), "measurements quoted with different numbers:\n{}", errors.join("\n"));
}

#[test]
fn rounding_is_the_pages() {
    assert_eq!(rounded("10.93", 1), "10.9");
    assert_eq!(rounded("26.88", 1), "26.9");
    assert_eq!(rounded("0.53", 2), "0.53");
    assert_eq!(rounded("11", 0), "11");
    assert_ne!(rounded("10.93", 1), "11.1");
}

/// The files of `common` a page includes code from that its prose does not name: by path
/// (`common/src/rt/ao.rs`), by a folder above it (`common/src/rt/accel/`), or by module path
/// (`rt::ao`, `common::rt::ao`). From chapter 04 on, a lesson's calls live where the chapters
/// after it call them, in `common`; the page shows them there, and must say where that is.
fn unnamed_common_listings(page: &str) -> Vec<String> {
    let prose: String =
        page.lines().filter(|l| !l.trim_start().starts_with("{{#include")).collect::<Vec<_>>().join("\n");
    let mut unnamed = Vec::new();
    for line in page.lines() {
        let Some(target) = line.trim().strip_prefix("{{#include ../../").and_then(|t| t.strip_suffix("}}"))
        else {
            continue;
        };
        let file = target.split(':').next().unwrap_or(target);
        let Some(inside) = file.strip_prefix("common/src/") else { continue };
        let module = inside.trim_end_matches(".rs").trim_end_matches("/mod").replace('/', "::");
        let mut folders = Vec::new();
        let mut folder = std::path::Path::new(file).parent();
        while let Some(f) =
            folder.filter(|f| f.starts_with("common/src") && *f != std::path::Path::new("common/src"))
        {
            folders.push(format!("{}/", f.display()));
            folder = f.parent();
        }
        let named = prose.contains(file)
            || folders.iter().any(|f| prose.contains(f.as_str()))
            || prose.contains(&format!("`{module}"))
            || prose.contains(&format!("common::{module}"));
        if !named && !unnamed.contains(&file.to_owned()) {
            unnamed.push(file.to_owned());
        }
    }
    unnamed
}

#[test]
fn each_chapter_page_names_the_common_files_it_shows() {
    let mut found = Vec::new();
    for page in pages().iter().filter(|p| p.chapter().is_some()) {
        let text = std::fs::read_to_string(root().join("book/src").join(&page.name)).unwrap();
        for file in unnamed_common_listings(&text) {
            found.push(format!("{}: shows code from {file} and never says where it lives", page.name));
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn the_common_file_check_catches_an_unnamed_file() {
    let include = "{{#include ../../common/src/rt/ao.rs:record}}";
    assert_eq!(
        unnamed_common_listings(&format!("Some prose.\n\n```rust\n{include}\n```\n")),
        ["common/src/rt/ao.rs"]
    );
    for named in
        ["[`common/src/rt/ao.rs`](x)", "`common/src/rt/` holds it", "`rt::ao::record`", "`common::rt::ao`"]
    {
        assert!(
            unnamed_common_listings(&format!("{named}\n\n```rust\n{include}\n```\n")).is_empty(),
            "{named}"
        );
    }
    // The include line itself does not count as naming the file.
    assert_eq!(unnamed_common_listings(include).len(), 1);
}

/// The pages being rewritten on their own as this test was added; each fails it today (the test
/// below prints where). Whoever merges those rewrites links their citations and empties this
/// list: a page listed here that no longer fails is an error, so the list cannot outlive its use.
const CITATIONS_PENDING: &[&str] = &[];

/// The chapters' slugs by number: `08` -> `08-composite`.
fn chapter_slugs() -> BTreeMap<String, String> {
    std::fs::read_dir(root().join("chapters"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.len() > 3 && n.as_bytes()[..2].iter().all(u8::is_ascii_digit))
        .map(|n| (n[..2].to_owned(), n))
        .collect()
}

/// A prose line as the reader sees it: each character with the target of the link it is in, if
/// any. Code spans and images (their alt text too) become one space: a chapter named there is
/// no citation.
fn linked_text(line: &[char]) -> Vec<(char, Option<String>)> {
    fn closing(line: &[char], open: usize) -> Option<usize> {
        let mut depth = 0;
        for (i, c) in line.iter().enumerate().skip(open) {
            match c {
                '[' => depth += 1,
                ']' => {
                    depth -= 1;
                    if depth == 0 {
                        return Some(i);
                    }
                }
                _ => {}
            }
        }
        None
    }
    fn walk(line: &[char], target: Option<&str>, out: &mut Vec<(char, Option<String>)>) {
        let mut i = 0;
        while i < line.len() {
            let c = line[i];
            if c == '`' {
                let end = line[i + 1..].iter().position(|&c| c == '`').map_or(line.len(), |p| i + 1 + p);
                out.push((' ', None));
                i = end + 1;
                continue;
            }
            let image = c == '!' && line.get(i + 1) == Some(&'[');
            let open = if image { i + 1 } else { i };
            if line[open] == '['
                && let Some(close) = closing(line, open)
                && line.get(close + 1) == Some(&'(')
                && let Some(end) = line[close + 2..].iter().position(|&c| c == ')').map(|p| close + 2 + p)
            {
                if image {
                    out.push((' ', None));
                } else {
                    let url: String = line[close + 2..end].iter().collect();
                    walk(&line[open + 1..close], Some(target.unwrap_or(&url)), out);
                }
                i = end + 1;
                continue;
            }
            out.push((c, target.map(str::to_owned)));
            i += 1;
        }
    }
    let mut out = Vec::new();
    walk(line, None, &mut out);
    out
}

/// The chapter numbers a line cites after "chapter" or "chapters" (`chapter 08`, `chapters
/// 05-10`, `chapters 01, 02 and 11`, `chapters 01 to 13`), each with its position in `text`.
fn cited_numbers(text: &[char]) -> Vec<(usize, String)> {
    let lower: Vec<char> = text.iter().map(|c| c.to_ascii_lowercase()).collect();
    let starts = |at: usize, word: &str| word.chars().enumerate().all(|(k, w)| lower.get(at + k) == Some(&w));
    let two_digits = |at: usize| {
        text.get(at).is_some_and(char::is_ascii_digit)
            && text.get(at + 1).is_some_and(char::is_ascii_digit)
            && !text.get(at + 2).is_some_and(char::is_ascii_digit)
    };
    let spaces = |mut at: usize| {
        while text.get(at) == Some(&' ') {
            at += 1;
        }
        at
    };
    let mut found = Vec::new();
    for at in 0..text.len() {
        if !starts(at, "chapter") || (at > 0 && text[at - 1].is_alphanumeric()) {
            continue;
        }
        let mut next = at + "chapter".len();
        if text.get(next) == Some(&'s') {
            next += 1;
        }
        if text.get(next) != Some(&' ') {
            continue;
        }
        let mut cursor = spaces(next);
        while two_digits(cursor) {
            found.push((cursor, text[cursor..cursor + 2].iter().collect()));
            // A separator and another number, or the end of the list.
            let mut after = spaces(cursor + 2);
            if matches!(text.get(after), Some('-' | '–' | ',')) {
                after = spaces(after + 1);
            }
            for word in ["and ", "or ", "to "] {
                if starts(after, word) {
                    after = spaces(after + word.len());
                }
            }
            if after == cursor + 2 {
                break;
            }
            cursor = after;
        }
    }
    found
}

/// Where `text` (a page, or the README) cites a chapter without linking it. The rule: in each
/// paragraph, list item and table row, the first mention of each chapter is a link to its page
/// (`08-composite.md`, or its deeper page, with any `#anchor` and any path before it), so that
/// wherever a reader starts reading, the chapter named there is one click away, and a paragraph
/// that names chapter 08 five times links it once. Headings, fenced blocks, code spans and
/// image alt text cite nothing; nor does a chapter's own page (or its deeper page) cite itself.
fn unlinked_citations(name: &str, text: &str, slugs: &BTreeMap<String, String>) -> Vec<(usize, String)> {
    let own = name.get(..2).filter(|n| slugs.contains_key(*n));
    let mut errors = Vec::new();
    let mut seen: BTreeSet<String> = BTreeSet::new();
    let mut fenced = false;
    for (number, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if trimmed.starts_with("```") {
            fenced = !fenced;
            seen.clear();
            continue;
        }
        let item = trimmed.starts_with("- ")
            || trimmed.starts_with("* ")
            || trimmed.starts_with('|')
            || trimmed
                .split_once(". ")
                .is_some_and(|(n, _)| !n.is_empty() && n.chars().all(|c| c.is_ascii_digit()));
        if fenced || trimmed.is_empty() || trimmed.starts_with('#') || trimmed.starts_with("{{#") || item {
            seen.clear();
        }
        if fenced || trimmed.starts_with('#') || trimmed.starts_with("{{#") {
            continue;
        }
        let chars: Vec<char> = line.chars().collect();
        let shown = linked_text(&chars);
        let plain: Vec<char> = shown.iter().map(|(c, _)| *c).collect();
        for (at, cited) in cited_numbers(&plain) {
            let Some(slug) = slugs.get(&cited) else { continue };
            if Some(cited.as_str()) == own || !seen.insert(cited.clone()) {
                continue;
            }
            let linked = shown[at].1.as_deref().is_some_and(|url| {
                let file = url.split('#').next().unwrap_or_default().rsplit('/').next().unwrap_or_default();
                file == format!("{slug}.md") || file == format!("{slug}-deeper.md")
            });
            if !linked {
                errors.push((number + 1, format!("chapter {cited} is not a link to {slug}.md: {trimmed}")));
            }
        }
    }
    errors
}

/// Every chapter a page (or the README) cites is a link, by the rule of [`unlinked_citations`].
#[test]
fn every_chapter_a_page_cites_is_a_link() {
    let slugs = chapter_slugs();
    assert!(slugs.len() >= 14, "chapters/ has {} chapters", slugs.len());
    let mut files = harness::files_ending(&root().join("book/src"), "md");
    files.push(root().join("README.md"));
    files.sort();
    let (mut errors, mut pending, mut citations) = (Vec::new(), BTreeMap::new(), 0);
    for file in &files {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        if name == "SUMMARY.md" {
            continue; // the sidebar: every entry is a link already, and names no "chapter NN"
        }
        let text = std::fs::read_to_string(file).unwrap();
        citations += text.lines().map(|l| cited_numbers(&l.chars().collect::<Vec<_>>()).len()).sum::<usize>();
        let found = unlinked_citations(&name, &text, &slugs);
        let at = |(line, why): &(usize, String)| format!("{name}:{line}: {why}");
        if CITATIONS_PENDING.contains(&name.as_str()) {
            pending.insert(name.clone(), found.len());
            for finding in &found {
                eprintln!("pending: {}", at(finding));
            }
        } else {
            errors.extend(found.iter().map(at));
        }
    }
    for name in CITATIONS_PENDING {
        match pending.get(*name) {
            None => errors.push(format!("CITATIONS_PENDING lists {name}, which is not a page")),
            Some(0) => {
                errors.push(format!("{name} links every chapter it cites: remove it from CITATIONS_PENDING"))
            }
            Some(_) => {}
        }
    }
    assert!(citations > 300, "only {citations} chapter citations found: did the pages move?");
    assert!(errors.is_empty(), "chapters cited without a link:\n{}", errors.join("\n"));
}

#[test]
fn the_citation_check_catches_an_unlinked_chapter() {
    let slugs: BTreeMap<String, String> =
        [("03", "03-semaphores"), ("08", "08-composite"), ("10", "10-vertex-animation")]
            .map(|(n, s)| (n.to_owned(), s.to_owned()))
            .into();
    let lines = |text: &str| -> Vec<usize> {
        unlinked_citations("x.md", text, &slugs).into_iter().map(|(line, _)| line).collect()
    };
    assert_eq!(lines("As chapter 08 does."), [1]);
    assert_eq!(lines("As [chapter 08](08-composite.md#a) does, and chapter 08 again."), Vec::<usize>::new());
    assert_eq!(lines("As [chapter 08](08-composite-deeper.md) does."), Vec::<usize>::new());
    assert_eq!(lines("As [chapter 08](03-semaphores.md) does."), [1], "a link to another chapter");
    assert_eq!(lines("Chapters [03](03-semaphores.md)-10 check it."), [1], "the end of a range");
    assert_eq!(lines("Chapters 03 to [10](10-vertex-animation.md)."), [1]);
    assert_eq!(lines("Chapters 03, 08 and 10."), [1, 1, 1]);
    assert_eq!(lines("[chapter 08](08-composite.md)\nchapter 08 again\n\nchapter 08"), [4], "per paragraph");
    assert_eq!(lines("[chapter 08](08-composite.md)\n- chapter 08 in a list item"), [2]);
    assert_eq!(lines("| [chapter 08](08-composite.md) |\n| chapter 08 |"), [2], "per table row");
    assert_eq!(lines("## Since chapter 08\n`chapter 08`\n![chapter 08](a.png)"), Vec::<usize>::new());
    assert_eq!(lines("```text\nchapter 08\n```"), Vec::<usize>::new());
    assert_eq!(lines("chapter 99 and chapter 8"), Vec::<usize>::new(), "no such chapter");
    assert!(unlinked_citations("08-composite.md", "chapter 08", &slugs).is_empty(), "its own page");
    assert_eq!(unlinked_citations("08-composite-deeper.md", "chapter 03", &slugs).len(), 1);
}

/// The chapters a text names after "chapter" or "chapters", ranges expanded: `chapters 05-10,
/// 12 and 13` -> 05, 06, 07, 08, 09, 10, 12, 13. Links and code spans are read as the reader
/// sees them.
fn chapters_named(text: &str) -> BTreeSet<u32> {
    let shown: Vec<char> =
        linked_text(&text.chars().collect::<Vec<_>>()).into_iter().map(|(c, _)| c).collect();
    let cited = cited_numbers(&shown);
    let mut named = BTreeSet::new();
    for (i, (at, number)) in cited.iter().enumerate() {
        let number: u32 = number.parse().unwrap();
        named.insert(number);
        // A range: `05-10`, `05–10`, `01 to 13`.
        if i > 0 {
            let (before, previous) = &cited[i - 1];
            let between: String = shown[before + 2..*at].iter().collect();
            if matches!(between.trim(), "-" | "–" | "to") {
                named.extend(previous.parse::<u32>().unwrap()..number);
            }
        }
    }
    named
}

/// A page's prose as one line per paragraph, list item and table row (headings, fenced blocks and
/// includes left out).
fn paragraphs_of(text: &str) -> Vec<String> {
    let mut found = vec![String::new()];
    let mut fenced = false;
    for line in text.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with("```") {
            fenced = !fenced;
        }
        if fenced || trimmed.starts_with("```") || trimmed.is_empty() || trimmed.starts_with('#') {
            found.push(String::new());
        } else if !trimmed.starts_with("{{#") {
            if trimmed.starts_with('|') || trimmed.starts_with("- ") || trimmed.starts_with("* ") {
                found.push(String::new());
            }
            let last = found.last_mut().unwrap();
            last.push(' ');
            last.push_str(trimmed);
        }
    }
    found.into_iter().filter(|p| !p.trim().is_empty()).collect()
}

/// The chapters named in the sentence of `page` that says `claim`, before it (from the sentence's
/// start, or the last `;`): `Chapters 01-05, 11 and 14 need only ...` -> 01-05, 11, 14.
fn chapters_claiming(page: &str, claim: &str) -> BTreeSet<u32> {
    let text = std::fs::read_to_string(root().join("book/src").join(page)).unwrap();
    let paragraph = paragraphs_of(&text)
        .into_iter()
        .find(|p| p.contains(claim))
        .unwrap_or_else(|| panic!("{page} no longer says \"{claim}\": update this test with the page"));
    let before = &paragraph[..paragraph.find(claim).unwrap()];
    let start = before.rfind(". ").max(before.rfind("; ")).map_or(0, |at| at + 2);
    chapters_named(&before[start..])
}

/// Per chapter number (and `bench`, as 0 is no chapter, left out): the device extensions its
/// reports enable, all runs together. The reports come from runs on lavapipe, which has no
/// external semaphores, so these are the extensions each chapter requires.
fn enabled_extensions(snapshots: &[(String, Value)]) -> BTreeMap<u32, BTreeSet<String>> {
    let mut found: BTreeMap<u32, BTreeSet<String>> = BTreeMap::new();
    for (_, report) in snapshots {
        let Some(number) = report["chapter"].as_str().and_then(|c| c.get(..2)).and_then(|n| n.parse().ok())
        else {
            continue;
        };
        let extensions = report["vulkan"]["extensions"].as_array().into_iter().flatten();
        found.entry(number).or_default().extend(extensions.filter_map(|e| e.as_str().map(str::to_owned)));
    }
    found
}

/// A fact stated "for chapters a-b" covers every chapter it is true of, and only those: each
/// sentence below names a set of chapters, and the set is worked out here from the reports or the
/// code. (The troubleshooting page's lists once stopped at chapter 10 while chapters 12-14 came.)
#[test]
fn facts_stated_for_a_set_of_chapters_name_every_chapter_they_apply_to() {
    let chapters: BTreeSet<u32> = chapter_slugs().keys().map(|n| n.parse().unwrap()).collect();
    let extensions = enabled_extensions(&snapshots());
    assert_eq!(extensions.keys().copied().collect::<BTreeSet<u32>>(), chapters, "a report for every chapter");
    let only_memory: BTreeSet<u32> = extensions
        .iter()
        .filter(|(_, e)| e.iter().eq(["VK_KHR_external_memory_fd"].iter()))
        .map(|(n, _)| *n)
        .collect();
    let ray_tracing: BTreeSet<u32> = extensions
        .iter()
        .filter(|(_, e)| {
            e.contains("VK_KHR_ray_tracing_pipeline") && e.contains("VK_KHR_acceleration_structure")
        })
        .map(|(n, _)| *n)
        .collect();
    // The 16-byte read-back limit is `common::scene::gbuffer::check_size`'s: every program that
    // draws G-buffers (or chapter 12's visibility buffer, whose checks draw them) reaches it
    // through `scene::gbuffer`, and no other program names that module.
    let sources = sources();
    let gbuffer: BTreeSet<u32> = chapters
        .iter()
        .copied()
        .filter(|n| {
            let slug = &chapter_slugs()[&format!("{n:02}")];
            sources.text.get(&format!("chapters/{slug}")).is_some_and(|t| t.contains("gbuffer"))
        })
        .collect();
    // Chapters that draw in a window of their own: their sources open one (chapter 14's viewer
    // opens its window with `gl_in_window`, and the pages name it apart).
    let windowed: BTreeSet<u32> = chapters
        .iter()
        .copied()
        .filter(|n| {
            let slug = &chapter_slugs()[&format!("{n:02}")];
            let text = sources.text.get(&format!("chapters/{slug}"));
            text.is_some_and(|t| t.contains("contexts_in_window") || t.contains("Window::open"))
        })
        .collect();
    let claims = [
        ("introduction.md", "draw in a window", &windowed, "their sources open a window"),
        (
            "running.md",
            "[chapter 14](14-two-processes.md)'s viewer, and the picture",
            &windowed,
            "their sources open a window",
        ),
        (
            "troubleshooting.md",
            "need only `VK_KHR_external_memory_fd`",
            &only_memory,
            "its reports enable only that",
        ),
        ("troubleshooting.md", "need ray tracing", &ray_tracing, "its reports enable ray tracing"),
        (
            "troubleshooting.md",
            "also read a 16-byte-a-pixel G-buffer back",
            &gbuffer,
            "its sources use `scene::gbuffer`, whose `check_size` sets the limit",
        ),
    ];
    let mut errors = Vec::new();
    for (page, claim, truth, why) in claims {
        let stated = chapters_claiming(page, claim);
        if &stated != truth {
            errors.push(format!(
                "{page}: \"{claim}\" is said of chapters {stated:?}, but is true of {truth:?} ({why})"
            ));
        }
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// A sentence that says which chapters make a check (`chapters 03-10 check it
/// (`hand_over_layouts_agree`)`) names every chapter whose reports have it, and only those: the
/// chapters of a sentence with the word "check" and two or more chapters named after "chapters"
/// are those whose reports, on every run, have one of the checks it names in code.
#[test]
fn sentences_that_say_which_chapters_check_something_name_them_all() {
    let (snapshots, sources) = (snapshots(), sources());
    let checks = checks(&snapshots, &sources);
    let reporting = |name: &str| -> BTreeSet<u32> {
        checks
            .always
            .iter()
            .filter(|(_, names)| names.contains(name))
            .filter_map(|(chapter, _)| chapter.get(..2)?.parse().ok())
            .collect()
    };
    let (mut errors, mut found) = (Vec::new(), 0);
    for page in pages() {
        let text = std::fs::read_to_string(root().join("book/src").join(&page.name)).unwrap();
        for paragraph in paragraphs_of(&text) {
            for sentence in paragraph.split(". ") {
                let named = chapters_named(sentence);
                let plural = sentence.to_ascii_lowercase().contains("chapters ");
                let checked: Vec<&str> = code_spans(sentence)
                    .into_iter()
                    .filter(|s| is_check_name(s) && !reporting(s).is_empty())
                    .collect();
                if !plural || named.len() < 2 || checked.is_empty() || !sentence.contains("check") {
                    continue;
                }
                found += 1;
                let truth: BTreeSet<u32> = checked.iter().flat_map(|c| reporting(c)).collect();
                if named != truth {
                    errors.push(format!(
                        "{}: \"{}\" names chapters {named:?}; the reports with {checked:?} are {truth:?}",
                        page.name,
                        sentence.trim()
                    ));
                }
            }
        }
    }
    assert!(found >= 2, "only {found} sentences say which chapters check what: did the pages move?");
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// `4:1` for 4.0, `3:2` for 1.5: a side's ratio as the troubleshooting page writes it.
fn ratio(value: f32) -> String {
    (1..=4)
        .map(|q| (q, value * q as f32))
        .find(|(_, p)| (p - p.round()).abs() < 1e-4)
        .map_or(format!("{value}:1"), |(q, p)| format!("{}:{q}", p.round()))
}

/// The shape column for a program's `Smallest::shape`: `any`, `16:1 to 1:16`, `any width, at
/// most 1:2`.
fn shape_cell(widest: Option<f32>, tallest: Option<f32>) -> String {
    let flip = |r: String| {
        let (a, b) = r.split_once(':').unwrap();
        format!("{b}:{a}")
    };
    match (widest, tallest) {
        (None, None) => "any".to_owned(),
        (None, Some(t)) => format!("any width, at most {}", flip(ratio(t))),
        (Some(w), None) => format!("at most {}, any height", ratio(w)),
        (Some(w), Some(t)) => format!("{} to {}", ratio(w), flip(ratio(t))),
    }
}

/// A program's `const SMALLEST: Smallest` from its `main.rs`: (`WxH`, the shape column).
fn smallest_of(main: &str) -> Option<(String, String)> {
    let start = main.find("const SMALLEST: Smallest =")?;
    let rest = &main[start..];
    let item = &rest[..rest.find(";\n").unwrap_or(rest.len())];
    if item.contains("Smallest::ANY") {
        return Some(("1x1".to_owned(), "any".to_owned()));
    }
    let number = |key: &str| -> String {
        let after = &item[item.find(key).unwrap_or_else(|| panic!("no {key} in {item}")) + key.len()..];
        after.trim_start().chars().take_while(|c| c.is_ascii_digit()).collect()
    };
    let size = format!("{}x{}", number("width:"), number("height:"));
    let shape = match item.split_once("shape: Some((") {
        None => shape_cell(None, None),
        Some((_, after)) => {
            let parts: Vec<&str> = after.split(',').map(str::trim).collect();
            let side = |s: &str| (s != "f32::INFINITY").then(|| s.parse::<f32>().unwrap());
            shape_cell(side(parts[0]), side(parts[1]))
        }
    };
    Some((size, shape))
}

/// The troubleshooting page's table of smallest sizes has a row for every program that states a
/// `SMALLEST`, with the size and shape its code states.
#[test]
fn the_smallest_size_table_is_every_programs_code() {
    let mut programs = BTreeMap::new();
    for entry in std::fs::read_dir(root().join("chapters")).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if let Ok(main) = std::fs::read_to_string(entry.path().join("main.rs"))
            && let Some(smallest) = smallest_of(&main)
        {
            programs.insert(name, smallest);
        }
    }
    assert!(programs.len() >= 15, "only {} programs state a SMALLEST: {programs:?}", programs.len());
    let page = std::fs::read_to_string(root().join("book/src/troubleshooting.md")).unwrap();
    let table =
        page.split("| Program | Smallest |").nth(1).expect("the troubleshooting page's smallest-size table");
    let mut errors = Vec::new();
    let mut listed = BTreeSet::new();
    for row in table.lines().skip(2).take_while(|l| l.starts_with('|')) {
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        for program in cells[1].split(',').map(str::trim) {
            listed.insert(program.to_owned());
            match programs.get(program) {
                None => errors.push(format!("the table lists {program}, which states no SMALLEST")),
                Some((size, shape)) if (size.as_str(), shape.as_str()) != (cells[2], cells[3]) => errors
                    .push(format!(
                        "{program}: the table says {} and {}; its code, {size} and {shape}",
                        cells[2], cells[3]
                    )),
                Some(_) => {}
            }
        }
    }
    for program in programs.keys().filter(|p| !listed.contains(*p)) {
        errors.push(format!("{program} states a SMALLEST, but the table has no row for it"));
    }
    assert!(errors.is_empty(), "troubleshooting.md's smallest sizes:\n{}", errors.join("\n"));
}

#[test]
fn the_fact_checkers_read_what_the_pages_write() {
    assert_eq!(
        chapters_named("Chapters [05](a.md)-[10](b.md), 12 and 13 read"),
        BTreeSet::from([5, 6, 7, 8, 9, 10, 12, 13])
    );
    assert_eq!(chapters_named("chapters 01 to 03, and chapter 11"), BTreeSet::from([1, 2, 3, 11]));
    assert_eq!(chapters_named("`chapters 05-10` in code"), BTreeSet::new());
    assert_eq!(shape_cell(Some(16.0), Some(16.0)), "16:1 to 1:16");
    assert_eq!(shape_cell(Some(1.5), Some(2.0)), "3:2 to 1:2");
    assert_eq!(shape_cell(None, Some(2.0)), "any width, at most 1:2");
    let main = "const SMALLEST: Smallest = Smallest {\n    width: 48,\n    height: 40,\n    why: \"x\",\n    shape: Some((\n        1.5,\n        f32::INFINITY,\n        \"y\",\n    )),\n};\n";
    assert_eq!(smallest_of(main), Some(("48x40".to_owned(), "at most 3:2, any height".to_owned())));
    assert_eq!(
        smallest_of("const SMALLEST: Smallest = Smallest::ANY;\n"),
        Some(("1x1".to_owned(), "any".to_owned()))
    );
}

/// Chapter pages whose first command has no transcript yet, each being rewritten as this test
/// was added; whoever merges the rewrite adds the transcript and empties the list (a page listed
/// here that has its transcript is an error).
const TRANSCRIPT_PENDING: &[&str] = &[];

/// Every chapter's page shows the transcript of the first command it prints at its top (right
/// after the command, as the house order has it, or under "## What you should see"): what a
/// reader runs first, and what it prints, generated and tested by `tests/transcripts.rs`.
#[test]
fn every_chapter_page_shows_the_transcript_of_its_first_command() {
    let mut errors = Vec::new();
    let mut missing = BTreeSet::new();
    for page in pages().iter().filter(|p| p.chapter().is_some() && !p.name.ends_with("-deeper.md")) {
        let text = std::fs::read_to_string(root().join("book/src").join(&page.name)).unwrap();
        let first = page
            .blocks
            .iter()
            .find(|b| b.info == "sh")
            .and_then(|b| {
                b.lines.iter().map(|(_, l)| l.trim()).find(|l| !l.is_empty() && !l.starts_with('#'))
            })
            .map(|l| l.split(" #").next().unwrap().split_whitespace().collect::<Vec<_>>().join(" "));
        let Some(first) = first else {
            errors.push(format!("{}: prints no command at its top", page.name));
            continue;
        };
        // The first command of every transcript the page includes.
        let shown: Vec<String> = text
            .split("{{#include transcripts/")
            .skip(1)
            .filter_map(|s| s.split("}}").next())
            .filter_map(|file| std::fs::read_to_string(root().join("book/src/transcripts").join(file)).ok())
            .filter_map(|t| t.lines().find_map(|l| l.strip_prefix("$ ")).map(str::to_owned))
            .map(|c| c.split_whitespace().collect::<Vec<_>>().join(" "))
            .collect();
        let command = shown.first();
        if !shown.contains(&first) {
            missing.insert(page.name.clone());
            if !TRANSCRIPT_PENDING.contains(&page.name.as_str()) {
                errors.push(format!(
                    "{}: shows no transcript of its first command, `{first}` \
                     (its first shows {command:?}): add book/src/transcripts/NAME.txt with `$ {first}` and run \
                     `cargo run -p xtask -- transcripts`",
                    page.name
                ));
            }
        }
    }
    for name in TRANSCRIPT_PENDING.iter().filter(|n| !missing.contains(**n)) {
        errors
            .push(format!("{name} shows its first command's transcript: remove it from TRANSCRIPT_PENDING"));
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// The introduction's table of chapters says, cumulatively, what each chapter needs: a row adds
/// its `VK_...` extensions to everything above it, `none beyond NN's` starts again from chapter
/// NN's, and `—` adds nothing. Read that way, each chapter's Vulkan extensions are those its
/// reports enable (the semaphore extension left out: every chapter that asks for it runs
/// without it, on the host path, and the reports come from lavapipe, which has none).
#[test]
fn the_introductions_table_states_the_extensions_each_chapter_enables() {
    let extensions = enabled_extensions(&snapshots());
    let intro = std::fs::read_to_string(root().join("book/src/introduction.md")).unwrap();
    let mut stated: BTreeMap<u32, BTreeSet<String>> = BTreeMap::new();
    let mut running: BTreeSet<String> = BTreeSet::new();
    // The chapters' table alone: the first table whose rows start with a chapter's number (a later
    // table of exit codes has rows numbered 0 to 2).
    let table = intro.lines().skip_while(|l| !l.starts_with("| 01 ")).take_while(|l| l.starts_with("| "));
    for row in table {
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        let Ok(number) = cells[1].parse::<u32>() else { continue };
        let needs = cells[cells.len() - 2];
        if let Some(rest) = needs.strip_prefix("none beyond ") {
            let from: u32 = rest[..2].parse().expect("`none beyond NN's`");
            running = stated.get(&from).cloned().unwrap_or_default();
        }
        running.extend(
            code_spans(needs)
                .into_iter()
                .filter(|s| s.starts_with("VK_") && *s != "VK_KHR_external_semaphore_fd")
                .map(str::to_owned),
        );
        stated.insert(number, running.clone());
    }
    assert!(stated.len() >= 14, "the introduction's table has {} chapters", stated.len());
    let errors: Vec<String> = extensions
        .iter()
        .filter(|(n, enabled)| stated.get(n) != Some(enabled))
        .map(|(n, enabled)| {
            format!(
                "chapter {n:02}: the table adds up to {:?}; its reports enable {enabled:?}",
                stated.get(n)
            )
        })
        .collect();
    assert!(errors.is_empty(), "introduction.md's \"adds to what it needs\" column:\n{}", errors.join("\n"));
}

/// Chapters the workshop kit has no slot for yet, being added as this test was written; whoever
/// merges the slot empties the list (a chapter listed here that has its slot is an error).
const WORKSHOP_PENDING: &[&str] = &[];

/// The workshop kit promises a slot per chapter ("One per chapter"): its time table has a row for
/// every chapter folder, and every row's chapter has a challenge headed `**NN · ...**` (which
/// `tests/workshop.rs` holds to a solution that builds and passes).
#[test]
fn the_workshop_has_a_slot_for_every_chapter() {
    let page = std::fs::read_to_string(root().join("book/src/workshop.md")).unwrap();
    let rows: BTreeSet<String> = page
        .lines()
        .skip_while(|l| !l.starts_with("## A time budget"))
        .take_while(|l| !l.starts_with("## Lavapipe"))
        .filter_map(|row| row.strip_prefix("| [")?.split(']').next().map(str::to_owned))
        .collect();
    let mut errors = Vec::new();
    for number in chapter_slugs().keys() {
        let slot = rows.contains(number) && page.contains(&format!("**{number} · "));
        match (slot, WORKSHOP_PENDING.contains(&number.as_str())) {
            (false, false) => errors.push(format!(
                "chapter {number} has no row in the workshop's time table or no challenge headed **{number} · ...**"
            )),
            (true, true) => errors.push(format!("chapter {number} has its workshop slot: remove it from WORKSHOP_PENDING")),
            _ => {}
        }
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

/// The sizes `--resize-every K` goes through, in order, as `common::frame::input::resize_every`
/// makes them: its `[2, 3, 4]` quarters, indexed by `frame / K`, starting at frame K (index 1).
fn resize_every_order() -> Vec<&'static str> {
    let source = std::fs::read_to_string(root().join("common/src/frame/input.rs")).unwrap();
    let start = source.find("pub fn resize_every").expect("common::frame::input::resize_every");
    let body = &source[start..];
    let list = body.find("let quarters = [").map(|i| &body[i + "let quarters = [".len()..]).unwrap();
    let quarters: Vec<u32> =
        list[..list.find(']').unwrap()].split(',').map(|q| q.trim().parse().unwrap()).collect();
    assert!(
        body.contains("[(frame / every) as usize % 3]"),
        "resize_every indexes its quarters otherwise now"
    );
    let word = |q: u32| match q {
        2 => "half",
        3 => "three quarters",
        4 => "full",
        other => panic!("a resize to {other} quarters has no word here"),
    };
    (1..=quarters.len()).map(|i| word(quarters[i % quarters.len()])).collect()
}

/// Sentences that name `--resize-every` and list its sizes ("three quarters, full, then half"):
/// the sizes named must come in `order` (a rotation of it reads as another order, and is wrong).
fn resize_order_errors(page: &Page, order: &[&str]) -> (Vec<String>, usize) {
    let (mut errors, mut read) = (Vec::new(), 0);
    // The prose as one string, and where each of its lines starts in it.
    let (mut joined, mut starts) = (String::new(), Vec::new());
    for (number, line) in &page.prose {
        starts.push((joined.len(), *number));
        joined.push_str(&line.replace("whole", "full"));
        joined.push(' ');
    }
    let mut at = 0;
    for sentence in joined.split(". ") {
        let line = starts.iter().take_while(|(start, _)| *start <= at).last().map_or(0, |(_, n)| *n);
        at += sentence.len() + 2;
        if !sentence.contains("--resize-every") && !sentence.contains("resize_every") {
            continue;
        }
        let mut named: Vec<(usize, &str)> =
            order.iter().filter_map(|w| sentence.find(w).map(|at| (at, *w))).collect();
        // "three quarters" holds no "half", and "full" none of the others: each is found once.
        named.sort();
        if named.len() < 2 {
            continue;
        }
        read += 1;
        let said: Vec<&str> = named.iter().map(|(_, w)| *w).collect();
        let expected: Vec<&str> = order.iter().copied().filter(|w| said.contains(w)).collect();
        if said != expected {
            errors.push(format!(
                "{}:{line}: names --resize-every's sizes as {} where the code makes {}",
                page.name,
                said.join(", "),
                expected.join(", ")
            ));
        }
    }
    (errors, read)
}

#[test]
fn resize_sizes_are_named_in_the_order_they_come() {
    let order = resize_every_order();
    let (mut errors, mut read) = (Vec::new(), 0);
    for page in pages() {
        let (page_errors, page_read) = resize_order_errors(&page, &order);
        errors.extend(page_errors);
        read += page_read;
    }
    assert!(errors.is_empty(), "pages that name the resizes out of order:\n{}", errors.join("\n"));
    assert!(read > 0, "no page names --resize-every's sizes: the check read nothing");
    // The check can fail: the sizes named the other way round.
    let wrong =
        format!("`--resize-every 2` makes them anew\n({}, {}, then {}).\n", order[2], order[1], order[0]);
    let (caught, _) = resize_order_errors(&Page::parse("15-wgpu.md", &wrong), &order);
    assert_eq!(caught.len(), 1, "the wrong order is caught: {caught:?}");
}

/// What a page says of a flag: "`--blur`, 0–8 pixels, default 2", "`--slots` images (2 by
/// default ...)", "`--samples` (rays per pixel per frame, 0–256, default 16)".
#[derive(Debug, PartialEq)]
struct FlagClaim {
    line: usize,
    flag: String,
    default: Option<f64>,
    range: Option<(f64, f64)>,
}

/// A number as pages write it ("10,000", "4096", "0.5"), and where it ends.
fn page_number(text: &[char]) -> Option<(f64, usize)> {
    let end = text.iter().position(|c| !(c.is_ascii_digit() || *c == ',' || *c == '.')).unwrap_or(text.len());
    let digits: String = text[..end].iter().filter(|c| **c != ',').collect();
    let digits = digits.trim_end_matches('.');
    let end = end - (text[..end].iter().rev().take_while(|c| matches!(c, '.' | ',')).count());
    digits.parse().ok().filter(|_| text.first().is_some_and(char::is_ascii_digit)).map(|n| (n, end))
}

/// The claims a paragraph makes: after each `` `--flag` `` (or `` `--flag N` ``), up to the next
/// flag, `;`, `|`, the end of a sentence or of the parenthesis, a default ("default 2", "2 by
/// default") and a range ("0–8").
fn flag_claims(line: usize, paragraph: &str) -> Vec<FlagClaim> {
    let chars: Vec<char> = paragraph.chars().collect();
    let mut claims = Vec::new();
    let mut at = 0;
    while let Some(start) =
        (at..chars.len()).find(|&i| chars[i] == '`' && chars[i + 1..].starts_with(&['-', '-']))
    {
        let Some(close) = (start + 1..chars.len()).find(|&i| chars[i] == '`') else { break };
        let span: String = chars[start + 1..close].iter().collect();
        at = close + 1;
        let mut words = span.split_whitespace();
        let Some(flag) = words.next().filter(|f| f.len() > 2 && !f.contains('=')) else { continue };
        // `--step 0.1` is a run's choice, not the flag's description; `--instances N` is one.
        if words.next().is_some_and(|value| !value.chars().all(|c| c.is_ascii_uppercase())) {
            continue;
        }
        let mut depth = 0i32;
        let mut end = at;
        while end < chars.len() {
            let c = chars[end];
            let sentence_end = c == '.' && chars.get(end + 1).is_none_or(|n| *n == ' ');
            if c == '(' {
                depth += 1;
            } else if c == ')' {
                depth -= 1;
            }
            if c == ';' || c == '|' || c == '`' || sentence_end || depth < 0 || (c == ')' && depth == 0) {
                break;
            }
            end += 1;
        }
        let window = &chars[at..end];
        let (mut default, mut range) = (None, None);
        for i in 0..window.len() {
            // Only what opens a clause of the flag's own: "(default 2", ", 0–8 pixels", not
            // "the default 65,026 triangles" or "keys 1–6".
            let before = window[..i].iter().rev().find(|c| **c != ' ');
            let opens = before.is_none_or(|c| matches!(c, '(' | ',' | ':'))
                && (i == 0 || window[i - 1] == ' ' || window[i - 1] == '(');
            if !opens {
                continue;
            }
            if window[i..].starts_with(&"default ".chars().collect::<Vec<_>>()) {
                default = default.or(page_number(&window[i + 8..]).map(|(n, _)| n));
            } else if let Some((n, len)) = page_number(&window[i..]) {
                let rest: String = window[i + len..].iter().collect();
                if rest.starts_with(" by default") {
                    default = default.or(Some(n));
                } else if let Some(after) = rest.strip_prefix('–')
                    && let Some((hi, _)) = page_number(&after.chars().collect::<Vec<_>>())
                {
                    range = range.or(Some((n, hi)));
                }
            }
        }
        if default.is_some() || range.is_some() {
            claims.push(FlagClaim { line, flag: flag.to_owned(), default, range });
        }
    }
    claims
}

/// Every claim of every page, by page: paragraphs are the prose's consecutive lines joined.
fn page_flag_claims() -> Vec<(Page, Vec<FlagClaim>)> {
    pages()
        .into_iter()
        .map(|page| {
            let mut claims = Vec::new();
            let mut paragraph: Option<(usize, usize, String)> = None;
            let lines = page.prose.iter().map(|(n, l)| (*n, l.as_str())).chain([(usize::MAX, "")]);
            for (number, line) in lines {
                let continues = paragraph.as_ref().is_some_and(|(_, last, _)| *last + 1 == number);
                let row = line.trim_start().starts_with('|');
                if !continues || line.trim().is_empty() || row {
                    if let Some((first, _, text)) = paragraph.take() {
                        claims.extend(flag_claims(first, &text));
                    }
                }
                if row {
                    claims.extend(flag_claims(number, line));
                } else if !line.trim().is_empty() {
                    let (first, _, mut text) = paragraph.take().unwrap_or((number, number, String::new()));
                    text.push(' ');
                    text.push_str(line.trim());
                    paragraph = Some((first, number, text));
                }
            }
            (page, claims)
        })
        .collect()
}

#[test]
fn the_flag_claim_reader_reads_the_pages_ways() {
    let read = |text: &str| flag_claims(1, text);
    let claim = |flag: &str, default, range| vec![FlagClaim { line: 1, flag: flag.into(), default, range }];
    assert_eq!(
        read("(`--blur`, 0–8 pixels, default 2; 0 turns it off)"),
        claim("--blur", Some(2.0), Some((0.0, 8.0)))
    );
    assert_eq!(
        read("`--instances N` (default 10,000) tetrahedra."),
        claim("--instances", Some(10_000.0), None)
    );
    assert_eq!(read("`--slots` images (2 by default: one being drawn)"), claim("--slots", Some(2.0), None));
    assert_eq!(read("`--samples` (per frame, 0–256, default 16), `--power` (1–3, default 2)").len(), 2);
    assert_eq!(read("`--radius` (default relative to the scene), and 5 by default elsewhere"), vec![]);
    assert_eq!(read("`--frames 4` draws 4. Then 3 by default"), vec![]);
    assert_eq!(read("`--step 0.1`, the default 65,026 triangles"), vec![]);
    assert_eq!(read("(`--view`, `--all-views` headless, keys 1–6 in a window)"), vec![]);
    assert_eq!(
        read("`--max-samples` rays (4096 by default, 256 frames of 16)"),
        claim("--max-samples", Some(4096.0), None)
    );
}

/// The programs whose flags a page can mean: its chapter's, where it is a chapter's page and the
/// chapter has the flag; else every program that has it (the tools, the other chapters).
fn programs_for<'a>(
    page: &Page,
    flag: &str,
    helps: &'a [(String, Vec<(String, String)>)],
) -> Vec<&'a (String, Vec<(String, String)>)> {
    let has = |(_, flags): &&(String, Vec<(String, String)>)| flags.iter().any(|(f, _)| f == flag);
    let own: Vec<_> =
        helps.iter().filter(|(name, _)| Some(name.as_str()) == page.chapter()).filter(has).collect();
    if own.is_empty() { helps.iter().filter(has).collect() } else { own }
}

/// `[default: X]` of a flag's help, as a number, if it starts with one.
fn help_default(text: &str) -> Option<Option<f64>> {
    let value = text.split("[default: ").nth(1)?;
    let chars: Vec<char> = value.chars().collect();
    Some(page_number(&chars).map(|(n, _)| n))
}

/// A page that gives a flag a default or a range gives the program's own: the default its
/// `--help` prints, a range its value parser accepts at both ends and refuses past them. The
/// one test here that runs the programs (`--help` alone, no GPU).
#[test]
fn flag_defaults_and_ranges_the_pages_give_are_the_programs() {
    let bins = Path::new(env!("CARGO_BIN_EXE_01-exportable-memory")).parent().unwrap();
    let mut names: Vec<String> = chapter_slugs().into_values().collect();
    names.extend(["bench".to_owned(), "convergence".to_owned()]);
    let paths: Vec<(String, String)> = names
        .iter()
        .map(|name| {
            let bin = bins.join(name);
            assert!(
                bin.exists(),
                "{} is not built: `cargo test --workspace` builds every program",
                bin.display()
            );
            (name.clone(), bin.to_string_lossy().into_owned())
        })
        .collect();
    let mut helps = Vec::new();
    for (name, bin) in &paths {
        for program in harness::flags::programs(bin) {
            let label =
                [name.clone()].into_iter().chain(program.1.iter().cloned()).collect::<Vec<_>>().join(" ");
            let chapter = if program.1.is_empty() { name.clone() } else { label };
            helps.push((chapter, program.clone(), harness::flags::flags_with_values(&program)));
        }
    }
    let by_flags: Vec<(String, Vec<(String, String)>)> =
        helps.iter().map(|(name, _, flags)| (name.clone(), flags.clone())).collect();
    let (mut errors, mut claims_seen) = (Vec::new(), 0);
    for (page, claims) in page_flag_claims() {
        for claim in claims {
            claims_seen += 1;
            let at = format!("{}:{}: {}", page.name, claim.line, claim.flag);
            let programs = programs_for(&page, &claim.flag, &by_flags);
            // The workshop's solutions add flags of their own (their patches are tested apart).
            if programs.is_empty() && page.name != "workshop.md" {
                errors.push(format!("{at}: no program's --help lists it"));
            }
            for (name, flags) in programs {
                let text = &flags.iter().find(|(f, _)| *f == claim.flag).unwrap().1;
                if let Some(default) = claim.default {
                    match help_default(text) {
                        Some(Some(d)) if d == default => {}
                        given => errors.push(format!(
                            "{at}: the page says default {default}, {name} --help gives {given:?}"
                        )),
                    }
                }
                if let Some((lo, hi)) = claim.range {
                    let program = &helps.iter().find(|(n, _, _)| n == name).unwrap().1;
                    let code = |v: f64| harness::flags::offer(program, &claim.flag, &v.to_string()).0;
                    let (inside, outside) = ([lo, hi], [lo - 1.0, hi + 1.0]);
                    let wrong: Vec<String> = inside
                        .iter()
                        .filter(|v| code(**v) != Some(0))
                        .map(|v| format!("{v} refused"))
                        .chain(
                            outside.iter().filter(|v| code(**v) == Some(0)).map(|v| format!("{v} accepted")),
                        )
                        .collect();
                    if !wrong.is_empty() {
                        errors.push(format!("{at}: the page gives {lo}–{hi}, {name}: {}", wrong.join(", ")));
                    }
                }
            }
        }
    }
    assert!(
        claims_seen >= 8,
        "only {claims_seen} flag defaults or ranges found in the pages: is the reader broken?"
    );
    assert!(
        errors.is_empty(),
        "pages that give a flag another default or range than the program:\n{}",
        errors.join("\n")
    );
}
