//! The resize census: whether a chapter that makes its images anew on every resize leaks
//! anything doing so. Apart from `resources` (what it counts) and `report` (where it checks),
//! which it uses both.

use crate::instruments::report::Report;
use crate::instruments::resources::{self, live, open_fd_count};
use std::collections::BTreeMap;

/// Whatever can count the objects it holds as the driver sees them, by kind: the GL context
/// (`GlContext::live_objects`). A trait here, so that the census stays on this floor.
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
    pub fn check(self, gl: &impl LiveObjects, report: &mut Report) -> anyhow::Result<()> {
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

/// One process's resources after one session of chapter 14's (a viewer served, or a renderer
/// watched), all that it made for that session gone: the soak checks these stay flat.
#[derive(serde::Serialize, Debug, Clone, PartialEq)]
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

/// This process's resources now, GL's counted by `gl` if there is one.
pub fn sample(gl: Option<&dyn LiveObjects>) -> Sample {
    let targets = resources::open_fd_targets();
    let live = live();
    Sample {
        shared_fds: targets.iter().filter(|(t, _)| resources::is_shared_object(t)).map(|(_, n)| n).sum(),
        fds: targets.values().sum(),
        vk_memory: live.iter().filter(|(kind, _)| kind.starts_with("vk_memory")).map(|(_, n)| n).sum(),
        gl_objects: gl.map_or(0, |gl| gl.live_objects().values().sum()),
        rss_kib: resources::resident_kib(),
    }
}
