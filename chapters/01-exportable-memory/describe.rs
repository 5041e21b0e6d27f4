//! How chapter 01 shows what the driver answered: on stderr, and as the report's JSON.

use ash::vk;
use common::VulkanContext;
use serde_json::json;
use std::os::fd::{AsRawFd, OwnedFd};

pub fn describe_support(what: &str, p: &vk::ExternalMemoryProperties) {
    eprintln!(
        "{what}: {:?}; compatible handle types {:?}",
        p.external_memory_features, p.compatible_handle_types
    );
}

pub fn support_json(p: &vk::ExternalMemoryProperties) -> serde_json::Value {
    let f = p.external_memory_features;
    json!({
        "exportable": f.contains(vk::ExternalMemoryFeatureFlags::EXPORTABLE),
        "importable": f.contains(vk::ExternalMemoryFeatureFlags::IMPORTABLE),
        "dedicated_only": f.contains(vk::ExternalMemoryFeatureFlags::DEDICATED_ONLY),
        "compatible_handle_types": format!("{:?}", p.compatible_handle_types),
    })
}

pub fn requirements_json(
    r: &vk::MemoryRequirements,
    d: &vk::MemoryDedicatedRequirements,
) -> serde_json::Value {
    json!({
        "size": r.size,
        "alignment": r.alignment,
        "prefers_dedicated": d.prefers_dedicated_allocation == vk::TRUE,
        "requires_dedicated": d.requires_dedicated_allocation == vk::TRUE,
    })
}

pub fn memory_json(ctx: &VulkanContext, size: u64, type_index: u32) -> serde_json::Value {
    let flags = ctx.memory_properties.memory_types[type_index as usize].property_flags;
    json!({ "size": size, "type_index": type_index, "flags": format!("{flags:?}") })
}

/// Is `fd` an open descriptor of this process?
pub fn is_open(fd: &OwnedFd) -> bool {
    std::fs::metadata(format!("/proc/self/fd/{}", fd.as_raw_fd())).is_ok()
}

/// What the kernel says the descriptor points at (a memfd on lavapipe, a device node on NVIDIA).
pub fn fd_target(fd: &OwnedFd) -> String {
    std::fs::read_link(format!("/proc/self/fd/{}", fd.as_raw_fd()))
        .map(|p| p.display().to_string())
        .unwrap_or_else(|e| format!("? ({e})"))
}
