//! A child process owned from the moment it is spawned (chapter 14's viewer): whatever way out
//! of the code that started it, it is not left running, nor left a zombie.

use std::process::Child;
use std::time::{Duration, Instant};

/// A started process: dropped, it is killed (`SIGKILL`, if it still runs) and reaped (`wait`).
/// Derefs to the [`Child`], for its pid and an early `kill`.
pub struct OwnedChild(Child);

impl From<Child> for OwnedChild {
    fn from(child: Child) -> Self {
        OwnedChild(child)
    }
}

impl OwnedChild {
    /// Waits up to `grace` for it to exit by itself, then kills it; reaps it either way. Whether
    /// it exited with 0 by itself.
    pub fn end(mut self, grace: Duration) -> bool {
        let started = Instant::now();
        while matches!(self.0.try_wait(), Ok(None)) && started.elapsed() < grace {
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.0.kill(); // one that has exited ignores it
        self.0.wait().is_ok_and(|status| status.success())
        // dropped here: kill and wait again, both harmless on a reaped child
    }
}

impl std::ops::Deref for OwnedChild {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for OwnedChild {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for OwnedChild {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dropped, a child that would run for a minute is killed and reaped: no process, not even a
    /// zombie, is left with its pid. Ended, one that exits by itself says whether it exited 0.
    #[test]
    fn a_dropped_child_is_killed_and_reaped() {
        let child = OwnedChild::from(std::process::Command::new("sleep").arg("60").spawn().unwrap());
        let proc = std::path::PathBuf::from(format!("/proc/{}", child.id()));
        assert!(proc.exists());
        drop(child);
        assert!(!proc.exists(), "{} is still there after the drop", proc.display());
        let exits = OwnedChild::from(std::process::Command::new("true").spawn().unwrap());
        assert!(exits.end(Duration::from_secs(5)));
        let hangs = OwnedChild::from(std::process::Command::new("sleep").arg("60").spawn().unwrap());
        let started = Instant::now();
        assert!(!hangs.end(Duration::from_millis(50)), "killed: not a clean exit");
        assert!(started.elapsed() < Duration::from_secs(5));
    }
}
