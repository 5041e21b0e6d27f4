//! The validation layer: on whenever it is installed, its messages printed and counted for the
//! report (a Vulkan object still alive when the device is destroyed is one of its errors).

use crate::instruments::report::ValidationReport;
use ash::vk;
use std::ffi::{CStr, c_void};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

pub(crate) const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

pub(crate) static VALIDATION_ON: AtomicBool = AtomicBool::new(false);
static VALIDATION_ERRORS: AtomicU32 = AtomicU32::new(0);
static VALIDATION_WARNINGS: AtomicU32 = AtomicU32::new(0);

/// The validation layer is on whenever it is installed, unless `VKGL_VALIDATION=0`.
pub(crate) fn validation_wanted(entry: &ash::Entry) -> bool {
    if std::env::var("VKGL_VALIDATION").is_ok_and(|v| v == "0") {
        return false;
    }
    let layers = unsafe { entry.enumerate_instance_layer_properties() }.unwrap_or_default();
    let found = layers.iter().any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER));
    if !found {
        eprintln!("vulkan: VK_LAYER_KHRONOS_validation is not installed; running without validation");
    }
    found
}

/// How many errors and warnings the validation layer reported in this process so far.
pub fn validation_counts() -> ValidationReport {
    ValidationReport {
        layer: VALIDATION_ON.load(Ordering::Relaxed),
        errors: VALIDATION_ERRORS.load(Ordering::Relaxed),
        warnings: VALIDATION_WARNINGS.load(Ordering::Relaxed),
        gl_errors: 0,
    }
}

pub(crate) fn messenger_create_info() -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(on_validation_message))
}

unsafe extern "system" fn on_validation_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user_data: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes a valid callback-data struct whose message is a C string or null.
    let message = unsafe { data.as_ref() }
        .filter(|d| !d.p_message.is_null())
        .map(|d| unsafe { CStr::from_ptr(d.p_message) }.to_string_lossy().into_owned())
        .unwrap_or_default();
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        VALIDATION_ERRORS.fetch_add(1, Ordering::Relaxed);
        eprintln!("validation error: {message}");
    } else {
        VALIDATION_WARNINGS.fetch_add(1, Ordering::Relaxed);
        eprintln!("validation warning: {message}");
    }
    vk::FALSE
}

/// For a program whose Vulkan instance a library made (chapter 15's wgpu, which installs its
/// own messenger): the layer is on for this run, as [`validation_counts`] reports.
pub fn layer_enabled_elsewhere() {
    VALIDATION_ON.store(true, Ordering::Relaxed);
}

/// One message from that library's messenger (or its own validation), counted and printed as
/// this module's messenger counts and prints the layer's.
pub fn count_message(error: bool, message: &str) {
    if error {
        VALIDATION_ERRORS.fetch_add(1, Ordering::Relaxed);
        eprintln!("validation error: {message}");
    } else {
        VALIDATION_WARNINGS.fetch_add(1, Ordering::Relaxed);
        eprintln!("validation warning: {message}");
    }
}
