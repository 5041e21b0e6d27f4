//! What chapter 14 watches across many viewers and renderers: a sample of each process's
//! resources after each session, for the soak's "flat" (fds, live Vulkan memory, GL objects,
//! resident memory), and the checks' fd bookkeeping.

use common::instruments::resources;
use common::{GlContext, Report};
use serde::Serialize;
use std::collections::BTreeMap;

/// One process's resources after one session, all that it made for that session gone.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct Sample {
    /// Open fds of the kinds the program makes itself (`resources::is_shared_object`).
    pub shared_fds: usize,
    /// Every open fd, the driver's included.
    pub fds: usize,
    /// Vulkan memory objects alive (the renderer's ring; 0 in the viewer).
    pub vk_memory: i64,
    /// GL objects alive, as the driver counts them (`GlContext::live_objects`; 0 without GL).
    pub gl_objects: usize,
    pub rss_kib: u64,
}

/// This process's resources now.
pub fn sample(gl: Option<&GlContext>) -> Sample {
    let targets = resources::open_fd_targets();
    let live = resources::live();
    Sample {
        shared_fds: targets.iter().filter(|(t, _)| resources::is_shared_object(t)).map(|(_, n)| n).sum(),
        fds: targets.values().sum(),
        vk_memory: live.iter().filter(|(kind, _)| kind.starts_with("vk_memory")).map(|(_, n)| n).sum(),
        gl_objects: gl.map_or(0, |gl| gl.live_objects().values().sum()),
        rss_kib: resources::resident_kib(),
    }
}

// ANCHOR: fd_check
/// The check `no_fd_leaked`: no socket, exported memory or semaphore is open now that was not
/// open at `before` (`resources::is_shared_object` says why the driver's own files are not
/// counted). Each one left is named on stderr.
pub fn no_fd_leaked(who: &str, before: &BTreeMap<String, usize>) -> bool {
    let leaked = resources::new_shared_fds(before);
    if !leaked.is_empty() {
        eprintln!("{who}: fds left open: {leaked:?}");
    }
    leaked.is_empty()
}
// ANCHOR_END: fd_check

/// Median and the largest of `values` (milliseconds), for the report.
pub fn median_max(values: &[f64]) -> serde_json::Value {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    serde_json::json!({ "median": median, "max": sorted.last().copied().unwrap_or(0.0), "n": sorted.len() })
}

/// Puts the viewer's summary into the renderer's report: its GL, its checks (as `viewer_*`), the
/// picture it kept, and its resources after each renderer (`--reconnect`).
pub fn merge_summary(report: &mut Report, json: &str) -> anyhow::Result<()> {
    use anyhow::Context as _;
    let summary: serde_json::Value =
        serde_json::from_str(json).context("the viewer's summary is not JSON")?;
    let text = |v: &serde_json::Value| v.as_str().unwrap_or_default().to_owned();
    let gl = &summary["gl"];
    report.gl = Some(common::instruments::report::GlReport {
        renderer: text(&gl["renderer"]),
        version: text(&gl["version"]),
        device_uuid: text(&gl["device_uuid"]),
        driver_uuid: text(&gl["driver_uuid"]),
        extensions: gl["extensions"].as_array().into_iter().flatten().map(text).collect(),
    });
    for (name, ok) in summary["checks"].as_object().into_iter().flatten() {
        report.check(&format!("viewer_{name}"), ok.as_bool() == Some(true));
    }
    report.check("viewer_no_gl_errors", summary["gl_errors"] == 0);
    for image in summary["images"].as_array().into_iter().flatten() {
        let size = |key: &str| image[key].as_u64().unwrap_or(0) as u32;
        let path = std::path::PathBuf::from(text(&image["path"]));
        report.image(&text(&image["name"]), &path, size("width"), size("height"), &text(&image["format"]));
    }
    report.set("frames_shown_by_the_last_viewer", &summary["frames_shown"]);
    report.set("window", summary["window"] == true); // the viewer's: the renderer has none
    if let Some(sessions) = summary.get("sessions") {
        report.set("viewer_sessions", sessions);
    }
    Ok(())
}
