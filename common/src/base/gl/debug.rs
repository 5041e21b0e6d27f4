//! GL's errors and debug output: named, counted for the report, and switched at run time.

use super::GlContext;
use glow::HasContext;
use std::sync::atomic::{AtomicU32, Ordering};

pub(super) fn error_name(error: u32) -> &'static str {
    match error {
        glow::INVALID_ENUM => "GL_INVALID_ENUM",
        glow::INVALID_VALUE => "GL_INVALID_VALUE",
        glow::INVALID_OPERATION => "GL_INVALID_OPERATION",
        glow::OUT_OF_MEMORY => "GL_OUT_OF_MEMORY",
        glow::INVALID_FRAMEBUFFER_OPERATION => "GL_INVALID_FRAMEBUFFER_OPERATION",
        _ => "unknown",
    }
}

// ---------------------------------------------------------------------------------------------
// Debug output: GL's counterpart of the validation layer

static GL_ERRORS: AtomicU32 = AtomicU32::new(0);

/// How many errors GL's debug output reported in this process.
pub fn gl_error_count() -> u32 {
    GL_ERRORS.load(Ordering::Relaxed)
}

// ANCHOR: debug_output
/// How GL reports problems (`bench --gl-debug`). Every context starts `Synchronous`: a message
/// arrives inside the call that caused it, which is what one wants while learning and testing,
/// and what costs most (the driver may serialise its work to do it). Timed runs can choose less.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DebugOutput {
    /// Messages inside the call that caused them (the default of every chapter).
    Synchronous,
    /// Messages whenever the driver gets to them: errors are still counted, later.
    Asynchronous,
    /// No messages: only `glGetError` (`GlContext::check_error`) still sees errors.
    Off,
}

impl GlContext {
    /// Changes how this context reports problems; see [`DebugOutput`].
    pub fn set_debug_output(&self, mode: DebugOutput) {
        unsafe {
            match mode {
                DebugOutput::Off => self.gl.disable(glow::DEBUG_OUTPUT),
                _ => self.gl.enable(glow::DEBUG_OUTPUT),
            }
            match mode {
                DebugOutput::Synchronous => self.gl.enable(glow::DEBUG_OUTPUT_SYNCHRONOUS),
                _ => self.gl.disable(glow::DEBUG_OUTPUT_SYNCHRONOUS),
            }
        }
    }
}
// ANCHOR_END: debug_output

pub(super) fn enable_debug_output(gl: &mut glow::Context) {
    unsafe {
        // Synchronous: the message arrives inside the call that caused it, so a backtrace helps.
        gl.enable(glow::DEBUG_OUTPUT);
        gl.enable(glow::DEBUG_OUTPUT_SYNCHRONOUS);
        gl.debug_message_callback(|_source, kind, _id, severity, message| {
            if kind == glow::DEBUG_TYPE_ERROR {
                GL_ERRORS.fetch_add(1, Ordering::Relaxed);
                eprintln!("gl debug error: {message}");
            } else if severity == glow::DEBUG_SEVERITY_HIGH || severity == glow::DEBUG_SEVERITY_MEDIUM {
                eprintln!("gl debug: {message}");
            }
        });
    }
}
