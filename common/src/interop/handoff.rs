//! How GL and Vulkan take turns on shared memory (taught in chapter 03): two exported
//! semaphores where both drivers can share them, or the CPU waiting for each side where not.

use crate::base::gl::{self, GlContext};
use crate::base::owned::{Owned, create};
use crate::base::vulkan::VulkanContext;
use crate::instruments::fail;
use anyhow::{Context as _, Result};
use ash::vk;
use glow::HasContext;
use std::cell::Cell;
use std::collections::BTreeMap;
use std::os::fd::{AsRawFd, FromRawFd, IntoRawFd, OwnedFd};
use std::sync::Mutex;

/// The Vulkan device extension for semaphores shared as fds. Optional: without it, [`Handoff::Host`].
pub const SEMAPHORE_EXTENSION: &std::ffi::CStr = ash::khr::external_semaphore_fd::NAME;
/// The one handle type semaphores are shared as: an opaque fd, meaningful to the same driver only.
const SEMAPHORE_HANDLE_TYPE: vk::ExternalSemaphoreHandleTypeFlags =
    vk::ExternalSemaphoreHandleTypeFlags::OPAQUE_FD;

/// One semaphore, seen by both APIs. Deleted on both sides when dropped (fields, in order: GL's
/// first). No submission may still wait on it or signal it then.
pub struct SharedSemaphore {
    pub gl: gl::Owned<gl::Semaphore>,
    pub vk: Owned<vk::Semaphore>,
}

/// Both APIs and how work passes between them, as every frame that hands images over needs
/// them: the contexts, the hand-over, and the command buffer Vulkan's part is recorded into.
#[derive(Clone, Copy)]
pub struct Apis<'a> {
    pub vk: &'a VulkanContext,
    pub gl: &'a GlContext,
    pub handoff: &'a Handoff,
    pub commands: &'a crate::base::commands::Commands,
}

/// The two hand-overs of every frame, and how they are made.
#[allow(clippy::large_enum_variant)] // one per program: boxing the semaphores would buy nothing
pub enum Handoff {
    /// GL and Vulkan wait for each other on the GPU; the CPU never waits.
    Semaphores {
        /// Signalled by GL when it is done with the shared images; Vulkan waits on it.
        gl_done: SharedSemaphore,
        /// Signalled by Vulkan when it is done; GL waits on it.
        vulkan_done: SharedSemaphore,
    },
    /// The driver cannot share semaphores (lavapipe, llvmpipe): the CPU waits for GL to finish
    /// (`glFinish`) before submitting Vulkan's work, and for Vulkan's fence before GL goes on.
    /// Each API sits idle while the other works, and the CPU blocks twice a frame. Nothing tells
    /// GL a layout, so GL changes none: a shared image stays in the layout Vulkan last left it
    /// in, which is why [`Handoff::hand_over`] keeps it in `GENERAL` both ways on this path.
    Host {
        /// Hand-overs to Vulkan that named another layout than the one Vulkan had left.
        disagreements: Cell<u32>,
    },
}

/// The layout (GL's name) each shared texture, by GL name, was in when Vulkan last handed it to
/// GL: written by [`Handoff::gl_acquire`] and `interop::hand_new_images_to_gl`, forgotten when the
/// texture is deleted. On the host path GL moves no layout, so this is the layout Vulkan's next
/// acquire must name.
static LEFT_BY_VULKAN: Mutex<BTreeMap<u32, u32>> = Mutex::new(BTreeMap::new());

/// Records that Vulkan left `texture` in `layout` for GL (`None`: the texture is gone).
pub(crate) fn vulkan_left(texture: u32, layout: Option<u32>) {
    let mut left = LEFT_BY_VULKAN.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    match layout {
        Some(layout) => left.insert(texture, layout),
        None => left.remove(&texture),
    };
}

/// A shared texture's line in that record: forgotten when dropped, with the texture (a field of
/// `interop::SharedTexture`), so that a later texture given the same name starts with none.
#[derive(Debug)]
pub struct LeftByVulkan(u32);

impl LeftByVulkan {
    pub(crate) fn new(texture: glow::Texture) -> Self {
        LeftByVulkan(texture.0.get())
    }
}

impl Drop for LeftByVulkan {
    fn drop(&mut self) {
        vulkan_left(self.0, None);
    }
}

// ANCHOR: hand_over
/// The layouts of one shared image at the two hand-overs of a frame. Vulkan's acquire barrier
/// starts from `to_vulkan` and its release barrier ends in `to_gl`; GL's signal and wait name the
/// same two (`common::base::gl::layout::of`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HandOver {
    /// Where GL leaves the image for Vulkan.
    pub to_vulkan: vk::ImageLayout,
    /// Where Vulkan leaves the image for GL.
    pub to_gl: vk::ImageLayout,
}
// ANCHOR_END: hand_over

impl HandOver {
    /// GL's names for the two layouts, for [`Handoff::gl_release`] and [`Handoff::gl_acquire`].
    pub fn gl(self) -> (u32, u32) {
        let name = |layout| gl::layout::of(layout).expect("a layout GL can name");
        (name(self.to_vulkan), name(self.to_gl))
    }
}

impl Handoff {
    // ANCHOR: sync_new
    /// Semaphores when both sides support them (and `VKGL_HIDE_EXTENSIONS` hides neither), else
    /// the host fallback; says which on stderr.
    pub fn new(vk: &VulkanContext, gl: &GlContext) -> Result<Handoff> {
        Handoff::with(vk, gl, SharedSemaphore::new)
    }

    /// As [`Handoff::new`], each semaphore shared by `share` (chapter 03, which teaches it, shares
    /// its own).
    pub fn with(
        vk: &VulkanContext,
        gl: &GlContext,
        share: impl Fn(&VulkanContext, &GlContext) -> Result<SharedSemaphore>,
    ) -> Result<Handoff> {
        let vulkan_can = vk.has_extension(SEMAPHORE_EXTENSION) && vulkan_can_export_semaphores(vk);
        let (Some(_), true) = (&gl.semaphores, vulkan_can) else {
            let missing = match (vulkan_can, gl.semaphores.is_some()) {
                (false, false) => "neither Vulkan nor GL shares semaphores",
                (false, true) => "Vulkan cannot export semaphores as fds",
                _ => "GL cannot import semaphores (no GL_EXT_semaphore_fd)",
            };
            eprintln!("sync: host ({missing}): the CPU waits for each API in turn");
            return Ok(Handoff::Host { disagreements: Cell::new(0) });
        };
        let gl_done = share(vk, gl).context("sharing the gl_done semaphore")?;
        // Should this one fail, `gl_done` is dropped on the way out, which deletes it.
        let vulkan_done = share(vk, gl).context("sharing the vulkan_done semaphore")?;
        eprintln!("sync: semaphores (GL and Vulkan wait for each other on the GPU)");
        Ok(Handoff::Semaphores { gl_done, vulkan_done })
    }
    // ANCHOR_END: sync_new

    /// "semaphores" or "host", for the report.
    pub fn name(&self) -> &'static str {
        match self {
            Handoff::Semaphores { .. } => "semaphores",
            Handoff::Host { .. } => "host",
        }
    }

    // ANCHOR: hand_over_layouts
    /// The layouts to hand a shared image over in, on this path. `to_vulkan` is the layout
    /// Vulkan's work wants first, `to_gl` the one GL's work wants.
    ///
    /// - Semaphores: those two. GL's signal moves the image to `to_vulkan`, and GL's wait is
    ///   told Vulkan left it in `to_gl`: each side finds the layout it asked for.
    /// - Host: `GENERAL` both ways. `glFinish` and a fence carry no layout, so GL moves the image
    ///   nowhere and Vulkan's next acquire finds it where Vulkan's last release left it. With two
    ///   different layouts, Vulkan would acquire from a layout the image is not in. `GENERAL` is
    ///   the one layout valid for every use on both sides (attachment, sampling, storage, copies).
    pub fn hand_over(&self, to_vulkan: vk::ImageLayout, to_gl: vk::ImageLayout) -> HandOver {
        match self {
            Handoff::Semaphores { .. } => HandOver { to_vulkan, to_gl },
            Handoff::Host { .. } => {
                HandOver { to_vulkan: vk::ImageLayout::GENERAL, to_gl: vk::ImageLayout::GENERAL }
            }
        }
    }
    // ANCHOR_END: hand_over_layouts

    /// On the host path: did every hand-over to Vulkan name the layout Vulkan itself had left
    /// the image in (GL changes none there)? With semaphores GL makes the transitions, and any
    /// pair of layouts agrees.
    pub fn layouts_agreed(&self) -> bool {
        match self {
            Handoff::Semaphores { .. } => true,
            Handoff::Host { disagreements, .. } => disagreements.get() == 0,
        }
    }

    // ANCHOR: gl_release
    /// `glSignalSemaphoreEXT` or `glWaitSemaphoreEXT` (`call`) on GL's side of `semaphore`, for
    /// no buffer and for `textures`, each in the layout (GL's name) that `layouts` gives it.
    unsafe fn on_textures(
        call: unsafe extern "system" fn(u32, u32, *const u32, u32, *const u32, *const u32),
        semaphore: &SharedSemaphore,
        textures: &[glow::Texture],
        layouts: &[u32],
    ) {
        let names: Vec<u32> = textures.iter().map(|t| t.0.get()).collect();
        unsafe {
            call(semaphore.gl.0, 0, std::ptr::null(), names.len() as u32, names.as_ptr(), layouts.as_ptr())
        }
    }

    /// GL has finished with `textures`; Vulkan may start. `layouts` are GL's names
    /// (`common::base::gl::layout`) for the layouts Vulkan's first barrier will find them in.
    pub fn gl_release(&self, gl: &GlContext, textures: &[glow::Texture], layouts: &[u32]) {
        // GL reads one layout per texture from the pointer: a shorter slice would be read past.
        assert_eq!(textures.len(), layouts.len(), "one layout per texture");
        match self {
            Handoff::Semaphores { gl_done, .. } => {
                let ext = gl.semaphores.as_ref().expect("Handoff::Semaphores implies GL semaphores");
                unsafe {
                    Handoff::on_textures(ext.SignalSemaphoreEXT, gl_done, textures, layouts);
                    // The signal sits in GL's command queue until flushed: without this, Vulkan
                    // could wait for it forever.
                    gl.gl.flush();
                }
            }
            Handoff::Host { disagreements } => {
                // No layout travels with glFinish: the textures are in the layouts Vulkan's own
                // releases left. Count every one that `layouts` misnames (for the chapter's check).
                disagreements.set(disagreements.get() + misnamed_layouts(textures, layouts));
                unsafe { gl.gl.finish() }
            }
        }
    }
    // ANCHOR_END: gl_release

    /// What Vulkan's submission waits on: GL's release (`None` on the host path, where the CPU
    /// already waited).
    pub fn vulkan_waits_on(&self) -> Option<vk::Semaphore> {
        match self {
            Handoff::Semaphores { gl_done, .. } => Some(*gl_done.vk),
            Handoff::Host { .. } => None,
        }
    }

    /// What Vulkan's submission signals for GL (`None` on the host path).
    pub fn vulkan_signals(&self) -> Option<vk::Semaphore> {
        match self {
            Handoff::Semaphores { vulkan_done, .. } => Some(*vulkan_done.vk),
            Handoff::Host { .. } => None,
        }
    }

    // ANCHOR: gl_acquire
    /// Vulkan's work (submitted with `fence`) must be done before GL uses `textures`, which
    /// Vulkan left in `layouts`. Semaphores: GL's queue waits, the CPU does not. Host: the CPU
    /// waits for the fence.
    pub fn gl_acquire(
        &self,
        vk: &VulkanContext,
        gl: &GlContext,
        fence: vk::Fence,
        textures: &[glow::Texture],
        layouts: &[u32],
    ) -> Result<()> {
        assert_eq!(textures.len(), layouts.len(), "one layout per texture"); // as in gl_release
        crate::instruments::fail::step("GL's acquire of the shared images")?;
        match self {
            Handoff::Semaphores { vulkan_done, .. } => {
                let ext = gl.semaphores.as_ref().expect("Handoff::Semaphores implies GL semaphores");
                unsafe { Handoff::on_textures(ext.WaitSemaphoreEXT, vulkan_done, textures, layouts) };
                Ok(())
            }
            Handoff::Host { .. } => {
                // Where Vulkan left them, GL will not move them: the next gl_release checks it.
                textures.iter().zip(layouts).for_each(|(t, &layout)| vulkan_left(t.0.get(), Some(layout)));
                crate::base::commands::wait_for(vk, fence, "vkWaitForFences for Vulkan's work, on the CPU")
            }
        }
    }
    // ANCHOR_END: gl_acquire
}

/// On the host path: how many of `textures` are not in the layout `layouts` names for them,
/// that is not where Vulkan last left them (or Vulkan never handed them to GL). Each is named on
/// stderr.
fn misnamed_layouts(textures: &[glow::Texture], layouts: &[u32]) -> u32 {
    let left = LEFT_BY_VULKAN.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let mut misnamed = 0;
    for (texture, layout) in textures.iter().zip(layouts) {
        let actual = left.get(&texture.0.get());
        if actual != Some(layout) {
            misnamed += 1;
            let actual = actual.map_or("UNDEFINED: Vulkan never handed it to GL".into(), |l| {
                format!("{} (Vulkan's last release)", gl::layout::name(*l))
            });
            eprintln!(
                "sync: host path: texture {} handed to Vulkan as {}, but GL moves no layout here \
                 and it is in {actual}",
                texture.0.get(),
                gl::layout::name(*layout)
            );
        }
    }
    misnamed
}

// ANCHOR: can_export_semaphores
/// Can this device export binary semaphores as opaque fds?
pub fn vulkan_can_export_semaphores(vk: &VulkanContext) -> bool {
    let info = vk::PhysicalDeviceExternalSemaphoreInfo::default().handle_type(SEMAPHORE_HANDLE_TYPE);
    let mut support = vk::ExternalSemaphoreProperties::default();
    unsafe {
        vk.instance.get_physical_device_external_semaphore_properties(vk.physical_device, &info, &mut support)
    };
    support.external_semaphore_features.contains(vk::ExternalSemaphoreFeatureFlags::EXPORTABLE)
}
// ANCHOR_END: can_export_semaphores

impl SharedSemaphore {
    // ANCHOR: share_semaphore
    /// A Vulkan semaphore exported as an fd and imported into GL, which then owns the fd (taught
    /// in chapter 03, whose `main.rs` makes these calls itself).
    pub fn new(vk: &VulkanContext, gl: &GlContext) -> Result<Self> {
        // Each side is owned as it is made: an early return deletes what exists.
        let semaphore = exportable_semaphore(vk)?;
        let fd = semaphore_fd(vk, *semaphore)?;
        let gl_semaphore = import_semaphore(gl, fd)?;
        Ok(SharedSemaphore { gl: gl_semaphore, vk: semaphore })
    }
}

/// A binary Vulkan semaphore whose payload can be exported as an opaque fd.
pub fn exportable_semaphore(vk: &VulkanContext) -> Result<Owned<vk::Semaphore>> {
    let mut export = vk::ExportSemaphoreCreateInfo::default().handle_types(SEMAPHORE_HANDLE_TYPE);
    let info = vk::SemaphoreCreateInfo::default().push_next(&mut export);
    let semaphore = create(&vk.device, "vkCreateSemaphore (exportable)", || unsafe {
        vk.device.create_semaphore(&info, None)
    })?;
    crate::instruments::resources::created("vk_semaphore_exportable", 0);
    Ok(semaphore)
}

/// A new fd for `semaphore`'s payload (`vkGetSemaphoreFdKHR`), ours to close or to hand on.
pub fn semaphore_fd(vk: &VulkanContext, semaphore: vk::Semaphore) -> Result<OwnedFd> {
    let loader = ash::khr::external_semaphore_fd::Device::new(&vk.instance, &vk.device);
    let get = vk::SemaphoreGetFdInfoKHR::default().semaphore(semaphore).handle_type(SEMAPHORE_HANDLE_TYPE);
    let fd = fail::call("vkGetSemaphoreFdKHR", || unsafe { loader.get_semaphore_fd(&get) })?;
    // SAFETY: vkGetSemaphoreFdKHR returned a new fd that nothing else owns. Until an import
    // succeeds, `fd` closes it on every way out.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

/// GL's semaphore for the payload `fd` refers to (`glImportSemaphoreFdEXT`), owned from the call
/// that makes it. A successful import takes the fd; a failed one does not, and `fd` is closed on
/// the way out.
pub fn import_semaphore(gl: &GlContext, fd: OwnedFd) -> Result<gl::Owned<gl::Semaphore>> {
    let ext = gl.semaphores.as_ref().context("GL has no GL_EXT_semaphore_fd")?;
    let gl_semaphore = gl::create(ext, "glGenSemaphoresEXT", |ext| {
        let mut name = 0;
        unsafe { (ext.GenSemaphoresEXT)(1, &mut name) };
        gl::made(name, "glGenSemaphoresEXT").map(gl::Semaphore)
    })?;
    fail::step("glImportSemaphoreFdEXT")?;
    unsafe { (ext.ImportSemaphoreFdEXT)(gl_semaphore.0, gl::HANDLE_TYPE_OPAQUE_FD_EXT, fd.as_raw_fd()) };
    // On failure `fd` is dropped, and so closed (the failed import did not take it), and GL's
    // semaphore is deleted.
    gl.check_error("glImportSemaphoreFdEXT")?;
    // SAFETY: the import succeeded; the fd is GL's now.
    let _ = fd.into_raw_fd();
    Ok(gl_semaphore)
}
// ANCHOR_END: share_semaphore
