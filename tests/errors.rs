//! Error paths: every fallible step of every chapter, made to fail in turn, must leave nothing
//! behind. `VKGL_FAIL_AT=list` (common::instruments::fail) lists the steps a run reaches, numbered;
//! `VKGL_FAIL_AT=<n>` makes step n fail as a driver might. Each such run must exit 2 with an
//! error naming the step, without a panic, without a single validation message (a Vulkan object
//! still alive when the device is destroyed is one: "has not been destroyed"), with no counted
//! resource alive at exit (`common::instruments::resources::live`: exportable memory, every GL object
//! ...), and with no file descriptor left open beyond those the driver keeps after a successful
//! run (the listing run, which fails nothing, is the baseline).

mod harness;

use harness::{Run, flags, run_chapter, run_chapter_with};
use std::collections::BTreeMap;

/// A chapter, how it runs (small, few frames: a failure injected early in a run is as cheap as
/// the run up to it), whether it takes `--headless`, and the variable that injects its failures.
struct Case {
    name: &'static str,
    bin: &'static str,
    args: &'static [&'static str],
    headless: bool,
    fail_at: &'static str,
}

const fn chapter(name: &'static str, bin: &'static str, args: &'static [&'static str]) -> Case {
    Case { name, bin, args, headless: true, fail_at: "VKGL_FAIL_AT" }
}

const CH14: &[&str] = &["--size", "32x24", "--frames", "3"];

const CASES: &[Case] = &[
    chapter("01-exportable-memory", env!("CARGO_BIN_EXE_01-exportable-memory"), &["--size", "32x24"]),
    chapter("02-gl-buffer-import", env!("CARGO_BIN_EXE_02-gl-buffer-import"), &["--size", "32x24"]),
    chapter("03-semaphores", env!("CARGO_BIN_EXE_03-semaphores"), &["--size", "32x24", "--frames", "3"]),
    chapter(
        "04-compute-triangle",
        env!("CARGO_BIN_EXE_04-compute-triangle"),
        &["--size", "64x48", "--frames", "3"],
    ),
    chapter("05-g-buffers", env!("CARGO_BIN_EXE_05-g-buffers"), &["--size", "32x24"]),
    chapter("06-blas-tlas", env!("CARGO_BIN_EXE_06-blas-tlas"), &["--size", "32x24"]),
    chapter(
        "07-ao-ray-pipeline",
        env!("CARGO_BIN_EXE_07-ao-ray-pipeline"),
        &["--size", "32x24", "--frames", "2", "--samples", "2"],
    ),
    chapter(
        "08-composite",
        env!("CARGO_BIN_EXE_08-composite"),
        &["--size", "64x48", "--frames", "3", "--samples", "2", "--resize-every", "2"],
    ),
    chapter(
        "09-animated-instances",
        env!("CARGO_BIN_EXE_09-animated-instances"),
        &["--size", "32x24", "--frames", "2", "--samples", "2"],
    ),
    chapter(
        "10-vertex-animation",
        env!("CARGO_BIN_EXE_10-vertex-animation"),
        &["--size", "64x48", "--frames", "2", "--samples", "2", "--rings", "16"],
    ),
    chapter(
        "11-cuda-depth-composite",
        env!("CARGO_BIN_EXE_11-cuda-depth-composite"),
        &["--size", "32x32", "--frames", "2"],
    ),
    chapter(
        "12-fast-frame",
        env!("CARGO_BIN_EXE_12-fast-frame"),
        &["--size", "64x48", "--frames", "3", "--samples", "2", "--resize-every", "2"],
    ),
    chapter(
        "13-temporal-reuse",
        env!("CARGO_BIN_EXE_13-temporal-reuse"),
        &["--size", "64x48", "--frames", "4", "--cut-at", "2", "--instances", "50"],
    ),
    // The same walk without a cut: every frame but the last draws the next one's ids before it
    // waits, and those steps fail too.
    chapter(
        "13-temporal-reuse, next ids early",
        env!("CARGO_BIN_EXE_13-temporal-reuse"),
        &["--size", "64x48", "--frames", "4", "--cut-at", "0", "--instances", "50"],
    ),
    // Chapter 13's frame measured: the error against a converged trace of each frame.
    Case {
        name: "convergence temporal",
        bin: env!("CARGO_BIN_EXE_convergence"),
        args: &[
            "temporal",
            "--size",
            "64x48",
            "--frames",
            "4",
            "--cut-at",
            "2",
            "--instances",
            "50",
            "--error-against",
            "8",
        ],
        headless: false,
        fail_at: "VKGL_FAIL_AT",
    },
    // Two processes: VKGL_FAIL_AT fails the renderer's steps (its viewer is started without it);
    // VKGL_VIEWER_FAIL_AT, which the renderer passes on as the viewer's VKGL_FAIL_AT, the
    // viewer's, whose refusal the renderer reports as its own error (exit 2). The viewer's list
    // of what it left is the one printed then: the renderer, unarmed, prints none.
    chapter("14-two-processes", env!("CARGO_BIN_EXE_14-two-processes"), CH14),
    Case {
        fail_at: "VKGL_VIEWER_FAIL_AT",
        ..chapter("14-two-processes (viewer)", env!("CARGO_BIN_EXE_14-two-processes"), CH14)
    },
    Case {
        name: "bench",
        bin: env!("CARGO_BIN_EXE_bench"),
        args: &["--quick", "--scenes", "ceiling", "--sizes", "32x24", "--spp", "1"],
        headless: false,
        fail_at: "VKGL_FAIL_AT",
    },
    Case {
        name: "convergence",
        bin: env!("CARGO_BIN_EXE_convergence"),
        args: &["--quick", "--exact-only"],
        headless: false,
        fail_at: "VKGL_FAIL_AT",
    },
];

fn run(case: &Case, fail_at: &str) -> Run {
    let env = [(case.fail_at, fail_at)];
    match case.headless {
        true => run_chapter(case.bin, case.args, &env),
        false => run_chapter_with(case.bin, case.args, &env),
    }
}

/// The steps a run reached: (number, what), in order.
fn steps(run: &Run) -> Vec<(u32, String)> {
    run.stderr
        .lines()
        .filter_map(|l| l.strip_prefix("fail step "))
        .filter_map(|l| l.split_once(": "))
        .map(|(n, what)| (n.parse().expect("a step number"), what.to_owned()))
        .collect()
}

/// Which steps to fail: the first and the last time each step is reached. The first proves the
/// cleanup of what exists before it; the last, of a step in a loop, the cleanup with a frame's
/// work in flight. (Failing every repetition of a frame's submission proves no more.)
fn chosen(steps: &[(u32, String)]) -> Vec<(u32, String)> {
    let mut first_and_last: BTreeMap<&str, (u32, u32)> = BTreeMap::new();
    for (n, what) in steps {
        first_and_last.entry(what).and_modify(|(_, last)| *last = *n).or_insert((*n, *n));
    }
    let mut chosen: Vec<(u32, String)> = first_and_last
        .iter()
        .flat_map(|(what, &(first, last))| {
            let both = if first == last { vec![first] } else { vec![first, last] };
            both.into_iter().map(|n| (n, what.to_string()))
        })
        .collect();
    chosen.sort();
    chosen
}

/// What each fd left open at exit points at (the fd numbers themselves may differ between runs).
fn fds_left(run: &Run) -> Vec<String> {
    listed_fds(run)
        .unwrap_or_else(|| panic!("with VKGL_FAIL_AT the chapter lists the fds it left:\n{}", run.stderr))
}

/// The fds a run listed, if it got as far as listing them.
fn listed_fds(run: &Run) -> Option<Vec<String>> {
    harness::fds_listed(&run.stderr)
}

/// What is wrong with a run whose step `n` failed, if anything: its exit code, its error, what
/// it printed, and what it left.
fn problems(run: &Run, (n, what): &(u32, String), kept_by_driver: &[String]) -> Vec<String> {
    let mut problems = Vec::new();
    if run.output.status.code() != Some(2) {
        problems.push(format!("exit code {:?}, not 2", run.output.status.code()));
    }
    // The error line: the step's own message, perhaps behind the context of what it was for.
    let named = format!("injected failure at step {n}: {what} (VKGL_FAIL_AT={n})");
    if !run.stderr.lines().any(|l| l.starts_with("error: ") && l.contains(&named)) {
        problems.push("no error naming the step".into());
    }
    for bad in ["panicked", "has not been destroyed", "not destroyed", "validation error", "RUST_BACKTRACE"] {
        if run.stderr.contains(bad) {
            problems.push(format!("stderr contains {bad:?}"));
        }
    }
    if !run.stderr.contains("resources: alive after the chapter ran: []") {
        problems.push("resources left alive".into());
    }
    match listed_fds(run) {
        None => problems.push("no list of the fds left (did it crash?)".into()),
        Some(mut left) => {
            left.retain(|fd| !kept_by_driver.contains(fd));
            if !left.is_empty() {
                problems.push(format!("fds left open: {left:?}"));
            }
        }
    }
    problems
}

#[test]
fn every_fallible_step_of_every_chapter_fails_cleanly() {
    // A few runs at once: each is one process, mostly waiting on the software driver.
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get()).clamp(2, 4);
    let (mut injected, mut reached, mut failures) = (0, 0, Vec::new());
    // `VKGL_ERRORS_ONLY=14-two`: only the programs whose name has it, while working on one.
    let only = std::env::var("VKGL_ERRORS_ONLY").unwrap_or_default();
    let cases: Vec<&Case> = CASES.iter().filter(|case| case.name.contains(&only)).collect();
    for case in &cases {
        // The listing run fails nothing: it must pass its checks, and is the fd baseline.
        let listing = run(case, "list");
        listing.succeeded();
        let kept_by_driver = fds_left(&listing);
        let all = steps(&listing);
        assert!(!all.is_empty(), "{}: VKGL_FAIL_AT=list listed no step:\n{}", case.name, listing.stderr);
        let chosen = chosen(&all);
        let next = std::sync::atomic::AtomicUsize::new(0);
        let found: Vec<String> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..workers)
                .map(|_| {
                    scope.spawn(|| {
                        let mut found = Vec::new();
                        while let Some(step) =
                            chosen.get(next.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
                        {
                            let run = run(case, &step.0.to_string());
                            let problems = problems(&run, step, &kept_by_driver);
                            if !problems.is_empty() {
                                let (n, what) = step;
                                let stderr: Vec<_> = run.stderr.lines().rev().take(20).collect();
                                let stderr = stderr.into_iter().rev().collect::<Vec<_>>().join("\n    ");
                                found.push(format!(
                                    "{} VKGL_FAIL_AT={n} ({what}): {}\n    {stderr}",
                                    case.name,
                                    problems.join("; ")
                                ));
                            }
                        }
                        found
                    })
                })
                .collect();
            workers.into_iter().flat_map(|w| w.join().expect("a worker thread")).collect()
        });
        eprintln!(
            "{}: {} steps reached, {} of them distinct; {} failures injected, {} unclean",
            case.name,
            all.len(),
            chosen.iter().map(|(_, what)| what).collect::<std::collections::BTreeSet<_>>().len(),
            chosen.len(),
            found.len()
        );
        (injected, reached) = (injected + chosen.len(), reached + all.len());
        failures.extend(found);
    }
    println!("injected failures run: {injected} (of {reached} steps reached) in {} programs", cases.len());
    assert!(failures.is_empty(), "{} unclean error paths:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn a_malformed_fail_at_is_refused() {
    for value in ["sumbit", "0"] {
        let run = run_chapter(
            env!("CARGO_BIN_EXE_03-semaphores"),
            &["--size", "32x32"],
            &[("VKGL_FAIL_AT", value)],
        );
        assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
        let refused = format!("VKGL_FAIL_AT={value} is none of none, list or a step number from 1");
        assert!(run.stderr.contains(&refused), "{}", run.stderr);
    }
}

/// A step number past the last step fails nothing: the run succeeds (and says nothing failed).
#[test]
fn a_step_past_the_last_fails_nothing() {
    let run = run_chapter(
        env!("CARGO_BIN_EXE_01-exportable-memory"),
        &["--size", "32x24"],
        &[("VKGL_FAIL_AT", "100000")],
    );
    run.succeeded();
    assert!(!run.stderr.contains("injected failure"), "{}", run.stderr);
}

/// A natural failure: a size the flags accept and the device refuses once both contexts exist
/// (reading a 16384x16384 RGBA32F G-buffer back takes 4 GiB, more than GL reads in one call).
#[test]
fn a_size_the_device_refuses_fails_cleanly() {
    let bin = env!("CARGO_BIN_EXE_05-g-buffers");
    let baseline = run_chapter(bin, &["--size", "32x24"], &[("VKGL_FAIL_AT", "none")]);
    baseline.succeeded();
    let kept_by_driver = fds_left(&baseline);
    let run = run_chapter(bin, &["--size", "16384x16384"], &[("VKGL_FAIL_AT", "none")]);
    assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
    assert!(run.stderr.contains("error: --size 16384x16384: "), "{}", run.stderr);
    assert!(run.stderr.contains("4294967296 bytes"), "the error names the bytes needed:\n{}", run.stderr);
    for bad in ["panicked", "not destroyed", "validation error"] {
        assert!(!run.stderr.contains(bad), "stderr contains {bad:?}:\n{}", run.stderr);
    }
    assert!(run.stderr.contains("resources: alive after the chapter ran: []"), "{}", run.stderr);
    let mut left = fds_left(&run);
    left.retain(|fd| !kept_by_driver.contains(fd));
    assert!(left.is_empty(), "fds left open {left:?}\n{}", run.stderr);
}

/// Calls into the driver, the allocator or the file system that return a `Result`: each must
/// be a step of `instruments::fail` (`fail::call`, `fail::step`, or `owned::create`, which makes its
/// call a step and owns the result, on its line or just above), so that
/// the test above fails it. A `Drop` cannot return a failure, so its calls are not steps; nor
/// are the calls that give something back (`vkDestroy*`, `vkUnmapMemory`, CUDA's frees).
const FALLIBLE: &[&str] = &[
    ".wait_for_fences(",
    ".reset_fences(",
    ".begin_command_buffer(",
    ".end_command_buffer(",
    ".reset_command_buffer(",
    ".queue_submit(",
    ".device_wait_idle(",
    ".bind_buffer_memory(",
    ".bind_image_memory(",
    ".map_memory(",
    ".allocate_memory(",
    ".get_memory_fd(",
    ".get_semaphore_fd(",
    ".get_query_pool_results(",
    ".get_ray_tracing_shader_group_handles(",
    ".enumerate_physical_devices(",
    "Allocator::new(",
    "cu::launch_kernel(",
    "cu::event::record(",
    "cuGraphicsMapResources(",
    "std::fs::write(",
    "std::fs::create_dir_all(",
];

/// `file:line: call` for every call of [`FALLIBLE`] in `text` that is not a step.
fn unstepped_calls(file: &str, text: &str) -> Vec<String> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    let mut in_drop = false;
    for (i, line) in lines.iter().enumerate() {
        let code = line.trim_start();
        if code.starts_with("#[cfg(test)]") {
            break; // unit tests may unwrap
        }
        // A top-level item starts: is it a Drop?
        if line.starts_with("impl") || line.starts_with("pub ") || line.starts_with("fn ") {
            in_drop = line.starts_with("impl") && line.contains("Drop for");
        }
        if code.starts_with("//") || in_drop {
            continue;
        }
        // A call, not the definition of the function called (`fn name(`).
        for call in
            FALLIBLE.iter().filter(|call| line.contains(*call) && !line.contains(&format!("fn {call}")))
        {
            let stepped = lines[i.saturating_sub(3)..=i]
                .iter()
                .any(|l| l.contains("fail::call(") || l.contains("fail::step(") || calls_create(l));
            if !stepped {
                found.push(format!("{file}:{}: {} ({call})", i + 1, code));
            }
        }
    }
    found
}

/// Does `line` call `owned::create` (a bare `create(`, not `foo_create(` or `.create(`)?
fn calls_create(line: &str) -> bool {
    line.match_indices("create(")
        .any(|(at, _)| !line[..at].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == '.'))
}

#[test]
fn every_fallible_call_is_a_step() {
    harness::assert_no_source_has(
        "fallible calls that VKGL_FAIL_AT cannot fail (wrap each in fail::call or fail::step)",
        unstepped_calls,
    );
}

#[test]
fn the_scan_finds_an_unstepped_call_and_spares_drop() {
    let text = "fn f() {\n    unsafe { vk.device.bind_buffer_memory(b, m, 0) }?;\n}\n\
                impl Drop for X {\n    fn drop(&mut self) {\n        let _ = d.wait_for_fences(&[f], true, 0);\n    }\n}\n\
                fn g() {\n    fail::call(\"vkMapMemory\", || unsafe {\n        d.map_memory(m, 0, 4, flags)\n    })?;\n}\n";
    let found = unstepped_calls("x.rs", text);
    assert_eq!(found, ["x.rs:2: unsafe { vk.device.bind_buffer_memory(b, m, 0) }?; (.bind_buffer_memory()"]);
}

#[test]
fn the_command_scan_finds_listed_commands() {
    let help = "Usage: tool [OPTIONS] [COMMAND]\n\nCommands:\n  temporal  Chapter 13's frame\n  \
                help      Print this message\n\nOptions:\n      --json  Print JSON\n";
    assert_eq!(flags::commands_in(help), ["temporal"]);
    let words = |program: &flags::Program| program.1.join(" ");
    let convergence: Vec<String> =
        flags::programs(env!("CARGO_BIN_EXE_convergence")).iter().map(words).collect();
    assert_eq!(convergence, ["", "temporal"], "convergence's --help lists its commands");
}

/// Every numeric flag of every program here, and of every command a program's `--help` lists
/// (`convergence temporal`), refuses what no flag means (`harness::flags`); whether each takes
/// -1, 0 and 0.5 is in the snapshot, to be read.
#[test]
fn every_numeric_flag_refuses_what_it_cannot_mean() {
    let mut bins: Vec<&str> = Vec::new();
    for case in CASES {
        if !bins.contains(&case.bin) {
            bins.push(case.bin);
        }
    }
    let table = flags::numeric_flags_refuse_what_they_cannot_mean(&bins);
    insta::with_settings!({
        // Not beside the reports: every .snap there is a report (tests/book_facts.rs).
        snapshot_path => "snapshots/flags",
        prepend_module_to_snapshot => false,
        omit_expression => true,
    }, {
        insta::assert_snapshot!("numeric-flags", table);
    });
}

/// Chapter 14's hidden `--viewer-fd` (the socket its renderer hands its viewer) refuses what
/// cannot be that socket, before any fd is made of it: -1, stdin/stdout/stderr, and an fd that is
/// open but not a socket, or not open at all.
#[test]
fn ch14_refuses_a_viewer_fd_that_is_not_its_socket() {
    let bin = env!("CARGO_BIN_EXE_14-two-processes");
    for fd in ["-1", "0", "2"] {
        let (code, stderr) = flags::offer(&(bin, Vec::new()), "--viewer-fd", fd);
        assert_eq!(code, Some(2), "--viewer-fd={fd}: {stderr}");
        assert!(stderr.contains("expected a number from 3 to 2147483647"), "{stderr}");
    }
    for fd in ["3", "1000"] {
        let run = run_chapter(bin, &["--viewer-fd", fd], &[]);
        assert_eq!(run.output.status.code(), Some(2), "{}", run.stderr);
        assert!(run.stderr.contains(&format!("--viewer-fd {fd} is not an open socket")), "{}", run.stderr);
        assert!(!run.stderr.contains("panicked"), "{}", run.stderr);
    }
}
