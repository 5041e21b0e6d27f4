//! The chapter report: what a chapter ran on, what it made, how long it took, and its own checks
//! of what it teaches. `--json` prints it as one JSON document; tests snapshot it.

use serde::Serialize;
use std::collections::BTreeMap;
use std::process::ExitCode;

#[derive(Serialize, Debug)]
pub struct Report {
    pub chapter: String,
    pub vulkan: Option<VulkanReport>,
    pub gl: Option<GlReport>,
    /// What the chapter created on the GPU, by kind (`common::instruments::resources`), beside the extensions.
    pub resources: Vec<crate::instruments::resources::Created>,
    /// Do GL and Vulkan run on the same device and driver? `None` when the chapter uses no GL.
    pub uuids_match: Option<bool>,
    /// How the two APIs take turns: "semaphores", "host", or `None` when they never share work.
    pub sync: Option<&'static str>,
    pub images: Vec<ImageReport>,
    pub timings_ms: BTreeMap<String, f64>,
    /// The chapter's own verifications. Any `false` makes the chapter exit non-zero.
    pub checks: BTreeMap<String, bool>,
    /// Checks that could not mean anything in this run, each with why (a window's frames follow
    /// the wall clock, or its size is one the check cannot judge). They pass nothing and fail
    /// nothing: only a headless run of the same chapter decides them.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub not_judged: BTreeMap<String, String>,
    pub validation: ValidationReport,
    /// Chapter-specific fields, printed after the common ones.
    #[serde(flatten)]
    pub details: serde_json::Map<String, serde_json::Value>,
}

#[derive(Serialize, Debug, Clone)]
pub struct VulkanReport {
    pub device: String,
    pub driver: String,
    pub api: String,
    pub device_uuid: String,
    pub driver_uuid: String,
    /// The device extensions this chapter enabled, and no others.
    pub extensions: Vec<String>,
}

#[derive(Serialize, Debug, Clone)]
pub struct GlReport {
    pub renderer: String,
    pub version: String,
    pub device_uuid: String,
    pub driver_uuid: String,
    /// The GL extensions this chapter requires.
    pub extensions: Vec<String>,
}

#[derive(Serialize, Debug, Clone)]
pub struct ImageReport {
    pub name: String,
    pub path: String,
    pub width: u32,
    pub height: u32,
    pub format: String,
}

#[derive(Serialize, Debug, Default, Clone, Copy)]
pub struct ValidationReport {
    /// Was `VK_LAYER_KHRONOS_validation` enabled for this run?
    pub layer: bool,
    pub errors: u32,
    pub warnings: u32,
    /// Errors from GL's debug output (`GL_DEBUG_TYPE_ERROR`).
    pub gl_errors: u32,
}

impl Report {
    pub fn new(chapter: &str) -> Self {
        Report {
            chapter: chapter.to_owned(),
            vulkan: None,
            gl: None,
            resources: Vec::new(),
            uuids_match: None,
            sync: None,
            images: Vec::new(),
            timings_ms: BTreeMap::new(),
            checks: BTreeMap::new(),
            not_judged: BTreeMap::new(),
            validation: ValidationReport::default(),
            details: serde_json::Map::new(),
        }
    }

    /// Records a check and logs it; returns `ok` so callers can branch on it.
    pub fn check(&mut self, name: &str, ok: bool) -> bool {
        eprintln!("  [{}] {name}", if ok { " ok " } else { "FAIL" });
        let previous = self.checks.insert(name.to_owned(), ok);
        assert!(previous.is_none(), "check {name:?} recorded twice");
        ok
    }

    /// Records that check `name` is not judged in this run, and why; logs it as `check` does.
    pub fn not_judged(&mut self, name: &str, why: &str) {
        eprintln!("  [ -- ] {name}: not judged ({why})");
        assert!(!self.checks.contains_key(name), "check {name:?} both judged and not");
        self.not_judged.insert(name.to_owned(), why.to_owned());
    }

    /// A check judged (`Ok`, as [`Report::check`]) or not, with why (`Err`, as
    /// [`Report::not_judged`]).
    pub fn verdict(&mut self, name: &str, verdict: Result<bool, String>) {
        match verdict {
            Ok(ok) => _ = self.check(name, ok),
            Err(why) => self.not_judged(name, &why),
        }
    }

    /// Adds a chapter-specific field.
    pub fn set(&mut self, key: &str, value: impl Serialize) {
        let value = serde_json::to_value(value).expect("report values are plain data");
        self.details.insert(key.to_owned(), value);
    }

    pub fn time_ms(&mut self, name: &str, ms: f64) {
        self.timings_ms.insert(name.to_owned(), ms);
    }

    /// Records an image the chapter wrote.
    pub fn image(&mut self, name: &str, path: &std::path::Path, width: u32, height: u32, format: &str) {
        self.images.push(ImageReport {
            name: name.to_owned(),
            path: path.display().to_string(),
            width,
            height,
            format: format.to_owned(),
        });
    }

    /// Takes in the report of another process of the same run (chapter 14's viewer, `who`,
    /// sent as JSON with its `gl_errors` count): its GL, its checks as `who_name`, a check
    /// `who_no_gl_errors`, and the images it wrote. What else it holds the caller picks.
    pub fn merge(&mut self, who: &str, other: &serde_json::Value) {
        let text = |v: &serde_json::Value| v.as_str().unwrap_or_default().to_owned();
        let gl = &other["gl"];
        self.gl = Some(GlReport {
            renderer: text(&gl["renderer"]),
            version: text(&gl["version"]),
            device_uuid: text(&gl["device_uuid"]),
            driver_uuid: text(&gl["driver_uuid"]),
            extensions: gl["extensions"].as_array().into_iter().flatten().map(text).collect(),
        });
        for (name, ok) in other["checks"].as_object().into_iter().flatten() {
            self.check(&format!("{who}_{name}"), ok.as_bool() == Some(true));
        }
        self.check(&format!("{who}_no_gl_errors"), other["gl_errors"] == 0);
        for image in other["images"].as_array().into_iter().flatten() {
            let size = |key: &str| image[key].as_u64().unwrap_or(0) as u32;
            let path = std::path::PathBuf::from(text(&image["path"]));
            self.image(&text(&image["name"]), &path, size("width"), size("height"), &text(&image["format"]));
        }
    }

    /// Prints the report and decides the exit code (a chapter's `run_chapter` returns it), from the checks
    /// and from `validation`, the layer's and GL's error counts that the caller filled in.
    pub fn finish(self, print: Print) -> ExitCode {
        let failed: Vec<&str> = self.checks.iter().filter(|(_, ok)| !**ok).map(|(n, _)| n.as_str()).collect();
        let mut ok = true;
        if self.checks.is_empty() {
            eprintln!("error: {} recorded no checks", self.chapter);
            ok = false;
        }
        if !failed.is_empty() {
            eprintln!("error: {} check(s) failed: {}", failed.len(), failed.join(", "));
            ok = false;
        }
        if self.validation.errors > 0 {
            eprintln!("error: the validation layer reported {} error(s) (above)", self.validation.errors);
            ok = false;
        }
        if self.validation.gl_errors > 0 {
            eprintln!("error: GL's debug output reported {} error(s) (above)", self.validation.gl_errors);
            ok = false;
        }
        if print == Print::Json {
            println!("{}", serde_json::to_string_pretty(&self).expect("report serialises"));
        }
        if ok {
            let unjudged = match self.not_judged.len() {
                0 => String::new(),
                n => format!(
                    " ({n} not judged: {})",
                    self.not_judged.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            };
            eprintln!("{}: all {} checks passed{unjudged}", self.chapter, self.checks.len());
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        }
    }
}

/// What [`Report::finish`] prints besides the checks and the verdict on stderr.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Print {
    /// The whole report as one JSON document on stdout (`--json`).
    Json,
    /// Nothing more.
    Summary,
}

/// Formats a UUID as Vulkan and GL both report it: 16 bytes, printed in hex.
pub fn uuid_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
