//! Injected failures, to prove the error paths clean up. Every fallible step a chapter takes
//! (creating a Vulkan or GL object, allocating, exporting or importing memory or a semaphore,
//! compiling a shader, submitting) goes through [`step`] or [`call`] first, which number the
//! steps in the order a run reaches them:
//!
//! - `VKGL_FAIL_AT=list` fails nothing and prints `fail step <n>: <what>` for each step reached;
//! - `VKGL_FAIL_AT=<n>` makes step `n` fail as if the driver had refused it;
//! - `VKGL_FAIL_AT=none` fails nothing.
//!
//! In all three, `run_chapter` prints what was left at exit (`instruments::resources`): the open fds,
//! the counted resources still alive, and the GL objects alive when the GL context went. A
//! Vulkan object left alive shows as the validation layer's "has not been destroyed" when the
//! device goes. `tests/errors.rs` fails every step of every chapter in turn.

use anyhow::{Result, bail};
use std::sync::atomic::{AtomicU32, Ordering};

/// What `VKGL_FAIL_AT` asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Armed {
    /// `none`: nothing fails; what is left at exit is listed all the same.
    Nothing,
    /// `list`: nothing fails; every step reached is printed.
    List,
    /// `<n>`: step `n` (from 1) fails.
    At(u32),
}

/// What `VKGL_FAIL_AT` asks for, if it is set (read once). A value that is none of the three
/// forms is refused by [`check_armed`].
pub fn armed() -> Option<Armed> {
    static ARMED: std::sync::OnceLock<Option<Armed>> = std::sync::OnceLock::new();
    *ARMED.get_or_init(|| parse(&std::env::var("VKGL_FAIL_AT").ok()?).ok())
}

fn parse(value: &str) -> Result<Armed> {
    match value {
        "none" => Ok(Armed::Nothing),
        "list" => Ok(Armed::List),
        n => match n.parse::<u32>() {
            Ok(n) if n > 0 => Ok(Armed::At(n)),
            _ => bail!("VKGL_FAIL_AT={value} is none of none, list or a step number from 1"),
        },
    }
}

/// Checks `VKGL_FAIL_AT` has one of the three forms: a typo would otherwise test nothing.
pub fn check_armed() -> Result<()> {
    match std::env::var("VKGL_FAIL_AT") {
        Ok(value) => parse(&value).map(|_| ()),
        Err(_) => Ok(()),
    }
}

/// How many steps this run has reached.
static REACHED: AtomicU32 = AtomicU32::new(0);

// ANCHOR: step
/// One fallible step, about to be taken: fails when `VKGL_FAIL_AT` names its number, as the
/// driver might have refused it; prints it with `VKGL_FAIL_AT=list`; otherwise does nothing.
pub fn step(what: &str) -> Result<()> {
    let n = REACHED.fetch_add(1, Ordering::Relaxed) + 1;
    match armed() {
        Some(Armed::List) => super::eprint_whole(&format!("fail step {n}: {what}")),
        Some(Armed::At(at)) if at == n => bail!("injected failure at step {n}: {what} (VKGL_FAIL_AT={n})"),
        _ => {}
    }
    Ok(())
}

/// A Vulkan or GL call as one fallible step: [`step`], then `call`, its error named by `what`
/// (`"vkCreateBuffer for the vertex buffer"`).
pub fn call<T, E>(what: &str, call: impl FnOnce() -> std::result::Result<T, E>) -> Result<T>
where
    E: std::fmt::Display + std::fmt::Debug + Send + Sync + 'static,
{
    step(what)?;
    call().map_err(|error| anyhow::Error::msg(error).context(what.to_owned()))
}
// ANCHOR_END: step

/// A leak on purpose, to prove a leak check can fail: with `VKGL_KEEP_A_RECEIVED_FD=1`, the first
/// fd this process receives and passes here is copied, and the copy never closed. (Chapter 14's
/// viewer passes each slot's memory.)
pub fn keep_a_copy_if_asked(fd: std::os::fd::BorrowedFd<'_>) -> Result<()> {
    static KEPT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let asked = std::env::var_os("VKGL_KEEP_A_RECEIVED_FD").is_some_and(|v| v == "1");
    if asked && !KEPT.swap(true, Ordering::Relaxed) {
        let copy = fd
            .try_clone_to_owned()
            .map_err(|error| anyhow::anyhow!("dup, for VKGL_KEEP_A_RECEIVED_FD: {error}"))?;
        std::mem::forget(copy); // the leak
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_forms_parse_and_anything_else_is_refused() {
        assert_eq!(parse("none").unwrap(), Armed::Nothing);
        assert_eq!(parse("list").unwrap(), Armed::List);
        assert_eq!(parse("12").unwrap(), Armed::At(12));
        for bad in ["0", "-1", "sumbit", ""] {
            assert!(parse(bad).is_err(), "{bad:?}");
        }
    }
}
