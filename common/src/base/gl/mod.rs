//! The OpenGL side (taught in chapter 02): a GL 4.5 core context, headless through EGL's device
//! platform, plus the `GL_EXT_memory_object` / `GL_EXT_semaphore` entry points that glow lacks.
//!
//! Support is decided from GL's extension list only: Mesa's `eglGetProcAddress` returns a
//! non-null stub for any name at all, so a non-null pointer proves nothing.

mod debug;
mod objects;

pub use debug::*;
pub use objects::*;

use crate::base::vulkan::{DeviceInfo, hidden_extensions};
use anyhow::{Context as _, Result, bail};
use glow::HasContext;
use glutin::api::egl;
use glutin::config::{ConfigSurfaceTypes, ConfigTemplateBuilder};
use glutin::context::{ContextApi, ContextAttributesBuilder, GlProfile, PossiblyCurrentContext, Version};
use glutin::prelude::*;
use std::collections::HashSet;
use std::ffi::{CStr, CString, c_void};

/// Sharing memory: memory objects, buffer and texture storage in them, and the device UUIDs.
pub const MEMORY_EXTENSIONS: [&str; 2] = ["GL_EXT_memory_object", "GL_EXT_memory_object_fd"];
/// Sharing semaphores.
pub const SEMAPHORE_EXTENSIONS: [&str; 2] = ["GL_EXT_semaphore", "GL_EXT_semaphore_fd"];

// ANCHOR: enums
// Enums from GL_EXT_memory_object(_fd) and GL_EXT_semaphore, which glow does not define.
pub const TEXTURE_TILING_EXT: u32 = 0x9580;
pub const DEDICATED_MEMORY_OBJECT_EXT: u32 = 0x9581;
pub const OPTIMAL_TILING_EXT: u32 = 0x9584;
pub const HANDLE_TYPE_OPAQUE_FD_EXT: u32 = 0x9586;
pub const DEVICE_UUID_EXT: u32 = 0x9597;
pub const DRIVER_UUID_EXT: u32 = 0x9598;
pub const UUID_SIZE_EXT: usize = 16;
/// GL's names for the Vulkan image layouts a semaphore signal or wait can hand over.
pub mod layout {
    pub const GENERAL: u32 = 0x958D;
    pub const COLOR_ATTACHMENT: u32 = 0x958E;
    pub const SHADER_READ_ONLY: u32 = 0x9591;
    pub const TRANSFER_SRC: u32 = 0x9592;
    pub const TRANSFER_DST: u32 = 0x9593;

    /// The enum's name, for messages.
    pub fn name(layout: u32) -> &'static str {
        match layout {
            GENERAL => "GL_LAYOUT_GENERAL_EXT",
            COLOR_ATTACHMENT => "GL_LAYOUT_COLOR_ATTACHMENT_EXT",
            SHADER_READ_ONLY => "GL_LAYOUT_SHADER_READ_ONLY_EXT",
            TRANSFER_SRC => "GL_LAYOUT_TRANSFER_SRC_EXT",
            TRANSFER_DST => "GL_LAYOUT_TRANSFER_DST_EXT",
            _ => "a layout this tutorial does not use",
        }
    }

    /// GL's name for a Vulkan layout; `None` for one GL has no name for.
    pub fn of(layout: ash::vk::ImageLayout) -> Option<u32> {
        use ash::vk::ImageLayout as L;
        Some(match layout {
            L::GENERAL => GENERAL,
            L::COLOR_ATTACHMENT_OPTIMAL => COLOR_ATTACHMENT,
            L::SHADER_READ_ONLY_OPTIMAL => SHADER_READ_ONLY,
            L::TRANSFER_SRC_OPTIMAL => TRANSFER_SRC,
            L::TRANSFER_DST_OPTIMAL => TRANSFER_DST,
            _ => return None,
        })
    }
}
// ANCHOR_END: enums

/// Declares a struct of GL function pointers and a loader that refuses null ones.
macro_rules! gl_functions {
    ($(#[$meta:meta])* $struct:ident { $($name:ident: fn($($ty:ty),*) $(-> $ret:ty)?;)* }) => {
        $(#[$meta])*
        #[allow(non_snake_case)]
        #[derive(Clone, Copy)]
        pub struct $struct {
            $(pub $name: unsafe extern "system" fn($($ty),*) $(-> $ret)?,)*
        }
        impl $struct {
            fn load(get: &dyn Fn(&CStr) -> *const c_void) -> Result<Self> {
                Ok($struct {
                    $($name: {
                        let name = CString::new(concat!("gl", stringify!($name))).unwrap();
                        let pointer = get(&name);
                        if pointer.is_null() {
                            bail!("the GL driver lists the extension but has no {name:?}");
                        }
                        // SAFETY: a non-null GL entry point with this signature (from the extension spec).
                        unsafe { std::mem::transmute::<*const c_void, unsafe extern "system" fn($($ty),*) $(-> $ret)?>(pointer) }
                    },)*
                })
            }
        }
    };
}

// ANCHOR: entry_points
gl_functions! {
    /// `GL_EXT_memory_object` and `GL_EXT_memory_object_fd`.
    MemoryObjectFns {
        CreateMemoryObjectsEXT: fn(i32, *mut u32);
        DeleteMemoryObjectsEXT: fn(i32, *const u32);
        MemoryObjectParameterivEXT: fn(u32, u32, *const i32);
        ImportMemoryFdEXT: fn(u32, u64, u32, i32);
        NamedBufferStorageMemEXT: fn(u32, isize, u32, u64);
        TextureStorageMem2DEXT: fn(u32, i32, u32, i32, i32, u32, u64);
        GetUnsignedBytevEXT: fn(u32, *mut u8);
        GetUnsignedBytei_vEXT: fn(u32, u32, *mut u8);
        IsMemoryObjectEXT: fn(u32) -> u8;
    }
}

gl_functions! {
    /// `GL_EXT_semaphore` and `GL_EXT_semaphore_fd`.
    SemaphoreFns {
        GenSemaphoresEXT: fn(i32, *mut u32);
        DeleteSemaphoresEXT: fn(i32, *const u32);
        ImportSemaphoreFdEXT: fn(u32, u32, i32);
        SignalSemaphoreEXT: fn(u32, u32, *const u32, u32, *const u32, *const u32);
        WaitSemaphoreEXT: fn(u32, u32, *const u32, u32, *const u32, *const u32);
        IsSemaphoreEXT: fn(u32) -> u8;
    }
}
// ANCHOR_END: entry_points

gl_functions! {
    /// GL 4.5 core's `glIs*` queries (glow lacks some), to count the objects that exist.
    IsFns {
        IsTexture: fn(u32) -> u8;
        IsBuffer: fn(u32) -> u8;
        IsFramebuffer: fn(u32) -> u8;
        IsRenderbuffer: fn(u32) -> u8;
        IsVertexArray: fn(u32) -> u8;
        IsProgram: fn(u32) -> u8;
        IsQuery: fn(u32) -> u8;
    }
}

/// Names up to this are always probed by [`GlContext::live_objects`]: a driver that reuses
/// freed names may hand out a low one while higher ones are still alive.
const PROBED_NAMES: u32 = 4096;

/// A current GL context and what the chapters need to know about it.
pub struct GlContext {
    /// Shared (`Rc`) with the owners in `common` that delete their GL objects when dropped.
    pub gl: std::rc::Rc<glow::Context>,
    /// Present when the chapter asked for [`MEMORY_EXTENSIONS`].
    pub memory: Option<MemoryObjectFns>,
    /// Present when the driver has [`SEMAPHORE_EXTENSIONS`] (and they are not hidden).
    pub semaphores: Option<SemaphoreFns>,
    pub renderer: String,
    pub version: String,
    pub device_uuid: [u8; UUID_SIZE_EXT],
    pub driver_uuid: [u8; UUID_SIZE_EXT],
    /// The required extensions, for the report.
    pub required: Vec<String>,
    extensions: HashSet<String>,
    is: IsFns,
    context: PossiblyCurrentContext,
}

impl GlContext {
    // ANCHOR: headless
    /// A headless GL 4.5 core context on the EGL device whose device UUID is Vulkan's, or on the
    /// first EGL device when none matches (the chapter's UUID check then says why that is fatal).
    /// Fails, naming each one, when an extension in `required` is missing.
    pub fn headless(vulkan: &DeviceInfo, required: &[&str]) -> Result<Self> {
        crate::instruments::fail::step("eglCreateContext (headless GL)")?;
        let devices: Vec<egl::device::Device> = egl::device::Device::query_devices()
            .context("EGL cannot list devices (EGL_EXT_device_enumeration): install libegl1 with Mesa's or the GPU vendor's EGL")?
            .collect();
        let mut fallback = None;
        let mut errors = Vec::new();
        for (index, device) in devices.iter().enumerate() {
            let label = match (device.name(), device.vendor()) {
                (Some(name), _) | (None, Some(name)) => name.to_owned(),
                _ if device.extensions().contains("EGL_MESA_device_software") => "Mesa software".to_owned(),
                _ => format!("#{index}"),
            };
            match Self::on_device(device, required) {
                Ok(context) if context.device_uuid == vulkan.device_uuid => {
                    eprintln!("gl: using {} (EGL device {label})", context.renderer);
                    return Ok(context);
                }
                Ok(context) => {
                    eprintln!(
                        "gl: EGL device {label} ({}) is not Vulkan's {}",
                        context.renderer, vulkan.name
                    );
                    fallback.get_or_insert(index);
                }
                Err(error) => {
                    eprintln!("gl: skipping EGL device {label}: {error:#}");
                    errors.push(format!("{label}: {error:#}"));
                }
            }
        }
        match fallback {
            // The probe's context is gone; make a fresh one current for the chapter to report on.
            Some(index) => Self::on_device(&devices[index], required),
            None if errors.is_empty() => {
                bail!("EGL lists no devices: install Mesa's EGL (libegl-mesa0) or a GPU driver")
            }
            None => bail!("no EGL device can run this chapter:\n  {}", errors.join("\n  ")),
        }
    }

    fn on_device(device: &egl::device::Device, required: &[&str]) -> Result<Self> {
        // SAFETY: the device comes from eglQueryDevicesEXT; no native display is involved.
        let display =
            unsafe { egl::display::Display::with_device(device, None) }.context("eglGetPlatformDisplay")?;
        // Device displays have no window surfaces: ask for any surface type, or nothing matches.
        let template = ConfigTemplateBuilder::new().with_surface_type(ConfigSurfaceTypes::empty()).build();
        let config = unsafe { display.find_configs(template) }?.next().context("no EGL config")?;
        let attributes = ContextAttributesBuilder::new()
            .with_context_api(ContextApi::OpenGl(Some(Version::new(4, 5))))
            .with_profile(GlProfile::Core)
            .with_debug(true)
            .build(None);
        let context =
            unsafe { display.create_context(&config, &attributes) }.context("a GL 4.5 core context")?;
        let context = context.make_current_surfaceless().context("eglMakeCurrent without a surface")?;
        let loader = |name: &CStr| display.get_proc_address(name);
        Self::new(PossiblyCurrentContext::Egl(context), &loader, required)
    }
    // ANCHOR_END: headless

    /// Wraps a context that is already current (headless here, or a window's in chapter 04).
    pub fn new(
        context: PossiblyCurrentContext,
        loader: &dyn Fn(&CStr) -> *const c_void,
        required: &[&str],
    ) -> Result<Self> {
        // SAFETY: the context is current on this thread and `loader` resolves its functions.
        let mut gl = unsafe { glow::Context::from_loader_function_cstr(|name| loader(name)) };
        let hidden = hidden_extensions();
        let extensions: HashSet<String> =
            gl.supported_extensions().iter().filter(|e| !hidden.contains(e)).cloned().collect();
        let (renderer, version) =
            unsafe { (gl.get_parameter_string(glow::RENDERER), gl.get_parameter_string(glow::VERSION)) };
        let missing: Vec<&str> = required.iter().copied().filter(|e| !extensions.contains(*e)).collect();
        if !missing.is_empty() {
            let hint = if missing.iter().any(|e| e.contains("semaphore")) {
                "GL_EXT_semaphore_fd: NVIDIA, AMD and Intel GL drivers have it; llvmpipe does not"
            } else {
                "GL_EXT_memory_object_fd: Mesa >= 21 (llvmpipe too) and NVIDIA's GL have it"
            };
            let hidden_note = if missing.iter().any(|e| hidden.iter().any(|h| h == e)) {
                " (some hidden by VKGL_HIDE_EXTENSIONS)"
            } else {
                ""
            };
            bail!("{renderer} (GL {version}) lacks {}{hidden_note}\n  {hint}", missing.join(", "));
        }
        enable_debug_output(&mut gl);
        let memory = if MEMORY_EXTENSIONS.iter().all(|e| extensions.contains(*e)) {
            Some(MemoryObjectFns::load(loader)?)
        } else {
            None
        };
        let semaphores = if SEMAPHORE_EXTENSIONS.iter().all(|e| extensions.contains(*e)) {
            Some(SemaphoreFns::load(loader)?)
        } else {
            None
        };
        let mut device_uuid = [0; UUID_SIZE_EXT];
        let mut driver_uuid = [0; UUID_SIZE_EXT];
        // ANCHOR: gl_uuids
        if let Some(m) = &memory {
            // SAFETY: both queries write exactly GL_UUID_SIZE_EXT bytes.
            unsafe {
                (m.GetUnsignedBytei_vEXT)(DEVICE_UUID_EXT, 0, device_uuid.as_mut_ptr());
                (m.GetUnsignedBytevEXT)(DRIVER_UUID_EXT, driver_uuid.as_mut_ptr());
            }
        }
        // ANCHOR_END: gl_uuids
        Ok(GlContext {
            gl: std::rc::Rc::new(gl),
            memory,
            semaphores,
            renderer,
            version,
            device_uuid,
            driver_uuid,
            required: required.iter().map(|e| e.to_string()).collect(),
            extensions,
            is: IsFns::load(loader)?,
            context,
        })
    }

    // ANCHOR: live_objects
    /// How many GL objects of each kind exist now, as the driver sees them: `glIs*` over every
    /// name up to the highest in use (found by making, then deleting, one more of each kind).
    /// The leak soak compares this before and after, with no bookkeeping of ours in between.
    pub fn live_objects(&self) -> std::collections::BTreeMap<&'static str, usize> {
        let gl = &*self.gl;
        let count = |next: u32, is: &dyn Fn(u32) -> u8| {
            (1..next.max(PROBED_NAMES)).filter(|&name| is(name) == glow::TRUE).count()
        };
        let mut live = std::collections::BTreeMap::new();
        // Each kind: make one (the name it gets is one past the highest in use, or a freed one),
        // delete it, and ask GL which names below that are objects of the kind.
        macro_rules! census {
            ($kind:literal, $create:expr, $delete:ident, $is:ident) => {{
                let made = $create;
                let next = made.as_ref().map_or(0, |object| object.0.get());
                made.into_iter().for_each(|object| gl.$delete(object));
                live.insert($kind, count(next, &|name| (self.is.$is)(name)));
            }};
        }
        unsafe {
            census!("gl_textures", gl.create_named_texture(glow::TEXTURE_2D), delete_texture, IsTexture);
            census!("gl_buffers", gl.create_named_buffer(), delete_buffer, IsBuffer);
            census!("gl_framebuffers", gl.create_named_framebuffer(), delete_framebuffer, IsFramebuffer);
            census!("gl_renderbuffers", gl.create_renderbuffer(), delete_renderbuffer, IsRenderbuffer);
            census!("gl_vertex_arrays", gl.create_named_vertex_array(), delete_vertex_array, IsVertexArray);
            census!("gl_programs", gl.create_program(), delete_program, IsProgram);
            census!("gl_queries", gl.create_query(), delete_query, IsQuery);
            if let Some(ext) = &self.memory {
                let mut n = 0;
                (ext.CreateMemoryObjectsEXT)(1, &mut n);
                (ext.DeleteMemoryObjectsEXT)(1, &n);
                live.insert("gl_memory_objects", count(n, &|name| (ext.IsMemoryObjectEXT)(name)));
            }
            if let Some(ext) = &self.semaphores {
                let mut n = 0;
                (ext.GenSemaphoresEXT)(1, &mut n);
                (ext.DeleteSemaphoresEXT)(1, &n);
                live.insert("gl_semaphores", count(n, &|name| (ext.IsSemaphoreEXT)(name)));
            }
        }
        live
    }
    // ANCHOR_END: live_objects

    pub fn has_extension(&self, name: &str) -> bool {
        self.extensions.contains(name)
    }

    /// The memory-object functions; an error when the chapter did not require them.
    pub fn memory_fns(&self) -> Result<&MemoryObjectFns> {
        self.memory.as_ref().context("GL_EXT_memory_object_fd was not required by this chapter")
    }

    /// The glutin context, for swapping buffers in a window.
    pub fn context(&self) -> &PossiblyCurrentContext {
        &self.context
    }

    /// The `gl` section of the chapter report.
    pub fn report(&self) -> crate::instruments::report::GlReport {
        crate::instruments::report::GlReport {
            renderer: self.renderer.clone(),
            version: self.version.clone(),
            device_uuid: crate::instruments::report::uuid_hex(&self.device_uuid),
            driver_uuid: crate::instruments::report::uuid_hex(&self.driver_uuid),
            extensions: self.required.clone(),
        }
    }

    /// Fails with the first error GL has recorded, naming `what` was being done.
    pub fn check_error(&self, what: &str) -> Result<()> {
        let error = unsafe { self.gl.get_error() };
        if error != glow::NO_ERROR {
            bail!("{what}: GL error {error:#06x} ({})", error_name(error));
        }
        Ok(())
    }
}

/// Do GL and Vulkan report the same device and driver UUIDs? (The report's `uuids_match`.)
pub fn uuids_match(vulkan: &DeviceInfo, gl: &GlContext) -> bool {
    vulkan.device_uuid == gl.device_uuid && vulkan.driver_uuid == gl.driver_uuid
}

// ANCHOR: same_device
/// GL and Vulkan must run on the same device and driver: an OPAQUE_FD handle means something
/// only to the driver that made it. On a laptop with two GPUs, GL may well run on the other one.
pub fn ensure_same_device(vulkan: &DeviceInfo, gl: &GlContext) -> Result<()> {
    let hex = crate::instruments::report::uuid_hex;
    if !uuids_match(vulkan, gl) {
        bail!(
            "GL and Vulkan run on different devices or drivers, so they cannot share memory:\n  \
             Vulkan: {} device {} driver {}\n  GL: {} device {} driver {}\n  \
             fix: make both use one GPU (e.g. __EGL_VENDOR_LIBRARY_FILENAMES / VK_DRIVER_FILES, or \
             PRIME offload variables on a laptop)",
            vulkan.name,
            hex(&vulkan.device_uuid),
            hex(&vulkan.driver_uuid),
            gl.renderer,
            hex(&gl.device_uuid),
            hex(&gl.driver_uuid),
        );
    }
    Ok(())
}
// ANCHOR_END: same_device

/// For the resize census (`instruments::census::ResizeCensus`): GL's own count.
impl crate::instruments::census::LiveObjects for GlContext {
    fn live_objects(&self) -> std::collections::BTreeMap<&'static str, usize> {
        GlContext::live_objects(self)
    }
}
