//! Chapter 15, steps 3 and 4: images both APIs draw into and read, in memory this chapter
//! allocated and exported (wgpu allocates through gpu-allocator, which cannot export); and the
//! two semaphores, where both drivers share them.

use anyhow::{Context as _, Result, ensure};
use ash::vk;
use common::base::gl::GlContext;
use common::base::image::image_info;
use common::base::owned::{Owned, create};
use common::instruments::fail;
use common::interop::exportable::{self, HANDLE_TYPE, MemoryTerms};
use common::interop::handoff::{SharedSemaphore, import_semaphore};
use common::interop::{SharedTexture, import_texture_2d};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use wgpu::hal::api::Vulkan;

// ANCHOR: shared_image
/// One image, seen three ways. Dropped, it first has wgpu destroy its texture and waits until
/// wgpu is done with it (its drop callback then runs); then its fields go in the order written:
/// GL's texture and memory object, then the image and its memory, which this chapter owns from
/// first to last.
pub struct SharedImage {
    pub wgpu: wgpu::Texture,
    /// wgpu's view of the whole image, made once: every pass that uses the image uses it.
    pub view: wgpu::TextureView,
    device: wgpu::Device,
    /// Set by wgpu's drop callback: wgpu is done with the image.
    released: Arc<AtomicBool>,
    pub gl: SharedTexture,
    pub image: Owned<vk::Image>,
    #[allow(dead_code)] // never read: held to be freed last, when dropped
    pub memory: Owned<vk::DeviceMemory>,
}

impl Drop for SharedImage {
    fn drop(&mut self) {
        // Without this, wgpu would keep the image until its last submission is over and the
        // device next polled: possibly after the image below is destroyed.
        self.wgpu.destroy();
        if let Err(error) = self.device.poll(wgpu::PollType::wait_indefinitely()) {
            eprintln!("wgpu: Device::poll before destroying a shared image: {error}");
        }
        if !self.released.load(Ordering::SeqCst) {
            DESTROYED_IN_USE.fetch_add(1, Ordering::SeqCst); // the report's check fails
        }
    }
}
// ANCHOR_END: shared_image

/// How many images wgpu has wrapped and let go of (its drop callbacks), and how many the chapter
/// would have destroyed while wgpu still held them: equal, and none, once all are dropped.
pub static WRAPPED: AtomicU32 = AtomicU32::new(0);
pub static RELEASED: AtomicU32 = AtomicU32::new(0);
pub static DESTROYED_IN_USE: AtomicU32 = AtomicU32::new(0);

/// What a shared image is for: its format in wgpu's, Vulkan's and GL's names, and what wgpu does
/// with it (GL may draw into or read any of them).
pub struct Kind {
    pub format: wgpu::TextureFormat,
    pub vk_format: vk::Format,
    pub gl_format: u32,
    pub usage: wgpu::TextureUsages,
}

// ANCHOR: share_image
/// An image of `kind` and `extent` that wgpu and GL both use.
pub fn share_image(
    wgpu: &wgpu::Device,
    gl_context: &GlContext,
    kind: &Kind,
    extent: vk::Extent2D,
) -> Result<SharedImage> {
    let Kind { format, vk_format, gl_format, usage } = *kind;
    // SAFETY: the guard is dropped before this function returns; nothing here destroys the device.
    let hal = unsafe { wgpu.as_hal::<Vulkan>() }.context("wgpu's device is not a Vulkan one")?;
    let (device, instance) = (hal.raw_device(), hal.shared_instance().raw_instance());
    // Every usage either API has for it: GL may draw into it (COLOR_ATTACHMENT) or sample it.
    let mut vk_usage = vk::ImageUsageFlags::COLOR_ATTACHMENT
        | vk::ImageUsageFlags::SAMPLED
        | vk::ImageUsageFlags::TRANSFER_SRC;
    let mut uses = wgpu::TextureUses::RESOURCE | wgpu::TextureUses::COPY_SRC; // wgpu-hal's names
    if usage.contains(wgpu::TextureUsages::RENDER_ATTACHMENT) {
        uses |= wgpu::TextureUses::COLOR_TARGET;
    }
    if usage.contains(wgpu::TextureUsages::STORAGE_BINDING) {
        vk_usage |= vk::ImageUsageFlags::STORAGE;
        uses |= wgpu::TextureUses::STORAGE_WRITE_ONLY;
    }

    // The image: chapter 01's, made exportable before its memory exists.
    let mut external = vk::ExternalMemoryImageCreateInfo::default().handle_types(HANDLE_TYPE);
    let info = image_info(vk_format, vk_usage, extent)
        .flags(vk::ImageCreateFlags::MUTABLE_FORMAT)
        .push_next(&mut external);
    let what = format!("vkCreateImage (exportable, {vk_format:?}, for wgpu)");
    let image = create(device, &what, || unsafe { device.create_image(&info, None) })?
        .counted("vk_image_exportable", 0);

    // Its memory: dedicated (GL imports it whole, at offset 0) and exportable.
    let requirements = unsafe { device.get_image_memory_requirements(*image) };
    let types = unsafe { instance.get_physical_device_memory_properties(hal.raw_physical_device()) };
    let local = vk::MemoryPropertyFlags::DEVICE_LOCAL;
    let type_index = (0..types.memory_type_count)
        .find(|&i| {
            requirements.memory_type_bits & (1 << i) != 0
                && types.memory_types[i as usize].property_flags.contains(local)
        })
        .context("no device-local memory type for a shared image")?;
    let mut export = vk::ExportMemoryAllocateInfo::default().handle_types(HANDLE_TYPE);
    let mut dedicated = vk::MemoryDedicatedAllocateInfo::default().image(*image);
    let allocate = vk::MemoryAllocateInfo::default()
        .allocation_size(requirements.size)
        .memory_type_index(type_index)
        .push_next(&mut export)
        .push_next(&mut dedicated);
    let what = format!("vkAllocateMemory: {} bytes, exportable, for wgpu's image", requirements.size);
    let memory = create(device, &what, || unsafe { device.allocate_memory(&allocate, None) })?
        .counted("vk_memory_exportable", requirements.size);
    fail::call("vkBindImageMemory", || unsafe { device.bind_image_memory(*image, *memory, 0) })?;

    // GL imports it (chapters 02 and 03): from here GL owns the fd.
    let loader = ash::khr::external_memory_fd::Device::new(instance, device);
    let fd = exportable::export_fd(&loader, *memory)?;
    let terms = MemoryTerms { size: requirements.size, dedicated: true };
    let gl_texture = import_texture_2d(gl_context, terms, fd, gl_format, (extent.width, extent.height))?;
    // ANCHOR_END: share_image

    // ANCHOR: wrap
    // wgpu wraps the image without owning it or its memory: `External` memory, and a callback,
    // which makes wgpu call it instead of vkDestroyImage once its last use is over.
    let descriptor = wgpu::TextureDescriptor {
        label: Some("shared with GL"),
        size: wgpu::Extent3d { width: extent.width, height: extent.height, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: usage | wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    };
    let released = Arc::new(AtomicBool::new(false));
    let flag = released.clone();
    let on_drop: wgpu::hal::DropCallback = Box::new(move || {
        flag.store(true, Ordering::SeqCst);
        RELEASED.fetch_add(1, Ordering::SeqCst);
    });
    fail::step("wgpu: texture_from_raw + create_texture_from_hal")?;
    // SAFETY: the image was made as `descriptor` says; it and its memory outlive wgpu's use of
    // them (`SharedImage`'s field order, and the poll in its owner's teardown).
    let hal_texture = unsafe {
        hal.texture_from_raw(
            *image,
            &wgpu::hal::TextureDescriptor {
                label: descriptor.label,
                size: descriptor.size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: descriptor.dimension,
                format,
                usage: uses,
                memory_flags: wgpu::hal::MemoryFlags::empty(),
                view_formats: vec![],
            },
            Some(on_drop),
            wgpu::hal::vulkan::TextureMemory::External,
        )
    };
    WRAPPED.fetch_add(1, Ordering::SeqCst);
    drop(hal);
    // UNINITIALIZED: nothing is in it yet, and wgpu's first barrier, in its first turn, may
    // discard. (wgpu takes what a wrapped texture holds as written, and never clears it itself:
    // what GL draws into one stays.)
    let texture = unsafe {
        wgpu.create_texture_from_hal::<Vulkan>(hal_texture, &descriptor, wgpu::TextureUses::UNINITIALIZED)
    };
    // ANCHOR_END: wrap
    let view = texture.create_view(&Default::default());
    Ok(SharedImage { wgpu: texture, view, device: wgpu.clone(), released, gl: gl_texture, image, memory })
}

// ANCHOR: semaphores
/// Two semaphores (wgpu done, GL done), exported and imported into GL, when the device enabled
/// `VK_KHR_external_semaphore_fd` and GL has `GL_EXT_semaphore_fd`; `None` (the host path) else.
pub fn share_semaphores(
    wgpu: &wgpu::Device,
    gl_context: &GlContext,
    vulkan_can: bool,
) -> Result<Option<[SharedSemaphore; 2]>> {
    if !vulkan_can || gl_context.semaphores.is_none() {
        let missing =
            if vulkan_can { "GL has no GL_EXT_semaphore_fd" } else { "no VK_KHR_external_semaphore_fd" };
        eprintln!("sync: host ({missing}): the CPU waits for each API in turn");
        return Ok(None);
    }
    // SAFETY: as in share_image.
    let hal = unsafe { wgpu.as_hal::<Vulkan>() }.context("wgpu's device is not a Vulkan one")?;
    let (device, instance) = (hal.raw_device(), hal.shared_instance().raw_instance());
    let loader = ash::khr::external_semaphore_fd::Device::new(instance, device);
    let handle = vk::ExternalSemaphoreHandleTypeFlags::OPAQUE_FD;
    let share = |what: &str| -> Result<SharedSemaphore> {
        let mut export = vk::ExportSemaphoreCreateInfo::default().handle_types(handle);
        let info = vk::SemaphoreCreateInfo::default().push_next(&mut export);
        let semaphore = create(device, &format!("vkCreateSemaphore ({what}, exportable)"), || unsafe {
            device.create_semaphore(&info, None)
        })?;
        let get = vk::SemaphoreGetFdInfoKHR::default().semaphore(*semaphore).handle_type(handle);
        let fd = fail::call("vkGetSemaphoreFdKHR", || unsafe { loader.get_semaphore_fd(&get) })?;
        ensure!(fd >= 0, "vkGetSemaphoreFdKHR returned fd {fd}");
        // SAFETY: a new fd that nothing else owns; import_semaphore closes it on failure.
        let fd = unsafe { std::os::fd::FromRawFd::from_raw_fd(fd) };
        Ok(SharedSemaphore { gl: import_semaphore(gl_context, fd)?, vk: semaphore })
    };
    let wgpu_done = share("wgpu done")?;
    let gl_done = share("GL done")?; // should it fail, `wgpu_done` is dropped: both sides deleted
    eprintln!("sync: semaphores (VK_KHR_external_semaphore_fd, GL_EXT_semaphore_fd)");
    Ok(Some([wgpu_done, gl_done]))
}
// ANCHOR_END: semaphores
