//! What a chapter created on the GPU, by kind: counted where each object is made, and listed in
//! the report next to the extensions the chapter enabled. The snapshots pin the list, so a
//! resource a scene does not need shows up in review (the numerics issue's "leave out what a
//! scene does not need").

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

/// One resource of `kind` is gone.
pub fn destroyed(kind: &str) {
    *LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).entry(kind.to_owned()).or_default() -= 1;
}

/// How many of each kind exist now, for the kinds whose destruction is counted: exportable
/// and host-visible memory, exportable images, GL's memory objects, imported textures and
/// buffers, renderbuffers. (GL's own view of every kind: `GlContext::live_objects`.)
pub fn live() -> BTreeMap<String, i64> {
    let live = LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    live.iter()
        .filter(|(kind, _)| COUNTED_WHEN_DESTROYED.iter().any(|k| kind.starts_with(k)))
        .map(|(kind, &n)| (kind.clone(), n))
        .collect()
}

const COUNTED_WHEN_DESTROYED: [&str; 9] = [
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
