//! The book as printed, run. Three tests:
//!
//! - `transcripts_match_what_the_programs_print`: every transcript in `book/src/transcripts/`
//!   (the output blocks the pages `{{#include}}`) is run again, command by command, and what the
//!   programs print now must be what the file says, after [`normalise`].
//! - `every_output_block_is_a_transcript_or_listed`: a page's `text`/`console` block is one of
//!   those includes, or is listed in [`TYPED_OUTPUT`] with the reason it cannot come from a run
//!   here (a GPU's output, a program changed as the text describes ...).
//! - `printed_commands_run_as_printed`: every command line of every `sh` block of the book and
//!   the README runs and exits 0, unless [`SKIPPED`] names it (and why). It prints the counts.
//!
//! How a command runs, here and in `cargo run -p xtask -- transcripts`, which writes the
//! transcripts (it runs this test with `VKGL_UPDATE_TRANSCRIPTS=1`):
//! - by `sh`, as printed, in a fresh temporary directory holding a link to `assets/` (so
//!   `--scene assets/bunny.obj` works and the pictures go to that directory's `out/`);
//! - with no display (`DISPLAY` and `WAYLAND_DISPLAY` unset): the chapters that open a window say
//!   so and run headless, as on any machine without one;
//! - on Mesa's software stack (lavapipe + llvmpipe), pinned as in the other tests;
//! - with a stand-in for `cargo` first on `PATH`: `cargo run [--release] --bin NAME [-- ARGS]`
//!   runs the binary this test was built with (the debug build: `--release` changes speed, not
//!   what a program prints); any other use of `cargo` fails.
//!
//! A transcript is a file of `$ command` lines, each followed by what the command printed,
//! stdout and stderr together as a terminal shows them. To add one, write the `$` lines, run the
//! xtask, read what it wrote and include the file in a page's `console` block.

mod harness;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn transcripts_dir() -> PathBuf {
    root().join("book/src/transcripts")
}

/// Where the program of a transcript or a printed command will run: a temporary directory with
/// `assets/`, and a `cargo` that runs the binaries this test was built with.
struct Scratch {
    dir: tempfile::TempDir,
    tools: tempfile::TempDir,
}

impl Scratch {
    fn new() -> Scratch {
        let dir = tempfile::tempdir().expect("temporary directory");
        std::os::unix::fs::symlink(root().join("assets"), dir.path().join("assets")).unwrap();
        let tools = tempfile::tempdir().expect("temporary directory");
        // Every binary of the package lands in one directory; the test knows one of them.
        let bins = Path::new(env!("CARGO_BIN_EXE_01-exportable-memory")).parent().unwrap();
        let cargo = tools.path().join("cargo");
        std::fs::write(&cargo, CARGO_STAND_IN.replace("@BINS@", &bins.display().to_string())).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&cargo, std::fs::Permissions::from_mode(0o755)).unwrap();
        Scratch { dir, tools }
    }

    /// `sh -c script` there, stdout and stderr in one stream as a terminal shows them: what it
    /// printed, and its exit status.
    fn run(&self, script: &str) -> (String, Option<i32>) {
        let path = std::env::var_os("PATH").unwrap_or_default();
        let mut paths = vec![self.tools.path().to_owned()];
        paths.extend(std::env::split_paths(&path));
        let mut command = Command::new("sh");
        command
            .arg("-c")
            .arg(format!("{{\n{script}\n}} 2>&1"))
            .current_dir(self.dir.path())
            .env("PATH", std::env::join_paths(paths).unwrap())
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY")
            .env_remove("VKGL_HIDE_EXTENSIONS")
            .env_remove("VKGL_FAIL_AT");
        harness::pin_software_stack(&mut command);
        let output = command.output().expect("starting sh");
        (String::from_utf8_lossy(&output.stdout).into_owned(), output.status.code())
    }
}

/// `cargo run [--release] [-p PACKAGE] --bin NAME [-- ARGS]`, as the pages print it, runs the
/// binary `cargo test` built; nothing else.
const CARGO_STAND_IN: &str = r#"#!/bin/sh
# The tests' stand-in for cargo (tests/transcripts.rs): runs `cargo run --bin NAME -- ARGS` as
# the binary that `cargo test` built, and nothing else.
if [ "$1" != run ]; then echo "cargo (stand-in): the tests run only 'cargo run --bin NAME', not: cargo $*" >&2; exit 97; fi
shift
bin=
while [ $# -gt 0 ]; do
    case "$1" in
        --release) shift ;;
        --bin) bin=$2; shift 2 ;;
        -p) shift 2 ;; # chapter 15's package: its binary is built beside the others
        --) shift; break ;;
        *) echo "cargo (stand-in): '$1' is not a flag the tests pass on" >&2; exit 97 ;;
    esac
done
if [ -z "$bin" ]; then echo "cargo (stand-in): no --bin" >&2; exit 97; fi
exec "@BINS@/$bin" "$@"
"#;

/// One transcript file: its `$` commands, each with what it printed.
struct Transcript {
    name: String,
    text: String,
}

impl Transcript {
    fn commands(&self) -> Vec<&str> {
        self.text.lines().filter_map(|l| l.strip_prefix("$ ")).collect()
    }

    /// Runs the commands one after another in one shell (so that `echo $?` reports the command
    /// before it and a file one command writes is there for the next), echoing each as `$ ...`.
    fn run(&self) -> String {
        let mut script = String::from("status=0\n");
        for command in self.commands() {
            let shown = format!("$ {command}").replace('\'', r"'\''");
            script.push_str(&format!("printf '%s\\n' '{shown}'\n(exit $status)\n{command}\nstatus=$?\n"));
        }
        Scratch::new().run(&script).0
    }
}

fn transcripts() -> Vec<Transcript> {
    let mut found: Vec<Transcript> = std::fs::read_dir(transcripts_dir())
        .expect("book/src/transcripts")
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "txt"))
        .map(|e| Transcript {
            name: e.file_name().to_string_lossy().into_owned(),
            text: std::fs::read_to_string(e.path()).unwrap(),
        })
        .collect();
    found.sort_by(|a, b| a.name.cmp(&b.name));
    found
}

/// What may differ between two runs of the same program on the software stack, masked:
/// - a number of milliseconds (`1.305 ms` -> `[ms]`) and a ratio of two (`(1.03x)`): timings;
/// - the versions in a device's name (`LLVM 15.0.6`, `Mesa 25.0.7-2~bpo12+1`, `256 bits`, the
///   vector width LLVM picked for this CPU) -> `LLVM [v]`, `Mesa [v]`, `[n] bits`;
/// - UUIDs (32 hex digits) -> `[uuid]`;
/// - file descriptor numbers (`fd 6`, `open fds: 7 before ...`, `"4 -> /memfd:..."`) -> `[n]`;
/// - process ids (`(pid 4711)`: chapter 14's viewer) -> `[n]`;
/// - trailing spaces.
///
/// Everything else must match: which checks ran, in which order, passed or failed, how many, the
/// files written, the counts and measurements that are not timings (pixels, bytes, noise).
fn normalise(text: &str) -> Vec<String> {
    text.lines().map(normalise_line).collect()
}

fn normalise_line(line: &str) -> String {
    let fds = line.trim_start().starts_with("open fds:") || line.contains("left open");
    let words: Vec<&str> = line.trim_end().split(' ').collect();
    let mut out: Vec<String> = Vec::with_capacity(words.len());
    for (i, word) in words.iter().enumerate() {
        let previous = i.checked_sub(1).map(|p| words[p].trim_start_matches('('));
        let next = words.get(i + 1).copied();
        let paren = if word.starts_with('(') { "(" } else { "" };
        let (head, tail) = split_number(word.strip_prefix('(').unwrap_or(word));
        let masked = if !head.is_empty() && next.is_some_and(|n| n == "ms" || n.starts_with("ms")) {
            format!("{paren}[ms]{tail}")
        } else if !head.is_empty() && paren == "(" && tail.starts_with("x)") {
            format!("([ratio]{tail}")
        } else if !head.is_empty() && tail.is_empty() && next.is_some_and(|n| n.starts_with("bits")) {
            "[n]".to_owned()
        } else if matches!(previous, Some("LLVM" | "Mesa")) && word.starts_with(|c: char| c.is_ascii_digit())
        {
            let end = word.find([')', ',']).unwrap_or(word.len());
            format!("[v]{}", &word[end..])
        } else if !head.is_empty() && (previous == Some("fd") || previous == Some("pid") || fds) {
            format!("[n]{tail}")
        } else if word.starts_with("[\"") && next == Some("->") {
            "[\"[n]".to_owned()
        } else if word.trim_end_matches(',').len() == 32
            && word.trim_end_matches(',').chars().all(|c| c.is_ascii_hexdigit())
        {
            format!("[uuid]{}", if word.ends_with(',') { "," } else { "" })
        } else {
            (*word).to_owned()
        };
        out.push(masked);
    }
    out.join(" ")
}

/// `1.305` -> (`1.305`, ``); `6,` -> (`6`, `,`); `abc` -> (``, `abc`).
fn split_number(word: &str) -> (&str, &str) {
    let end = word.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(word.len());
    let head = &word[..end];
    if head.starts_with(|c: char| c.is_ascii_digit()) { (head, &word[end..]) } else { ("", word) }
}

#[test]
fn normalise_masks_only_what_varies() {
    let cases = [
        (
            "host handshake: the CPU spends 1.305 ms a frame in it (median)",
            "host handshake: the CPU spends [ms] ms a frame in it (median)",
        ),
        (
            "vulkan: using llvmpipe (LLVM 15.0.6, 256 bits) (llvmpipe Mesa 25.0.7-2~bpo12+1 (LLVM 15.0.6))",
            "vulkan: using llvmpipe (LLVM [v], [n] bits) (llvmpipe Mesa [v] (LLVM [v]))",
        ),
        (
            "device UUID 6d65736132352e302e372d327e627000, driver UUID 6c6c766d706970655555494400000000",
            "device UUID [uuid], driver UUID [uuid]",
        ),
        (
            "buffer fd 6 -> /memfd:llvmpipe memory fd (deleted)",
            "buffer fd [n] -> /memfd:llvmpipe memory fd (deleted)",
        ),
        ("renderer: started the viewer (pid 4711)", "renderer: started the viewer (pid [n])"),
        (
            "open fds: 7 before exporting, 7 after cleaning up",
            "open fds: [n] before exporting, [n] after cleaning up",
        ),
        (
            "fds: left open after the chapter ran: [\"4 -> /memfd:allocation fd (deleted)\"]",
            "fds: left open after the chapter ran: [\"[n] -> /memfd:allocation fd (deleted)\"]",
        ),
        (
            "      pbo:  cpu_trace 162.290 ms  gl_upload 0.612 ms",
            "      pbo:  cpu_trace [ms] ms  gl_upload [ms] ms",
        ),
        (
            "trace through the updated TLAS 60.061 ms, through a rebuilt one 58.028 ms (1.04x)",
            "trace through the updated TLAS [ms] ms, through a rebuilt one [ms] ms ([ratio]x)",
        ),
    ];
    for (line, expected) in cases {
        assert_eq!(normalise_line(line), expected);
    }
    // What a transcript is for stays: checks, counts, pixels.
    for line in [
        "  [FAIL] gl_sees_each_frame_vulkan_wrote",
        "03-semaphores: all 4 checks passed",
        "rays and raster disagree on 0 of 76800 pixels (0.000%)",
        "noise between neighbours: 0.1046 after one frame, 0.0836 after 64 rays",
        "BLAS: 592 bytes built, 592 compacted; TLAS: 1760160 bytes",
    ] {
        assert_eq!(normalise_line(line), line);
    }
}

/// Transcripts that hold only where a condition holds, and the condition.
fn condition_unmet(transcript: &str) -> Option<&'static str> {
    // The message a machine without NVIDIA's driver prints; with it, CUDA runs.
    let cuda = || {
        ["ldconfig", "/sbin/ldconfig"].iter().any(|ldconfig| {
            Command::new(ldconfig)
                .arg("-p")
                .output()
                .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).contains("libcuda.so.1 "))
        })
    };
    (transcript.contains("no-cuda") && cuda())
        .then_some("ldconfig lists libcuda.so.1: this machine has NVIDIA's driver")
}

#[test]
fn transcripts_match_what_the_programs_print() {
    let update = std::env::var_os("VKGL_UPDATE_TRANSCRIPTS").is_some();
    let transcripts = transcripts();
    assert!(transcripts.len() >= 10, "only {} transcripts in book/src/transcripts", transcripts.len());
    let mut stale = Vec::new();
    let mut commands = 0;
    for transcript in &transcripts {
        assert!(
            !transcript.commands().is_empty(),
            "{}: no `$ command` line, so nothing to run",
            transcript.name
        );
        if let Some(why) = condition_unmet(&transcript.name) {
            eprintln!("not comparing {}: {why}", transcript.name);
            continue;
        }
        let start = Instant::now();
        let now = transcript.run();
        commands += transcript.commands().len();
        eprintln!("{}: {:.1} s", transcript.name, start.elapsed().as_secs_f64());
        let (expected, actual) = (normalise(&transcript.text), normalise(&now));
        if expected == actual {
            continue;
        }
        if update {
            std::fs::write(transcripts_dir().join(&transcript.name), &now).unwrap();
            eprintln!("wrote book/src/transcripts/{}", transcript.name);
            continue;
        }
        stale.push(format!("{}:\n{}", transcript.name, diff(&expected, &actual)));
    }
    eprintln!("{} transcripts, {commands} commands run", transcripts.len());
    assert!(
        stale.is_empty(),
        "the book's transcripts no longer show what the programs print (after masking timings, \
         versions, UUIDs and fd numbers).\nRegenerate them with `cargo run -p xtask -- transcripts`, \
         read `git diff book/src/transcripts` and the pages that include them:\n\n{}",
        stale.join("\n\n")
    );
}

/// The lines that differ, `-` the file's and `+` the program's, each with its line number in
/// the file or in the program's output (a longest-common-subsequence diff).
fn diff(expected: &[String], actual: &[String]) -> String {
    let (n, m) = (expected.len(), actual.len());
    // common[i][j]: the longest common subsequence of expected[i..] and actual[j..].
    let mut common = vec![vec![0usize; m + 1]; n + 1];
    for i in (0..n).rev() {
        for j in (0..m).rev() {
            common[i][j] = if expected[i] == actual[j] {
                common[i + 1][j + 1] + 1
            } else {
                common[i + 1][j].max(common[i][j + 1])
            };
        }
    }
    let (mut i, mut j, mut out) = (0, 0, Vec::new());
    while i < n || j < m {
        if i < n && j < m && expected[i] == actual[j] {
            (i, j) = (i + 1, j + 1);
        } else if j == m || (i < n && common[i + 1][j] >= common[i][j + 1]) {
            out.push(format!("{:>4} - {}", i + 1, expected[i]));
            i += 1;
        } else {
            out.push(format!("{:>4} + {}", j + 1, actual[j]));
            j += 1;
        }
    }
    out.join("\n")
}

/// The book's pages (`book/src/**/*.md`, not the links to the sources) and the README.
fn pages() -> Vec<(String, String)> {
    let mut files = harness::files_ending(&root().join("book/src"), "md");
    files.push(root().join("README.md"));
    files.sort();
    files
        .iter()
        .map(|f| {
            let name = f.strip_prefix(root()).unwrap().to_string_lossy().into_owned();
            (name, std::fs::read_to_string(f).unwrap())
        })
        .collect()
}

/// A page's fenced blocks: the info string (`sh`, `text`, `console` ...), the line of the
/// opening fence, and the lines inside.
fn blocks(text: &str) -> Vec<(String, usize, Vec<String>)> {
    let mut found = Vec::new();
    let mut open: Option<(String, usize, Vec<String>)> = None;
    for (number, line) in text.lines().enumerate() {
        let fence = line.trim_start().starts_with("```");
        match (&mut open, fence) {
            (None, true) => {
                open = Some((
                    line.trim_start().trim_start_matches('`').trim().to_owned(),
                    number + 1,
                    Vec::new(),
                ))
            }
            (Some(_), true) => found.push(open.take().unwrap()),
            (Some((_, _, lines)), false) => lines.push(line.to_owned()),
            (None, false) => {}
        }
    }
    found
}

// ANCHOR: typed
/// Output blocks that are typed, not generated: each shows what the tests cannot produce on
/// lavapipe, for the reason given. Keyed by page and the block's first line.
#[rustfmt::skip]
const TYPED_OUTPUT: &[(&str, &str, &str)] = &[
    ("book/src/01-exportable-memory.md", "vulkan: using NVIDIA H200", "an NVIDIA H200's output"),
    ("book/src/02-gl-buffer-import-deeper.md", "vulkan: using NVIDIA H200", "an NVIDIA H200's output"),
    ("book/src/02-gl-buffer-import.md", "gl debug error: GL_INVALID_OPERATION", "the program changed as the text says"),
    ("book/src/02-gl-buffer-import.md", "gl debug error: GL_OUT_OF_MEMORY", "the program changed as the text says"),
    ("book/src/03-semaphores-deeper.md", "vulkan: using NVIDIA H200", "an NVIDIA H200's output"),
    ("book/src/03-semaphores-deeper.md", "sync: host (GL cannot import semaphores", "a GPU's output, semaphores hidden"),
    ("book/src/03-semaphores-deeper.md", "$ cargo run --release --bin 03-semaphores -- --headless --frames 8", "the program changed as the text says"),
    ("book/src/06-blas-tlas.md", "rays and raster disagree on 40562", "the program changed as the text says"),
    ("book/src/troubleshooting.md", "error: GL and Vulkan run on different devices", "needs two GPUs"),
    ("book/src/troubleshooting.md", "error: no GL configuration for a window", "needs an X server with no GLX for the GPU"),
    ("book/src/troubleshooting.md", "gl debug error: GL_OUT_OF_MEMORY", "the program changed as page 02 says"),
];
// ANCHOR_END: typed

#[test]
fn every_output_block_is_a_transcript_or_listed() {
    let mut errors = Vec::new();
    let mut used = vec![false; TYPED_OUTPUT.len()];
    let mut included = 0;
    for (page, text) in pages() {
        for (info, line, lines) in blocks(&text) {
            if !matches!(info.as_str(), "text" | "console" | "") {
                continue;
            }
            let first = lines.first().map(|l| l.trim()).unwrap_or_default();
            if lines.len() == 1 && first.starts_with("{{#include transcripts/") {
                let file = first.trim_start_matches("{{#include ").trim_end_matches("}}");
                if !root().join("book/src").join(file).is_file() {
                    errors.push(format!("{page}:{line}: includes {file}, which does not exist"));
                }
                included += 1;
                continue;
            }
            match TYPED_OUTPUT.iter().position(|(p, start, _)| *p == page && first.starts_with(start)) {
                Some(i) => used[i] = true,
                None => errors.push(format!(
                    "{page}:{line}: an output block that is neither a transcript include \
                     ({{{{#include transcripts/NAME.txt}}}}) nor listed in TYPED_OUTPUT: `{first}`"
                )),
            }
        }
    }
    for (i, (page, start, _)) in TYPED_OUTPUT.iter().enumerate() {
        if !used[i] {
            errors.push(format!("TYPED_OUTPUT lists {page}'s block `{start}`, which is not there"));
        }
    }
    let files = transcripts().len();
    assert!(included >= files, "{included} includes for {files} transcripts: is one unused?");
    assert!(errors.is_empty(), "{}", errors.join("\n"));
    eprintln!("{included} output blocks included from transcripts, {} typed", TYPED_OUTPUT.len());
}

// ANCHOR: skipped
/// Printed commands the tests do not run, by how they start (or, ending in `$`, the whole
/// command), and why. `Slow` ones run when `VKGL_RUN_SLOW_COMMANDS=1` is set (the times are
/// the debug builds' on lavapipe, 2 CPU cores).
#[rustfmt::skip]
const SKIPPED: &[(&str, Skip)] = &[
    ("bash .ci/deps", Skip::Always("installs packages")),
    ("cargo install", Skip::Always("installs packages")),
    ("cargo build", Skip::Always("builds: `cargo test` built what the tests run")),
    ("cargo test", Skip::Always("runs the tests, this one included")),
    ("mdbook serve", Skip::Always("serves the book until stopped (tests/book.rs builds it)")),
    ("git apply", Skip::Always("changes the checkout (tests/workshop.rs applies the patches to a copy)")),
    ("cargo run --release --bin 11-cuda-depth-composite -- --tracer cuda", Skip::Always("needs CUDA: an NVIDIA GPU")),
    ("cargo run --release --bin 09-animated-instances -- --headless --json --size 1920x1080", Skip::Always("sized for a GPU")),
    ("cargo run --release --bin 10-vertex-animation -- --headless --json --size 1920x1080", Skip::Always("sized for a GPU")),
    ("cargo run --release --bin bench -- --json", Skip::Always("the full sweep: minutes on a GPU")),
    ("cargo run --release --bin bench -- --scenes default --spp 16", Skip::Always("the default scene's sweep at 16 rays: minutes on a GPU")),
    ("cargo run --release --bin bench -- --probe", Skip::Always("4K and 1080p: sized for a GPU")),
    ("cargo run --release --bin convergence -- --json", Skip::Always("the full sweep: minutes on a GPU")),
    ("cargo run --release --bin 14-two-processes -- --listen", Skip::Always("waits for the viewer a second terminal starts")),
    ("cargo run --release --bin 14-two-processes -- --connect", Skip::Always("connects to the renderer of a first terminal")),
    ("cargo run --release --bin bench -- --quick", Skip::Slow("35 to 55 s")),
    ("cargo run --release --bin 07-ao-ray-pipeline -- --headless --size 320x240 --frames 4 --scene", Skip::Slow("35 to 50 s")),
    ("cargo run --release --bin 08-composite -- --headless --size 320x240 --frames 4 --scene", Skip::Slow("about 45 s")),
    ("cargo run --release --bin 08-composite$", Skip::Slow("a window's size, headless: about 25 s")),
    ("cargo run --release --bin 09-animated-instances", Skip::Slow("20 s to 2.5 min")),
    ("cargo run --release --bin 12-fast-frame", Skip::Slow("50 s to 1.5 min")),
    ("Xvfb :7", Skip::Always("starts an X server, which runs until it is stopped")),
    ("DISPLAY=:7 __GLX_VENDOR_LIBRARY_NAME=nvidia", Skip::Always("needs an NVIDIA GPU and the X server above")),
    ("cargo run --release --bin 13-temporal-reuse$", Skip::Slow("a window's size, 120 frames headless: minutes")),
    ("cargo run --release --bin convergence -- temporal --size 1920x1080", Skip::Always("sized for a GPU")),
    ("cargo run --release --bin convergence -- temporal --size 3840x2160", Skip::Always("sized for a GPU")),
    ("VKGL_VALIDATION=0 cargo run --release --bin 03-semaphores -- --headless --size 3840x2160", Skip::Always("sized for a GPU")),
    ("VKGL_VALIDATION=0 cargo run --release -p chapter-15-wgpu --bin 15-wgpu -- --headless --size 3840x2160", Skip::Always("sized for a GPU")),
    ("VKGL_VALIDATION=0 cargo run --release -p chapter-16-textures --bin 16-textures -- --headless --size 3840x2160", Skip::Always("sized for a GPU: 300 frames at 4K")),
];
// ANCHOR_END: skipped

#[derive(Clone, Copy)]
enum Skip {
    Always(&'static str),
    Slow(&'static str),
}

/// Every command line of every `sh` block: (page:line, the command as printed). A line that is
/// only a comment is not a command.
fn printed_commands() -> Vec<(String, String)> {
    let mut found = Vec::new();
    for (page, text) in pages() {
        for (info, line, lines) in blocks(&text) {
            if info != "sh" {
                continue;
            }
            for (i, command) in lines.iter().enumerate() {
                let command = command.trim();
                if command.is_empty() || command.starts_with('#') {
                    continue;
                }
                found.push((format!("{page}:{}", line + 1 + i), command.to_owned()));
            }
        }
    }
    found
}

/// The command without its comment and with single spaces, as the skip list is written.
fn bare(command: &str) -> String {
    let without_comment = command.split(" #").next().unwrap();
    without_comment.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Does a skip-list entry name this command?
fn skips(entry: &str, command: &str) -> bool {
    match entry.strip_suffix('$') {
        Some(whole) => bare(command) == whole,
        None => bare(command).starts_with(entry),
    }
}

#[test]
fn printed_commands_run_as_printed() {
    let slow_too = std::env::var_os("VKGL_RUN_SLOW_COMMANDS").is_some();
    let commands = printed_commands();
    assert!(commands.len() >= 30, "only {} printed commands found: did the pages move?", commands.len());
    let mut used = vec![false; SKIPPED.len()];
    let (mut ran, mut skipped, mut failed) = (0, Vec::new(), Vec::new());
    let started = Instant::now();
    for (at, command) in &commands {
        let skip = SKIPPED.iter().position(|(entry, _)| skips(entry, command));
        if let Some(i) = skip {
            used[i] = true;
            match SKIPPED[i].1 {
                Skip::Always(why) => {
                    skipped.push(format!("{at}: {command}  ({why})"));
                    continue;
                }
                Skip::Slow(why) if !slow_too => {
                    skipped.push(format!("{at}: {command}  (slow: {why}; VKGL_RUN_SLOW_COMMANDS=1 runs it)"));
                    continue;
                }
                Skip::Slow(_) => {}
            }
        }
        let start = Instant::now();
        let (output, status) = Scratch::new().run(command);
        ran += 1;
        eprintln!("ran {at}: {command}  ({:.1} s, exit {status:?})", start.elapsed().as_secs_f64());
        if status != Some(0) {
            failed.push(format!("{at}: `{command}` exited with {status:?}:\n{output}"));
        }
    }
    for (i, (start, _)) in SKIPPED.iter().enumerate() {
        assert!(used[i], "SKIPPED names `{start}`, which no page prints: remove it");
    }
    eprintln!(
        "printed commands: {} on the pages, {ran} run ({:.0} s), {} skipped:\n  {}",
        commands.len(),
        started.elapsed().as_secs_f64(),
        skipped.len(),
        skipped.join("\n  ")
    );
    assert!(failed.is_empty(), "printed commands that fail as printed:\n\n{}", failed.join("\n\n"));
}

/// The run a chapter's page shows under "## Run it" or "## What you should see" (its first
/// transcript there) is the output of the first command the page prints at its top, the one a
/// reader (and a workshop laptop without a GPU) runs first: not the same program at another
/// size, whose numbers differ, nor a window's run. Pure text: no program runs.
#[test]
fn each_page_shows_the_run_of_a_command_it_prints_at_the_top() {
    let mut errors = Vec::new();
    let mut checked = 0;
    for (page, text) in pages() {
        let Some(name) = page.strip_prefix("book/src/") else { continue };
        if !name.as_bytes()[..2].iter().all(u8::is_ascii_digit) || name.ends_with("-deeper.md") {
            continue;
        }
        let top: Vec<String> = blocks(&text)
            .into_iter()
            .find(|(info, _, _)| info == "sh")
            .map(|(_, _, lines)| {
                lines
                    .iter()
                    .filter(|l| !l.trim().is_empty() && !l.trim().starts_with('#'))
                    .map(|l| bare(l))
                    .collect()
            })
            .unwrap_or_default();
        // The run sits under "## Run it" where a page shows it before its steps, else under
        // "## What you should see".
        let section =
            text.split("\n## Run it").nth(1).or_else(|| text.split("\n## What you should see").nth(1));
        let Some(section) = section else { continue };
        let Some(file) =
            section.split("{{#include transcripts/").nth(1).and_then(|rest| rest.split("}}").next())
        else {
            continue;
        };
        let transcript = std::fs::read_to_string(transcripts_dir().join(file)).unwrap();
        let Some(command) = transcript.lines().find_map(|l| l.strip_prefix("$ ")) else { continue };
        checked += 1;
        if top.first() != Some(&bare(command)) {
            errors.push(format!(
                "{page}: \"What you should see\" shows transcripts/{file}, the output of `{command}`, \
                 which is not the first command at the top of the page: {top:?}"
            ));
        }
    }
    assert!(checked >= 10, "only {checked} chapter pages show a run under \"What you should see\"");
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}
