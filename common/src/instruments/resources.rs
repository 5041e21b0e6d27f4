//! Every count of what a chapter holds, in one place: what it created on the GPU, by kind (counted
//! where each object is made, and listed in the report next to the extensions the chapter
//! enabled; the snapshots pin the list, so a resource a scene does not need shows up in review),
//! how many of the counted kinds are alive now (GL's objects among them, which die with their
//! context and so show a leak only here), and the open file descriptors.

use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Mutex;

/// (count, bytes) per kind, since the process started.
static CREATED: Mutex<BTreeMap<String, (u64, u64)>> = Mutex::new(BTreeMap::new());
/// How many of each kind exist now: created minus `destroyed` (counted for the kinds a resize
/// makes anew, so the leak tests can see growth).
static LIVE: Mutex<BTreeMap<String, i64>> = Mutex::new(BTreeMap::new());

/// One kind of resource in the report: how many were created, and the bytes they hold (memory
/// allocations and GL storage; 0 for objects whose memory is counted under another kind).
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct Created {
    pub kind: String,
    pub count: u64,
    pub bytes: u64,
}

/// Counts one more resource of `kind`, holding `bytes`.
pub fn created(kind: &str, bytes: u64) {
    let mut created = CREATED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let entry = created.entry(kind.to_owned()).or_default();
    entry.0 += 1;
    entry.1 += bytes;
    *LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).entry(kind.to_owned()).or_default() += 1;
}

/// One counted resource of `kind`: [`created`] when made, [`destroyed`] when dropped. Its owner
/// holds it, so the count follows the resource out of every early return.
#[must_use = "dropping it counts the resource as destroyed"]
#[derive(Debug)]
pub struct Counted(String);

/// Counts one more resource of `kind`, holding `bytes`, until the returned token is dropped.
pub fn count(kind: &str, bytes: u64) -> Counted {
    created(kind, bytes);
    Counted(kind.to_owned())
}

impl Drop for Counted {
    fn drop(&mut self) {
        destroyed(&self.0);
    }
}

/// One more `kind` alive, counted for [`live`] only (not listed in the report): GL's objects,
/// which die with their context and show a leak only here.
pub fn alive(kind: &str) {
    *LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).entry(kind.to_owned()).or_default() += 1;
}

/// One `kind` counted by [`alive`] is gone.
pub fn gone(kind: &str) {
    destroyed(kind);
}

/// One resource of `kind` is gone.
pub fn destroyed(kind: &str) {
    *LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).entry(kind.to_owned()).or_default() -= 1;
}

/// How many of each kind exist now, for the kinds whose destruction is counted: exportable
/// and host-visible memory, exportable images, every GL object (those `base::gl::create` made,
/// memory objects, semaphores, imported textures and buffers), renderbuffers. (GL's own view
/// of every kind: `GlContext::live_objects`.)
pub fn live() -> BTreeMap<String, i64> {
    let live = LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    live.iter()
        .filter(|(kind, _)| COUNTED_WHEN_DESTROYED.iter().any(|k| kind.starts_with(k)))
        .map(|(kind, &n)| (kind.clone(), n))
        .collect()
}

const COUNTED_WHEN_DESTROYED: [&str; 11] = [
    "gl_object",
    "gl_semaphore",
    "vk_memory_exportable",
    "vk_memory_host",
    "vk_image_exportable",
    "gl_memory_object",
    "gl_texture_imported",
    "gl_buffer_imported",
    "gl_renderbuffer",
    "cuda_graphics_resource",
    "cuda_external_memory",
];

/// Everything counted so far, sorted by kind.
pub fn list() -> Vec<Created> {
    let created = CREATED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    created.iter().map(|(kind, &(count, bytes))| Created { kind: kind.clone(), count, bytes }).collect()
}

// ANCHOR: open_fd_count
/// How many file descriptors this process has open: the chapters' leak check compares this
/// before and after their work.
pub fn open_fd_count() -> anyhow::Result<usize> {
    use anyhow::Context as _;
    Ok(std::fs::read_dir("/proc/self/fd").context("listing /proc/self/fd")?.count())
}
// ANCHOR_END: open_fd_count

/// [`open_fd_count`] at the end of a run, for the leak check against `before`: while it is
/// higher, counted again for up to a second. A driver's background thread (Mesa's shader cache
/// writer, say) may hold a file open for a moment after the work is done; a leaked fd stays.
pub fn settled_fd_count(before: usize) -> anyhow::Result<usize> {
    let mut count = open_fd_count()?;
    for _ in 0..20 {
        if count <= before {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        count = open_fd_count()?;
    }
    Ok(count)
}

// ANCHOR: shared_fds
/// What each open fd points at (`socket:[4711]`, `/memfd:... (deleted)`, `/dev/nvidiactl` ...),
/// with how many fds point at it. The numbers are left out: a file closed and opened again may
/// come back under another.
pub fn open_fd_targets() -> BTreeMap<String, usize> {
    let mut targets = BTreeMap::new();
    for fd in open_fds() {
        let target = fd.split_once(" -> ").map_or(fd.as_str(), |(_, target)| target);
        // The listing's own directory fd is open while it is listed, under a number of its own.
        if !target.ends_with("/fd") {
            *targets.entry(target.to_owned()).or_insert(0) += 1;
        }
    }
    targets
}

/// Is `target` (what an fd points at) a file a program makes or receives itself when it shares
/// memory across processes: a socket, exported memory (a memfd, a dma-buf) or an exported
/// semaphore (a sync file, a DRM syncobj)? Device files (`/dev/nvidia0`), regular files (a
/// shader cache) and directories are the driver's: it opens them when it likes (some only at
/// the first draw or read) and keeps them, so they prove nothing about the program.
pub fn is_shared_object(target: &str) -> bool {
    target.starts_with("socket:")
        || target.starts_with("/memfd:")
        || target.starts_with("/dmabuf:")
        || ["dmabuf", "sync_file", "syncobj"]
            .iter()
            .any(|kind| target.starts_with(&format!("anon_inode:{kind}")))
}

/// The fds of shared objects ([`is_shared_object`]) open now beyond those open in `before`
/// ([`open_fd_targets`]), one line each; counted again for up to a second while there are any,
/// as [`settled_fd_count`] does. Empty: nothing leaked.
pub fn new_shared_fds(before: &BTreeMap<String, usize>) -> Vec<String> {
    let new = || -> Vec<String> {
        open_fd_targets()
            .into_iter()
            .filter(|(target, n)| is_shared_object(target) && *n > before.get(target).copied().unwrap_or(0))
            .map(|(target, n)| format!("{target} (x{})", n - before.get(&target).copied().unwrap_or(0)))
            .collect()
    };
    let mut left = new();
    for _ in 0..20 {
        if left.is_empty() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
        left = new();
    }
    left
}
// ANCHOR_END: shared_fds

// ANCHOR: fd_check
/// The check `no_fd_leaked` of a program that shares memory across processes: no socket,
/// exported memory or semaphore is open now that was not open at `before` ([`is_shared_object`]
/// says why the driver's own files are not counted). Each one left is named on stderr, after `who`.
pub fn no_fd_leaked(who: &str, before: &BTreeMap<String, usize>) -> bool {
    let leaked = new_shared_fds(before);
    if !leaked.is_empty() {
        eprintln!("{who}: fds left open: {leaked:?}");
    }
    leaked.is_empty()
}
// ANCHOR_END: fd_check

/// This process's resident memory (`VmRSS` in `/proc/self/status`), in KiB; 0 if unknown.
pub fn resident_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|kib| kib.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

/// The open file descriptors and what each points at (`/proc/self/fd`), sorted: which fds a run
/// left open, beyond a count.
pub fn open_fds() -> Vec<String> {
    let mut fds: Vec<String> = std::fs::read_dir("/proc/self/fd")
        .map(|dir| {
            dir.flatten()
                .map(|entry| {
                    let target = std::fs::read_link(entry.path()).unwrap_or_default();
                    format!("{} -> {}", entry.file_name().to_string_lossy(), target.display())
                })
                .collect()
        })
        .unwrap_or_default();
    fds.sort();
    fds
}
