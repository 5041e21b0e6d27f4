//! The Vulkan context every chapter starts from: an instance (with the validation layer when it is
//! installed), the physical device that has every extension the chapter asks for, a logical device
//! with exactly those extensions, and one queue that can do graphics and compute.

use crate::instruments::fail;
use crate::instruments::report::{VulkanReport, uuid_hex};
use crate::instruments::validation::{
    VALIDATION_LAYER, VALIDATION_ON, messenger_create_info, validation_wanted,
};
use anyhow::{Context as _, Result};
use ash::vk;
use std::ffi::{CStr, c_char};
use std::fmt;
use std::sync::atomic::Ordering;

pub use crate::instruments::validation::validation_counts;

/// The Vulkan version every chapter is written against.
pub const API_VERSION: u32 = vk::API_VERSION_1_3;

/// What a chapter needs from the device. Later chapters add features here.
#[derive(Default, Clone, Copy)]
pub struct Requirements<'a> {
    /// Device extensions to enable. Every one must be present.
    pub extensions: &'a [&'a CStr],
    /// Device extensions enabled when present (the chapter has a fallback). No others are enabled.
    pub optional_extensions: &'a [&'a CStr],
    /// Enable the features ray tracing needs: buffer device addresses, acceleration structures
    /// and ray tracing pipelines. `extensions` must then list [`RAY_TRACING_EXTENSIONS`].
    pub ray_tracing: bool,
    /// Enable what an array of textures indexed in a shader needs (chapter 16's cut-outs):
    /// Vulkan 1.2's `runtimeDescriptorArray` (an array whose size the shader does not fix) and
    /// `shaderSampledImageArrayNonUniformIndexing` (neighbouring rays may read different
    /// textures). A device without both is skipped, and the skip says which it lacks.
    pub texture_arrays: bool,
}

/// What chapters 04 and 05 need (taught in 03): memory shared as fds, and semaphores where the
/// driver has them.
pub const INTEROP: Requirements<'static> = Requirements {
    extensions: &[ash::khr::external_memory_fd::NAME],
    optional_extensions: &[ash::khr::external_semaphore_fd::NAME],
    ray_tracing: false,
    texture_arrays: false,
};

/// What chapters 07 and 08 need (taught in 03 and 06): memory shared as fds, semaphores where
/// the driver has them, and ray tracing.
pub const RAY_TRACED_INTEROP: Requirements<'static> = Requirements {
    extensions: &[
        ash::khr::external_memory_fd::NAME,
        RAY_TRACING_EXTENSIONS[0],
        RAY_TRACING_EXTENSIONS[1],
        RAY_TRACING_EXTENSIONS[2],
    ],
    optional_extensions: &[ash::khr::external_semaphore_fd::NAME],
    ray_tracing: true,
    texture_arrays: false,
};

/// The device extensions for building acceleration structures and tracing rays through them.
pub const RAY_TRACING_EXTENSIONS: [&CStr; 3] = [
    ash::khr::acceleration_structure::NAME,
    ash::khr::ray_tracing_pipeline::NAME,
    // Required by VK_KHR_acceleration_structure, though this tutorial builds on the device.
    ash::khr::deferred_host_operations::NAME,
];

/// Facts about the chosen device that the report and the GL side need.
#[derive(Debug, Clone)]
pub struct DeviceInfo {
    pub name: String,
    /// Driver name and version, e.g. "llvmpipe (Mesa 25.0.7)".
    pub driver: String,
    pub api_version: u32,
    pub device_type: vk::PhysicalDeviceType,
    pub device_uuid: [u8; vk::UUID_SIZE],
    pub driver_uuid: [u8; vk::UUID_SIZE],
}

impl DeviceInfo {
    /// The `vulkan` section of a chapter report: this device, with the extensions enabled on it
    /// (a device made by another library, as chapter 15's wgpu, reports through this too).
    pub fn report(&self, extensions: Vec<String>) -> VulkanReport {
        VulkanReport {
            device: self.name.clone(),
            driver: self.driver.clone(),
            api: version_string(self.api_version),
            device_uuid: uuid_hex(&self.device_uuid),
            driver_uuid: uuid_hex(&self.driver_uuid),
            extensions,
        }
    }

    /// "NAME, device UUID driver UUID": what a refusal names, for either side.
    pub fn identity(&self) -> String {
        format!(
            "{}, device {} driver {}",
            self.name,
            uuid_hex(&self.device_uuid),
            uuid_hex(&self.driver_uuid)
        )
    }
}

pub struct VulkanContext {
    /// Destroyed after the device (fields drop after `Drop::drop`, which destroys the device).
    pub instance: Instance,
    pub physical_device: vk::PhysicalDevice,
    pub info: DeviceInfo,
    pub memory_properties: vk::PhysicalDeviceMemoryProperties,
    pub device: ash::Device,
    pub queue_family_index: u32,
    pub queue: vk::Queue,
    pub enabled_extensions: Vec<String>,
    /// Buffers may be given device addresses (`Requirements::ray_tracing`).
    pub device_addresses: bool,
    /// The Vulkan loader, unloaded last (fields drop in order): after the instance.
    pub entry: ash::Entry,
}

impl VulkanContext {
    pub fn new(requirements: &Requirements) -> Result<Self> {
        // SAFETY: loading libvulkan runs its initialisers; nothing else is loaded under that name.
        let entry = unsafe { ash::Entry::load() }.context(
            "could not load the Vulkan loader (libvulkan.so.1): install libvulkan1 and a driver \
             (Debian 12: bash .ci/deps)",
        )?;
        let validation = validation_wanted(&entry);

        let app_info =
            vk::ApplicationInfo::default().application_name(c"vkgl-interop").api_version(API_VERSION);
        let layers: Vec<*const c_char> = if validation { vec![VALIDATION_LAYER.as_ptr()] } else { vec![] };
        // The validation layer provides VK_EXT_debug_utils, through which its messages reach us.
        let instance_extensions: Vec<*const c_char> =
            if validation { vec![ash::ext::debug_utils::NAME.as_ptr()] } else { vec![] };
        let mut messenger_info = messenger_create_info();
        let mut instance_info = vk::InstanceCreateInfo::default()
            .application_info(&app_info)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&instance_extensions);
        if validation {
            // Chained here too, so that vkCreateInstance/vkDestroyInstance are validated as well.
            instance_info = instance_info.push_next(&mut messenger_info);
        }
        let instance = Instance {
            instance: fail::call("vkCreateInstance", || unsafe {
                entry.create_instance(&instance_info, None)
            })?,
            debug: None,
        };
        VALIDATION_ON.store(validation, Ordering::Relaxed);
        let mut instance = instance; // destroyed on every early return from here on
        if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let messenger = fail::call("vkCreateDebugUtilsMessengerEXT", || unsafe {
                loader.create_debug_utils_messenger(&messenger_create_info(), None)
            })?;
            instance.debug = Some((loader, messenger));
        }

        let (physical_device, info, queue_family_index, enabled_extensions) =
            pick_physical_device(&instance, requirements)?;
        eprintln!("vulkan: using {} ({})", info.name, info.driver);

        let priorities = [1.0];
        let queue_infos = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family_index)
            .queue_priorities(&priorities)];
        let extension_names: Vec<std::ffi::CString> =
            enabled_extensions.iter().map(|e| std::ffi::CString::new(e.as_str()).unwrap()).collect();
        let extension_names: Vec<*const c_char> = extension_names.iter().map(|e| e.as_ptr()).collect();
        let arrays = requirements.texture_arrays;
        let mut vulkan12 = vk::PhysicalDeviceVulkan12Features::default()
            .buffer_device_address(requirements.ray_tracing)
            .runtime_descriptor_array(arrays)
            .shader_sampled_image_array_non_uniform_indexing(arrays);
        let mut acceleration =
            vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default().acceleration_structure(true);
        let mut pipelines =
            vk::PhysicalDeviceRayTracingPipelineFeaturesKHR::default().ray_tracing_pipeline(true);
        // SPIR-V 1.6 (glslc --target-env=vulkan1.3) gives compute shaders' workgroup sizes as
        // LocalSizeId, which needs maintenance4: core in Vulkan 1.3, and every 1.3 device has it.
        let mut vulkan13 = vk::PhysicalDeviceVulkan13Features::default().maintenance4(true);
        let mut device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_infos)
            .enabled_extension_names(&extension_names)
            .push_next(&mut vulkan13);
        if requirements.ray_tracing || arrays {
            device_info = device_info.push_next(&mut vulkan12);
        }
        if requirements.ray_tracing {
            device_info = device_info.push_next(&mut acceleration).push_next(&mut pipelines);
        }
        let device = fail::call(&format!("vkCreateDevice on {}", info.name), || unsafe {
            instance.create_device(physical_device, &device_info, None)
        })?;
        let queue = unsafe { device.get_device_queue(queue_family_index, 0) };
        let memory_properties = unsafe { instance.get_physical_device_memory_properties(physical_device) };

        Ok(VulkanContext {
            entry,
            instance,
            physical_device,
            info,
            memory_properties,
            device,
            queue_family_index,
            queue,
            enabled_extensions,
            device_addresses: requirements.ray_tracing,
        })
    }

    /// The `vulkan` section of the chapter report.
    pub fn report(&self) -> VulkanReport {
        self.info.report(self.enabled_extensions.clone())
    }

    /// Was `name` enabled on the device (required, or optional and present)?
    pub fn has_extension(&self, name: &CStr) -> bool {
        self.enabled_extensions.iter().any(|e| e.as_bytes() == name.to_bytes())
    }

    /// The first memory type allowed by `type_bits` (from `VkMemoryRequirements`) that has all of `flags`.
    pub fn find_memory_type(&self, type_bits: u32, flags: vk::MemoryPropertyFlags) -> Result<u32> {
        let props = &self.memory_properties;
        (0..props.memory_type_count)
            .find(|&i| {
                type_bits & (1 << i) != 0 && props.memory_types[i as usize].property_flags.contains(flags)
            })
            .with_context(|| {
                format!("{} has no memory type with {flags:?} in bits {type_bits:#b}", self.info.name)
            })
    }
}

impl VulkanContext {
    /// Waits until the device has finished all work: what a chapter does once, before its list
    /// of `drop`s (after `glFinish`), so that no owner destroys what the GPU still uses.
    pub fn wait_idle(&self) -> Result<()> {
        fail::call("vkDeviceWaitIdle", || unsafe { self.device.device_wait_idle() })
    }
}

impl Drop for VulkanContext {
    /// The device; then (a field) the instance. The chapter's objects are gone by now: it made
    /// them after the context, so they were dropped before it.
    fn drop(&mut self) {
        unsafe { self.device.destroy_device(None) };
    }
}

/// The instance and the validation layer's messenger, destroyed when dropped.
pub struct Instance {
    instance: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
}

impl std::ops::Deref for Instance {
    type Target = ash::Instance;
    fn deref(&self) -> &ash::Instance {
        &self.instance
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        unsafe {
            if let Some((loader, messenger)) = &self.debug {
                loader.destroy_debug_utils_messenger(*messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

/// "1.4.305"
pub fn version_string(version: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(version),
        vk::api_version_minor(version),
        vk::api_version_patch(version)
    )
}

// ---------------------------------------------------------------------------------------------
// Choosing a physical device

/// Extensions named in `VKGL_HIDE_EXTENSIONS=a,b` are treated as absent, on the Vulkan and GL
/// side alike, so that the "missing extension" path can be seen and tested on any machine.
pub fn hidden_extensions() -> Vec<String> {
    std::env::var("VKGL_HIDE_EXTENSIONS")
        .unwrap_or_default()
        .split(',')
        .map(|s| s.trim().to_owned())
        .filter(|s| !s.is_empty())
        .collect()
}

/// Where to get an extension, for the error message when it is missing.
pub fn extension_hint(name: &str) -> &'static str {
    match name {
        "VK_KHR_external_memory_fd" => "every Linux GPU driver has it, and so has Mesa's lavapipe",
        "VK_KHR_external_semaphore_fd" => {
            "NVIDIA, AMD and Intel drivers have it; lavapipe does not (chapters then synchronise on the host)"
        }
        "VK_KHR_acceleration_structure"
        | "VK_KHR_ray_tracing_pipeline"
        | "VK_KHR_deferred_host_operations" => "needs a ray-tracing GPU driver, or Mesa >= 24.1 lavapipe",
        _ => "see the chapter's page in the book",
    }
}

/// No physical device can run the chapter; says why for each one.
#[derive(Debug)]
pub struct NoSuitableDevice {
    /// (device, reason it was skipped)
    pub skipped: Vec<(String, String)>,
    /// Every required extension some device lacked.
    pub missing: Vec<String>,
}

impl fmt::Display for NoSuitableDevice {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        if self.skipped.is_empty() {
            return write!(
                f,
                "the Vulkan loader found no device at all: install a driver (no GPU: Mesa's lavapipe, `bash .ci/deps`)"
            );
        }
        writeln!(f, "no Vulkan device can run this chapter:")?;
        for (device, reason) in &self.skipped {
            writeln!(f, "  - {device}: {reason}")?;
        }
        for ext in &self.missing {
            writeln!(f, "  {ext}: {}", extension_hint(ext))?;
        }
        write!(
            f,
            "fix: use a driver with these extensions; with no GPU, Mesa >= 24.1 lavapipe \
             (Debian 12: `bash .ci/deps` installs it from bookworm-backports)"
        )
    }
}

impl std::error::Error for NoSuitableDevice {}

/// Every physical device is considered; each one skipped is logged with its reason. Among the
/// suitable ones a discrete GPU beats an integrated one, which beats a software rasteriser.
fn pick_physical_device(
    instance: &ash::Instance,
    requirements: &Requirements,
) -> Result<(vk::PhysicalDevice, DeviceInfo, u32, Vec<String>)> {
    let hidden = hidden_extensions();
    let mut suitable = Vec::new();
    let mut skipped = Vec::new();
    let mut missing_any: Vec<String> = Vec::new();

    for physical_device in
        fail::call("vkEnumeratePhysicalDevices", || unsafe { instance.enumerate_physical_devices() })?
    {
        let info = device_info(instance, physical_device);
        let label = format!("{} ({})", info.name, info.driver);

        if info.api_version < API_VERSION {
            skipped.push((label, format!("Vulkan {} < 1.3", version_string(info.api_version))));
            continue;
        }
        let available: Vec<String> = fail::call("vkEnumerateDeviceExtensionProperties", || unsafe {
            instance.enumerate_device_extension_properties(physical_device)
        })?
        .iter()
        .filter_map(|e| e.extension_name_as_c_str().ok())
        .map(|e| e.to_string_lossy().into_owned())
        .collect();
        let missing: Vec<String> = requirements
            .extensions
            .iter()
            .map(|e| e.to_string_lossy().into_owned())
            .filter(|e| !available.contains(e) || hidden.contains(e))
            .collect();
        if !missing.is_empty() {
            let list: Vec<String> = missing
                .iter()
                .map(|e| {
                    if hidden.contains(e) {
                        format!("{e} (hidden by VKGL_HIDE_EXTENSIONS)")
                    } else {
                        e.clone()
                    }
                })
                .collect();
            skipped.push((label, format!("lacks {}", list.join(", "))));
            for e in missing {
                if !missing_any.contains(&e) {
                    missing_any.push(e);
                }
            }
            continue;
        }
        if requirements.texture_arrays {
            let lacking = lacking_texture_array_features(instance, physical_device);
            if !lacking.is_empty() {
                let reason =
                    format!("lacks the Vulkan 1.2 feature {} (an array of textures)", lacking.join(" and "));
                skipped.push((label, reason));
                continue;
            }
        }
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
        let wanted = vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE;
        let Some(family) = families.iter().position(|q| q.queue_flags.contains(wanted)) else {
            skipped.push((label, "no queue family does graphics and compute".into()));
            continue;
        };
        let enabled: Vec<String> = requirements
            .extensions
            .iter()
            .chain(requirements.optional_extensions)
            .map(|e| e.to_string_lossy().into_owned())
            .filter(|e| available.contains(e) && !hidden.contains(e))
            .collect();
        suitable.push((physical_device, info, family as u32, enabled));
    }

    for (device, reason) in &skipped {
        eprintln!("vulkan: skipping {device}: {reason}");
    }
    let rank = |t: vk::PhysicalDeviceType| match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    };
    suitable.sort_by_key(|(_, info, _, _)| rank(info.device_type));
    suitable.into_iter().next().ok_or_else(|| NoSuitableDevice { skipped, missing: missing_any }.into())
}

/// Which of the features [`Requirements::texture_arrays`] asks for the device lacks, by name.
fn lacking_texture_array_features(instance: &ash::Instance, device: vk::PhysicalDevice) -> Vec<&'static str> {
    let mut vulkan12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut features = vk::PhysicalDeviceFeatures2::default().push_next(&mut vulkan12);
    unsafe { instance.get_physical_device_features2(device, &mut features) };
    let hidden = std::env::var("VKGL_HIDE_FEATURES").unwrap_or_default();
    let has = |name: &str, on: u32| on == vk::TRUE && !hidden.split(',').any(|h| h.trim() == name);
    let mut lacking = Vec::new();
    if !has("runtimeDescriptorArray", vulkan12.runtime_descriptor_array) {
        lacking.push("runtimeDescriptorArray");
    }
    if !has(
        "shaderSampledImageArrayNonUniformIndexing",
        vulkan12.shader_sampled_image_array_non_uniform_indexing,
    ) {
        lacking.push("shaderSampledImageArrayNonUniformIndexing");
    }
    lacking
}

fn device_info(instance: &ash::Instance, physical_device: vk::PhysicalDevice) -> DeviceInfo {
    // ANCHOR: vulkan_uuids
    let mut id = vk::PhysicalDeviceIDProperties::default();
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut id).push_next(&mut driver);
    unsafe { instance.get_physical_device_properties2(physical_device, &mut props2) };
    // ANCHOR_END: vulkan_uuids
    let props = props2.properties;
    let text = |s: Result<&CStr, _>| s.map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    DeviceInfo {
        name: text(props.device_name_as_c_str()),
        driver: format!("{} {}", text(driver.driver_name_as_c_str()), text(driver.driver_info_as_c_str()))
            .trim()
            .to_owned(),
        api_version: props.api_version,
        device_type: props.device_type,
        device_uuid: id.device_uuid,
        driver_uuid: id.driver_uuid,
    }
}
