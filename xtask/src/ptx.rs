//! `cargo run -p xtask -- cuda`: compile each CUDA kernel in `shaders/cuda/` to the PTX committed
//! beside it, with NVRTC loaded at run time, and rewrite `shaders/cuda/ptx.lock` (one
//! `<sha256 of the source> <name>` line per kernel, hashed as the SPIR-V lock hashes GLSL).
//!
//! NVRTC comes with the CUDA toolkit (`libnvrtc.so.13`, `.12`) or, without one, as a Python
//! wheel: `pip install nvidia-cuda-nvrtc-cu12`. `NVRTC_LIBRARY=/path/to/libnvrtc.so.N` picks one.
//! The PTX is compiled for `compute_75`, which every driver from CUDA 10 to 13 runs; the driver
//! JIT-compiles it for the GPU it finds. A driver older than the NVRTC that wrote the PTX
//! refuses it: the PTX's `.version` line says which NVRTC that was.

use crate::spirv_lock;
use anyhow::{Context, Result, bail, ensure};
use std::ffi::{CStr, CString, c_char, c_int, c_void};
use std::fs;
use std::path::Path;
use std::process::Command;

pub const LOCK_FILE: &str = "ptx.lock";

/// What every kernel is compiled with. `--fmad=false`: no fused multiply-adds, so each operation
/// rounds as the CPU tracer's does (the chapter compares the two images).
pub const OPTIONS: &[&str] = &["--gpu-architecture=compute_75", "--fmad=false", "--std=c++17"];

/// The CUDA sources directly in `dir`, sorted.
pub fn sources(dir: &Path) -> Result<Vec<String>> {
    let mut names: Vec<String> = fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|entry| entry.ok()?.file_name().into_string().ok())
        .filter(|name| name.ends_with(".cu"))
        .collect();
    names.sort();
    Ok(names)
}

type Program = *mut c_void;

/// The six NVRTC calls a compile needs (nvrtc.h).
struct Nvrtc {
    _library: libloading::Library,
    create: unsafe extern "C" fn(
        *mut Program,
        *const c_char,
        *const c_char,
        c_int,
        *const *const c_char,
        *const *const c_char,
    ) -> c_int,
    compile: unsafe extern "C" fn(Program, c_int, *const *const c_char) -> c_int,
    log_size: unsafe extern "C" fn(Program, *mut usize) -> c_int,
    log: unsafe extern "C" fn(Program, *mut c_char) -> c_int,
    ptx_size: unsafe extern "C" fn(Program, *mut usize) -> c_int,
    ptx: unsafe extern "C" fn(Program, *mut c_char) -> c_int,
    destroy: unsafe extern "C" fn(*mut Program) -> c_int,
}

fn load_nvrtc() -> Result<Nvrtc> {
    let mut candidates: Vec<String> = std::env::var("NVRTC_LIBRARY").into_iter().collect();
    candidates.extend(["libnvrtc.so.13", "libnvrtc.so.12", "libnvrtc.so"].map(String::from));
    // The Python wheel's copy, wherever pip put it.
    let wheel = Command::new("python3")
        .args(["-c", "import nvidia.cuda_nvrtc; print(list(nvidia.cuda_nvrtc.__path__)[0])"])
        .output();
    if let Some(output) = wheel.ok().filter(|o| o.status.success()) {
        let dir = String::from_utf8_lossy(&output.stdout).trim().to_owned();
        candidates.push(format!("{dir}/lib/libnvrtc.so.12"));
    }
    for name in &candidates {
        // SAFETY: NVRTC's initialisers have no preconditions.
        let Ok(library) = (unsafe { libloading::Library::new(name) }) else { continue };
        println!("using NVRTC from {name}");
        // SAFETY: the signatures are nvrtc.h's.
        unsafe {
            return Ok(Nvrtc {
                create: *library.get(b"nvrtcCreateProgram\0")?,
                compile: *library.get(b"nvrtcCompileProgram\0")?,
                log_size: *library.get(b"nvrtcGetProgramLogSize\0")?,
                log: *library.get(b"nvrtcGetProgramLog\0")?,
                ptx_size: *library.get(b"nvrtcGetPTXSize\0")?,
                ptx: *library.get(b"nvrtcGetPTX\0")?,
                destroy: *library.get(b"nvrtcDestroyProgram\0")?,
                _library: library,
            });
        }
    }
    bail!(
        "NVRTC not found (tried {candidates:?}): install the CUDA toolkit, or `pip install \
         nvidia-cuda-nvrtc-cu12`, or set NVRTC_LIBRARY. Only editing kernels needs it; the committed \
         PTX builds and runs without it."
    )
}

fn compile(nvrtc: &Nvrtc, dir: &Path, name: &str) -> Result<String> {
    let source = CString::new(fs::read_to_string(dir.join(name))?)?;
    let c_name = CString::new(name)?;
    let options: Vec<CString> = OPTIONS.iter().map(|o| CString::new(*o).unwrap()).collect();
    let option_ptrs: Vec<*const c_char> = options.iter().map(|o| o.as_ptr()).collect();
    let mut program: Program = std::ptr::null_mut();
    // SAFETY: every pointer is a live NUL-terminated string; the program is destroyed below.
    unsafe {
        let code = (nvrtc.create)(
            &mut program,
            source.as_ptr(),
            c_name.as_ptr(),
            0,
            std::ptr::null(),
            std::ptr::null(),
        );
        ensure!(code == 0, "nvrtcCreateProgram({name}) returned {code}");
        let compiled = (nvrtc.compile)(program, option_ptrs.len() as c_int, option_ptrs.as_ptr());
        let mut size = 0;
        (nvrtc.log_size)(program, &mut size);
        let mut log = vec![0u8; size.max(1)];
        (nvrtc.log)(program, log.as_mut_ptr().cast());
        let log =
            CStr::from_bytes_until_nul(&log).map(|l| l.to_string_lossy().into_owned()).unwrap_or_default();
        if !log.trim().is_empty() {
            eprintln!("{log}");
        }
        let ptx = if compiled == 0 {
            (nvrtc.ptx_size)(program, &mut size);
            let mut ptx = vec![0u8; size];
            (nvrtc.ptx)(program, ptx.as_mut_ptr().cast());
            Some(CStr::from_bytes_until_nul(&ptx)?.to_string_lossy().into_owned())
        } else {
            None
        };
        (nvrtc.destroy)(&mut program);
        ptx.with_context(|| format!("NVRTC could not compile shaders/cuda/{name} (its errors are above)"))
    }
}

/// Compiles every kernel in `dir` and writes the lock.
pub fn build(dir: &Path) -> Result<()> {
    let nvrtc = load_nvrtc()?;
    let mut lock = String::new();
    for name in sources(dir)? {
        lock += &format!("{} {name}\n", spirv_lock::source_hash(dir, &name)?);
        let ptx = compile(&nvrtc, dir, &name)?;
        let out = name.replace(".cu", ".ptx");
        fs::write(dir.join(&out), ptx)?;
        println!("compiled shaders/cuda/{name} -> shaders/cuda/{out}");
    }
    fs::write(dir.join(LOCK_FILE), lock).context("writing shaders/cuda/ptx.lock")?;
    println!("wrote shaders/cuda/{LOCK_FILE}");
    Ok(())
}
