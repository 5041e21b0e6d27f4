//! `cargo run -p xtask -- shaders`: compile each Vulkan shader in `shaders/` to the `.spv` committed
//! beside it (so `cargo build` needs no glslc) and rewrite `shaders/spirv.lock`.
//! `-- shaders --check` writes nothing: it lists stale shaders and exits 1 if there are any.
//! `cargo run -p xtask -- cuda`: compile the CUDA kernels in `shaders/cuda/` to PTX with NVRTC and
//! rewrite `shaders/cuda/ptx.lock` (see ptx.rs).
//! `cargo run -p xtask -- transcripts`: run every command of the book's transcripts
//! (`book/src/transcripts/*.txt`) again and rewrite those whose output changed. The running and
//! the comparing live in `tests/transcripts.rs`, which this runs with `VKGL_UPDATE_TRANSCRIPTS=1`,
//! so the files are written exactly as the test reads them.

mod ptx;
mod spirv_lock;

use std::path::Path;
use std::process::{Command, ExitCode};
use std::{env, fs, io};

use anyhow::{Context, Result, bail, ensure};

fn main() -> Result<ExitCode> {
    let shaders = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().join("shaders");
    let args: Vec<String> = env::args().skip(1).collect();
    match args.iter().map(String::as_str).collect::<Vec<_>>()[..] {
        ["shaders"] => build(&shaders).map(|()| ExitCode::SUCCESS),
        ["shaders", "--check"] => check(&shaders),
        ["cuda"] => ptx::build(&shaders.join("cuda")).map(|()| ExitCode::SUCCESS),
        ["transcripts"] => transcripts(shaders.parent().unwrap()),
        _ => bail!("usage: cargo run -p xtask -- shaders [--check] | cuda | transcripts (got {args:?})"),
    }
}

fn build(dir: &Path) -> Result<()> {
    // Hashed before compiling: a source edited while glslc runs then reads as stale, not as built.
    let lock = spirv_lock::render_lock(dir)?;
    for name in spirv_lock::vulkan_sources(dir)? {
        // vulkan1.3: SPIR-V 1.6, what our Vulkan 1.3 devices consume. -O: spirv-opt's size and speed
        // passes. -g: debug information, which keeps the names of blocks and their members (-O
        // alone strips them); the tests read those names to check the Rust side of every block.
        // -I .: `#include` resolves in shaders/ wherever the includer lives.
        let mut glslc = Command::new("glslc");
        glslc.current_dir(dir).args(["--target-env=vulkan1.3", "-O", "-g", "-I", "."]);
        // glslc's own errors and warnings go straight to our stderr.
        let status = match glslc.args(["-o", &format!("{name}.spv"), &name]).status() {
            Err(e) if e.kind() == io::ErrorKind::NotFound => bail!(
                "glslc (shaderc's compiler) is not on PATH: install it with `apt-get install glslc` (or the \
                 Vulkan SDK) and rerun. Only editing shaders needs it; the committed .spv build without it."
            ),
            status => status.context("running glslc")?,
        };
        ensure!(status.success(), "glslc could not compile shaders/{name} (its errors are above)");
        let spv = dir.join(format!("{name}.spv"));
        let words = fs::read(&spv).with_context(|| format!("reading {}", spv.display()))?;
        fs::write(&spv, names_only(&words)?).with_context(|| format!("writing {}", spv.display()))?;
        println!("compiled shaders/{name} -> shaders/{name}.spv");
    }
    fs::write(dir.join(spirv_lock::LOCK_FILE), lock).context("writing shaders/spirv.lock")?;
    println!("wrote shaders/{}", spirv_lock::LOCK_FILE);
    Ok(())
}

/// SPIR-V without the debug information `-g` adds beside the names: the source text and the line
/// numbers (`OpSource*`, `OpString`, `OpLine`, `OpNoLine`, `OpModuleProcessed`). What is left is
/// the program `-O` alone makes, its ids numbered differently, plus `OpName` and `OpMemberName`.
fn names_only(spv: &[u8]) -> Result<Vec<u8>> {
    const SOURCE_AND_LINES: [u32; 7] = [2, 3, 4, 7, 8, 317, 330];
    ensure!(spv.len() % 4 == 0 && spv.len() >= 20, "not SPIR-V: {} bytes", spv.len());
    let words: Vec<u32> = spv.chunks_exact(4).map(|w| u32::from_le_bytes(w.try_into().unwrap())).collect();
    let mut kept = words[..5].to_vec(); // the header
    let mut at = 5;
    while at < words.len() {
        let (count, opcode) = ((words[at] >> 16) as usize, words[at] & 0xffff);
        ensure!(count > 0 && at + count <= words.len(), "SPIR-V instruction at word {at} runs past the end");
        if !SOURCE_AND_LINES.contains(&opcode) {
            kept.extend_from_slice(&words[at..at + count]);
        }
        at += count;
    }
    Ok(kept.iter().flat_map(|w| w.to_le_bytes()).collect())
}

fn check(dir: &Path) -> Result<ExitCode> {
    let problems = spirv_lock::stale(dir)?;
    problems.iter().for_each(|problem| eprintln!("stale: shaders/{problem}"));
    if problems.is_empty() {
        println!("SPIR-V in shaders/ is up to date");
        return Ok(ExitCode::SUCCESS);
    }
    eprintln!("fix: `cargo run -p xtask -- shaders`, then commit the .spv files and shaders/spirv.lock");
    Ok(ExitCode::FAILURE)
}

fn transcripts(root: &Path) -> Result<ExitCode> {
    let cargo = env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(root)
        .args([
            "test",
            "--locked",
            "--test",
            "transcripts",
            "--",
            "transcripts_match_what_the_programs_print",
        ])
        .args(["--exact", "--nocapture"])
        .env("VKGL_UPDATE_TRANSCRIPTS", "1")
        .status()
        .context("running cargo test --test transcripts")?;
    ensure!(status.success(), "writing the transcripts failed (see above)");
    println!("transcripts in book/src/transcripts are current: read `git diff book/src/transcripts`");
    Ok(ExitCode::SUCCESS)
}
