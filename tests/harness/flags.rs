//! Every numeric flag of a program, found from its `--help`, offered what no flag means.

/// `bin`, and the words before its flags: none for the program itself, `["temporal"]` for
/// `convergence temporal`.
pub type Program<'a> = (&'a str, Vec<String>);

/// `bin [words] --help`'s output, which must succeed.
pub fn help(bin: &str, words: &[String]) -> String {
    let help = std::process::Command::new(bin).args(words).arg("--help").output().unwrap();
    assert!(help.status.success(), "{bin} {words:?} --help: {help:?}");
    String::from_utf8(help.stdout).unwrap()
}

/// The commands a `--help` lists under `Commands:` (as clap lists subcommands), but `help`.
pub fn commands_in(help: &str) -> Vec<String> {
    let mut commands = Vec::new();
    let mut inside = false;
    for line in help.lines() {
        if !line.starts_with(' ') {
            inside = line.trim_end() == "Commands:";
        } else if inside
            && let Some(word) = line.split_whitespace().next()
            && word != "help"
        {
            commands.push(word.to_owned());
        }
    }
    commands
}

/// `bin`, and every command its `--help` lists, and theirs in turn.
pub fn programs(bin: &str) -> Vec<Program<'_>> {
    let mut found: Vec<Program> = vec![(bin, Vec::new())];
    let mut next = 0;
    while let Some((_, words)) = found.get(next).cloned() {
        for command in commands_in(&help(bin, &words)) {
            let mut deeper = words.clone();
            deeper.push(command);
            found.push((bin, deeper));
        }
        next += 1;
    }
    found
}

/// The flags `bin [words] --help` lists that take a value, each with its block of help text.
pub fn flags_with_values((bin, words): &Program) -> Vec<(String, String)> {
    let help = help(bin, words);
    let mut flags: Vec<(String, String)> = Vec::new();
    let mut in_commands = false;
    for line in help.lines() {
        let trimmed = line.trim_start();
        if !line.starts_with(' ') {
            in_commands = line.trim_end() == "Commands:";
        }
        // "  -n, --name <VALUE>", "      --name [<VALUE>]": a flag's first line; the rest is its help.
        let flag =
            trimmed.strip_prefix("-").and_then(|_| trimmed.split_whitespace().find(|w| w.starts_with("--")));
        match flag {
            Some(flag) if line.starts_with(' ') && !in_commands => {
                let name = flag.trim_end_matches(',').to_owned();
                let takes_value = trimmed.contains(" <") || trimmed.contains(" [<");
                flags.push((name, if takes_value { trimmed.to_owned() } else { String::new() }));
            }
            _ => {
                if let Some((_, text)) = flags.last_mut().filter(|(_, text)| !text.is_empty()) {
                    text.push_str(trimmed);
                }
            }
        }
    }
    flags.retain(|(name, text)| !text.is_empty() && name != "--help");
    flags
}

/// `bin [words] --flag=value --help`: clap parses every value before it acts on `--help`, so
/// this is 0 (help printed) when the value is taken and 2 (clap's error) when it is refused, with
/// nothing run either way.
pub fn offer((bin, words): &Program, flag: &str, value: &str) -> (Option<i32>, String) {
    let output = std::process::Command::new(bin)
        .args(words)
        .arg(format!("{flag}={value}"))
        .arg("--help")
        .output()
        .unwrap();
    (output.status.code(), String::from_utf8_lossy(&output.stderr).into_owned())
}

/// Every numeric flag of every program and of every command a program's `--help` lists
/// (`convergence temporal`), found from its `--help` (so that a flag or command added later is
/// covered with no one remembering to), refuses what no flag means: NaN, the infinities, numbers
/// past any limit. Each refusal exits 2 before anything runs, naming the flag and its range, and
/// no value panics. Whether each flag takes -1, 0 and 0.5 is in the snapshot, to be read.
/// Returns a line per numeric flag saying which of -1, 0 and 0.5 it takes, for a snapshot.
pub fn numeric_flags_refuse_what_they_cannot_mean(bins: &[&str]) -> String {
    let mut table = String::new();
    for program in bins.iter().copied().flat_map(programs) {
        let (bin, words) = &program;
        let file = std::path::Path::new(bin).file_name().unwrap().to_str().unwrap();
        let name = [file.to_owned()].into_iter().chain(words.iter().cloned()).collect::<Vec<_>>().join(" ");
        let mut numeric = 0;
        for (flag, help) in flags_with_values(&program) {
            if help.contains("[possible values:") {
                continue; // a choice of words
            }
            // A flag that takes a word is a path or a name; one that takes no plain number is a
            // size or a list of words. The rest are numbers.
            if offer(&program, &flag, "word").0 == Some(0) {
                continue;
            }
            let plain = ["0", "1", "2", "3", "10", "16", "0.5", "100"];
            if !plain.iter().any(|n| offer(&program, &flag, n).0 == Some(0)) {
                continue;
            }
            numeric += 1;
            let mut takes = Vec::new();
            for value in
                ["nan", "NaN", "inf", "-inf", "1e300", "-1e300", "18446744073709551616", "-1", "0", "0.5"]
            {
                let (code, stderr) = offer(&program, &flag, value);
                let no_sense = !["-1", "0", "0.5"].contains(&value);
                let refused = code == Some(2)
                    && stderr.contains(&format!("'{flag} "))
                    && stderr.contains("expected a number")
                    && stderr.contains(" from ")
                    && !stderr.contains("panicked");
                match (code, no_sense) {
                    (Some(0), false) => takes.push(value),
                    (Some(0), true) => panic!("{name} {flag}={value} is taken"),
                    _ => assert!(
                        refused,
                        "{name} {flag}={value}: exit {code:?}, not 2 naming the flag and its range:\n{stderr}"
                    ),
                }
            }
            // What is taken reaches the program: its field is read from what the parser gave
            // (a type that differs panics there), and it runs, up to a failure injected at its
            // first step.
            let taken = plain.iter().find(|n| offer(&program, &flag, n).0 == Some(0)).unwrap();
            for value in takes.iter().chain([taken]) {
                let run = std::process::Command::new(bin)
                    .args(words)
                    .arg(format!("{flag}={value}"))
                    .env("VKGL_FAIL_AT", "1")
                    .env_remove("DISPLAY")
                    .env_remove("WAYLAND_DISPLAY")
                    .output()
                    .unwrap();
                let stderr = String::from_utf8_lossy(&run.stderr);
                assert!(
                    run.status.code() == Some(2) && !stderr.contains("panicked"),
                    "{name} {flag}={value}: {:?}\n{stderr}",
                    run.status
                );
            }
            table.push_str(&format!("{name} {flag}: takes {takes:?}\n"));
        }
        assert!(numeric > 0, "{name}: no numeric flag found in its --help (the scan is broken)");
    }
    table
}
