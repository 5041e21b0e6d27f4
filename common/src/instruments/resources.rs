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

/// Whatever can count the objects it holds as the driver sees them, by kind: the GL context
/// (`GlContext::live_objects`). A trait here, so that the census below stays on this floor.
pub trait LiveObjects {
    fn live_objects(&self) -> BTreeMap<&'static str, usize>;
}

/// What a resize could leak, counted: open fds, the counted kinds alive (a kind none of which
/// is alive counts as none, so that a kind first made after the count is no growth), and the
/// driver's own count of every kind of GL object. GL's count leaves queries out: a name
/// `glGenQueries` made is a query to `glIsQuery` only once it has been begun (a timer may make
/// names it begins later); the counted kinds hold every query made.
#[derive(Debug, PartialEq)]
struct Alive {
    fds: usize,
    counted: BTreeMap<String, i64>,
    gl_objects: BTreeMap<&'static str, usize>,
}

impl Alive {
    fn now(gl: &impl LiveObjects) -> anyhow::Result<Alive> {
        let counted = live().into_iter().filter(|(_, n)| *n != 0).collect();
        let mut gl_objects = gl.live_objects();
        gl_objects.remove("gl_queries");
        Ok(Alive { fds: open_fd_count()?, counted, gl_objects })
    }
}

// ANCHOR: resize_census
/// The resize leak check every chapter that resizes makes: what exists after one resize must be
/// what exists after every later one. [`ResizeCensus::count`] after a resize counts what is alive
/// the first time it is called; [`ResizeCensus::check`] at the end compares (the check
/// `nothing_grows_across_resizes`), if anything was counted.
#[derive(Default)]
pub struct ResizeCensus {
    first: Option<Alive>,
}

impl ResizeCensus {
    /// Counts what is alive now, if nothing was counted yet.
    pub fn count(&mut self, gl: &impl LiveObjects) -> anyhow::Result<()> {
        if self.first.is_none() {
            self.first = Some(Alive::now(gl)?);
        }
        Ok(())
    }

    /// Counts again and checks that nothing grew (nothing, if no resize was counted); a failure
    /// prints both counts.
    pub fn check(
        self,
        gl: &impl LiveObjects,
        report: &mut crate::instruments::report::Report,
    ) -> anyhow::Result<()> {
        let Some(first) = self.first else { return Ok(()) };
        let now = Alive::now(gl)?;
        if !report.check("nothing_grows_across_resizes", now == first) {
            eprintln!("after the first resize: {first:?}\nat the end: {now:?}");
        }
        Ok(())
    }
}
// ANCHOR_END: resize_census

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instruments::report::Report;
    use std::cell::Cell;

    /// A GL context stand-in whose textures and queries are what the test says.
    struct Objects {
        textures: Cell<usize>,
        queries: Cell<usize>,
    }

    impl LiveObjects for Objects {
        fn live_objects(&self) -> BTreeMap<&'static str, usize> {
            BTreeMap::from([("gl_textures", self.textures.get()), ("gl_queries", self.queries.get())])
        }
    }

    /// The census over one resize and the end, with `grow` run between them.
    fn census_after(grow: impl Fn(&Objects)) -> Option<bool> {
        let gl = Objects { textures: Cell::new(3), queries: Cell::new(2) };
        let (mut census, mut report) = (ResizeCensus::default(), Report::new("test"));
        census.count(&gl).unwrap();
        grow(&gl);
        census.count(&gl).unwrap(); // a later resize counts nothing more
        census.check(&gl, &mut report).unwrap();
        report.checks.get("nothing_grows_across_resizes").copied()
    }

    #[test]
    fn the_census_sees_an_object_a_resize_leaks() {
        assert_eq!(census_after(|_| {}), Some(true));
        assert_eq!(census_after(|gl| gl.textures.set(4)), Some(false));
        // Queries are GL's names until begun; the counted resources hold every query made.
        assert_eq!(census_after(|gl| gl.queries.set(5)), Some(true));
    }

    #[test]
    fn no_resize_no_check() {
        let gl = Objects { textures: Cell::new(1), queries: Cell::new(0) };
        let mut report = Report::new("test");
        ResizeCensus::default().check(&gl, &mut report).unwrap();
        assert!(report.checks.is_empty());
    }
}
