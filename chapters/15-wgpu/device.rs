//! Chapter 15, step 1: a wgpu device that GL can share memory (and, where both drivers can,
//! semaphores) with. wgpu enables only the extensions its own features need; the two this
//! chapter needs are added through wgpu-hal's device-creation callback.

use anyhow::{Context as _, Result, bail};
use ash::vk;
use common::base::vulkan::{DeviceInfo, extension_hint, hidden_extensions};
use common::instruments::{fail, validation};
use std::ffi::CStr;
use std::sync::Arc;
use wgpu::hal::api::Vulkan;

/// Memory shared as fds: required.
pub const MEMORY_FD: &CStr = ash::khr::external_memory_fd::NAME;
/// Semaphores shared as fds: enabled where the driver has it (lavapipe has not).
pub const SEMAPHORE_FD: &CStr = ash::khr::external_semaphore_fd::NAME;

/// wgpu's device and queue, and what GL and the report need to know of them.
pub struct WgpuDevice {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// Name, driver and UUIDs, as common's Vulkan context would report them.
    pub info: DeviceInfo,
    /// Did the callback enable [`SEMAPHORE_FD`]?
    pub semaphores: bool,
    /// The device extensions enabled: wgpu's own and the callback's.
    pub extensions: Vec<String>,
}

// ANCHOR: instance
/// wgpu's Vulkan backend alone, with the validation layer wherever common's contexts would have
/// it (installed, and not `VKGL_VALIDATION=0`), its messages counted as theirs are.
pub fn instance() -> Result<wgpu::Instance> {
    let validate = !std::env::var("VKGL_VALIDATION").is_ok_and(|v| v == "0");
    let flags = if validate { wgpu::InstanceFlags::VALIDATION } else { wgpu::InstanceFlags::empty() };
    let descriptor = wgpu::hal::InstanceDescriptor {
        name: "chapter 15",
        flags,
        memory_budget_thresholds: Default::default(),
        backend_options: Default::default(),
        telemetry: None,
        display: None,
    };
    // The layer's messages reach wgpu-hal's messenger (and `log`) through VK_EXT_debug_utils,
    // which wgpu asks for only with InstanceFlags::DEBUG. That flag also writes the WGSL source
    // into the SPIR-V, which Debian 12's layer (1.3.239) calls invalid: ask for the extension alone.
    let mut layer = false;
    let callback = |args: wgpu::hal::vulkan::CreateInstanceCallbackArgs| {
        let layers = unsafe { args.entry.enumerate_instance_layer_properties() }.unwrap_or_default();
        layer = layers.iter().any(|l| l.layer_name_as_c_str() == Ok(c"VK_LAYER_KHRONOS_validation"));
        if validate && layer && !args.extensions.contains(&ash::ext::debug_utils::NAME) {
            args.extensions.push(ash::ext::debug_utils::NAME);
        }
    };
    fail::step("vkCreateInstance (wgpu-hal init_with_callback)")?;
    // SAFETY: the callback only adds an extension the layer provides.
    let hal = unsafe { wgpu::hal::vulkan::Instance::init_with_callback(&descriptor, Some(Box::new(callback))) }
        .context("wgpu-hal could not create a Vulkan instance: install libvulkan1 and a driver (Debian 12: bash .ci/deps)")?;
    match (validate, layer) {
        (true, true) => validation::layer_enabled_elsewhere(),
        (true, false) => {
            eprintln!("vulkan: VK_LAYER_KHRONOS_validation is not installed; running without validation")
        }
        (false, _) => {}
    }
    // SAFETY: a Vulkan instance wgpu-hal made, handed to wgpu whole.
    Ok(unsafe { wgpu::Instance::from_hal::<Vulkan>(hal) })
}
// ANCHOR_END: instance

/// Opens the device: the first Vulkan adapter, with [`MEMORY_FD`] (an error naming it, the
/// device and a fix when absent) and [`SEMAPHORE_FD`] where present.
pub fn open(instance: wgpu::Instance) -> Result<WgpuDevice> {
    fail::step("wgpu: request_adapter (Vulkan)")?;
    let adapter = pollster_block(instance.request_adapter(&wgpu::RequestAdapterOptions::default())).context(
        "wgpu found no Vulkan adapter: install a Vulkan driver (no GPU: Mesa's lavapipe, `bash .ci/deps`)",
    )?;
    // SAFETY: the guard is dropped at the end of this function; nothing here destroys the adapter.
    let hal_adapter = unsafe { adapter.as_hal::<Vulkan>() }.context("wgpu's adapter is not a Vulkan one")?;
    let instance_shared = hal_adapter.shared_instance();
    let (raw_instance, physical) = (instance_shared.raw_instance(), hal_adapter.raw_physical_device());

    // ANCHOR: uuids
    // The UUIDs GL must report too (chapter 02): wgpu does not expose them, Vulkan does.
    let mut ids = vk::PhysicalDeviceIDProperties::default();
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut properties = vk::PhysicalDeviceProperties2::default().push_next(&mut ids).push_next(&mut driver);
    unsafe { raw_instance.get_physical_device_properties2(physical, &mut properties) };
    let base = properties.properties;
    let info = DeviceInfo {
        name: base.device_name_as_c_str().unwrap_or(c"?").to_string_lossy().into_owned(),
        driver: format!(
            "{} {}",
            driver.driver_name_as_c_str().unwrap_or(c"?").to_string_lossy(),
            driver.driver_info_as_c_str().unwrap_or(c"?").to_string_lossy()
        ),
        api_version: base.api_version,
        device_type: base.device_type,
        device_uuid: ids.device_uuid,
        driver_uuid: ids.driver_uuid,
    };
    // ANCHOR_END: uuids

    // ANCHOR: extensions
    let available = fail::call("vkEnumerateDeviceExtensionProperties", || unsafe {
        raw_instance.enumerate_device_extension_properties(physical)
    })?;
    let hidden = hidden_extensions();
    let has = |name: &CStr| {
        let shown = !hidden.iter().any(|h| name.to_str() == Ok(h.as_str()));
        shown && available.iter().any(|e| e.extension_name_as_c_str() == Ok(name))
    };
    if !has(MEMORY_FD) {
        let name = MEMORY_FD.to_string_lossy();
        let why = if hidden.iter().any(|h| *h == name) { " (hidden by VKGL_HIDE_EXTENSIONS)" } else { "" };
        let fix = extension_hint(&name);
        bail!("{} lacks {name}{why}, which sharing memory with GL needs ({fix})", info.name);
    }
    let semaphores = has(SEMAPHORE_FD);
    let features = wgpu::Features::empty();
    let limits = adapter.limits(); // the device's own: the largest image it can draw included
    let mut enabled = Vec::new();
    // wgpu makes the VkDevice; the callback adds to the extensions it is about to ask for.
    let callback = |args: wgpu::hal::vulkan::CreateDeviceCallbackArgs| {
        for extension in [Some(MEMORY_FD), semaphores.then_some(SEMAPHORE_FD)].into_iter().flatten() {
            if !args.extensions.contains(&extension) {
                args.extensions.push(extension);
            }
        }
        enabled = args.extensions.iter().map(|e| e.to_string_lossy().into_owned()).collect();
    };
    fail::step("vkCreateDevice (wgpu-hal open_with_callback)")?;
    // SAFETY: the callback only adds extensions this device lists; it removes nothing.
    let open = unsafe {
        hal_adapter.open_with_callback(features, &limits, &Default::default(), Some(Box::new(callback)))
    }
    .with_context(|| format!("wgpu-hal could not open {}", info.name))?;
    drop(hal_adapter);
    let descriptor =
        wgpu::DeviceDescriptor { label: Some("chapter 15"), required_limits: limits, ..Default::default() };
    // SAFETY: `open` came from this adapter, with no features beyond `features` (none).
    let (device, queue) = unsafe { adapter.create_device_from_hal::<Vulkan>(open, &descriptor) }
        .context("wgpu::Adapter::create_device_from_hal")?;
    // ANCHOR_END: extensions
    // wgpu's own validation (a misused wgpu call) is counted with the layer's, not a panic.
    device.on_uncaptured_error(Arc::new(|error| validation::count_message(true, &format!("wgpu: {error}"))));
    enabled.sort();
    Ok(WgpuDevice { device, queue, info, semaphores, extensions: enabled })
}

/// Counts the validation layer's messages, which wgpu-hal's messenger passes to the `log` crate
/// (wgpu made the instance, so common's messenger is not there to count them).
pub struct LayerMessages;

impl log::Log for LayerMessages {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        metadata.level() <= log::Level::Warn && metadata.target().starts_with("wgpu_hal::vulkan")
    }
    fn log(&self, record: &log::Record) {
        if !self.enabled(record.metadata()) {
            return;
        }
        let message = record.args().to_string();
        match message.strip_prefix('\t') {
            // The objects and labels a message names come as records of their own.
            Some(detail) => eprintln!("  {detail}"),
            None => validation::count_message(record.level() == log::Level::Error, &message),
        }
    }
    fn flush(&self) {}
}

/// wgpu's adapter request is a future; on native backends it is ready at once.
fn pollster_block<T>(future: impl std::future::Future<Output = T>) -> T {
    let waker = std::task::Waker::noop();
    let mut context = std::task::Context::from_waker(waker);
    let mut future = std::pin::pin!(future);
    loop {
        if let std::task::Poll::Ready(value) = future.as_mut().poll(&mut context) {
            return value;
        }
    }
}
