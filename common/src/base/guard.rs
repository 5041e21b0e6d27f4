//! A raw handle and the call that destroys it (taught in chapter 01): chapters 01 and 02 keep
//! their Vulkan handles raw, so that the reader sees each `vkCreate*` and its `vkDestroy*`, yet
//! an early return (`?`) between creation and cleanup destroys what was made.

// ANCHOR: guard
/// `value`, with the call that destroys it: dropped, it makes the call. Wrapped the moment the
/// value exists, so every way out of the function destroys it, newest first; `*guard` is the
/// value.
pub struct Guard<T, F: FnOnce(&T)> {
    value: T,
    destroy: Option<F>,
}

/// Guards `value`: `destroy(&value)` runs when the guard is dropped.
pub fn guard<T, F: FnOnce(&T)>(value: T, destroy: F) -> Guard<T, F> {
    Guard { value, destroy: Some(destroy) }
}

impl<T, F: FnOnce(&T)> Drop for Guard<T, F> {
    fn drop(&mut self) {
        if let Some(destroy) = self.destroy.take() {
            destroy(&self.value);
        }
    }
}
// ANCHOR_END: guard

impl<T, F: FnOnce(&T)> Guard<T, F> {
    /// The value, no longer destroyed by this guard: for handing it to another owner, which
    /// destroys it with what it is bound to (a buffer with its memory).
    pub fn into_inner(mut self) -> T {
        self.destroy = None;
        // SAFETY: `self` is forgotten right after, so `value` is moved out exactly once, and
        // `destroy` (now None) owns nothing that leaks.
        let value = unsafe { std::ptr::read(&self.value) };
        std::mem::forget(self);
        value
    }
}

impl<T, F: FnOnce(&T)> std::ops::Deref for Guard<T, F> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.value
    }
}
