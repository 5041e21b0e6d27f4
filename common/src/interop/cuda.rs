//! CUDA beside Vulkan and GL (taught in chapter 11): finding the NVIDIA driver and the CUDA
//! device that GL and Vulkan run on, and the one `cudaGL.h` entry point that the `cudarc`
//! bindings (which cover `cuda.h` only) lack: `cuGraphicsGLRegisterBuffer`.
//!
//! Everything is loaded at run time: a machine without CUDA builds and runs the chapters, and
//! learns from [`Unavailable`] what is missing.

pub use crate::base::owned::Destroy;
use crate::base::owned::{Owned, create};
use crate::instruments::fail;
use anyhow::Result;
pub use cudarc::driver::{result as cu, sys};
use std::fmt;

/// The NVIDIA driver's CUDA library: the only CUDA file a CUDA program needs at run time (the
/// driver JIT-compiles our PTX). `cudarc` opens it under the same name.
pub const DRIVER_LIBRARY: &str = "libcuda.so.1";

/// CUDA cannot run here, and why: no driver, no device, or no device that is GL's.
#[derive(Debug)]
pub struct Unavailable(pub String);

impl fmt::Display for Unavailable {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Unavailable {}

// ANCHOR: register_buffer_fn
/// `cuGraphicsGLRegisterBuffer` (cudaGL.h): lets CUDA map a GL buffer object. `buffer` is the
/// GL name (a GLuint); `flags` a `CUgraphicsRegisterFlags`.
type RegisterBuffer =
    unsafe extern "C" fn(resource: *mut sys::CUgraphicsResource, buffer: u32, flags: u32) -> sys::CUresult;

/// The GL half of CUDA's graphics interop, loaded from the driver by hand.
pub struct GlInterop {
    register_buffer: RegisterBuffer,
    // Keeps libcuda loaded for as long as the function pointer may be called.
    _library: libloading::Library,
}

impl GlInterop {
    fn load() -> Result<Self, Unavailable> {
        // For tests on a machine that has CUDA: behave as if it had none.
        if std::env::var_os("VKGL_HIDE_CUDA").is_some() {
            return Err(Unavailable(format!("{DRIVER_LIBRARY} hidden by VKGL_HIDE_CUDA")));
        }
        // SAFETY: the driver's initialisers have no preconditions.
        let library = unsafe { libloading::Library::new(DRIVER_LIBRARY) }.map_err(|error| {
            Unavailable(format!(
                "{DRIVER_LIBRARY} not found: no NVIDIA driver is installed ({error}); fix: install the \
                 NVIDIA driver, or run with --tracer cpu"
            ))
        })?;
        // SAFETY: the signature is cudaGL.h's.
        let register_buffer = unsafe { library.get::<RegisterBuffer>(b"cuGraphicsGLRegisterBuffer\0") }
            .map(|symbol| *symbol)
            .map_err(|error| {
                Unavailable(format!("{DRIVER_LIBRARY} lacks cuGraphicsGLRegisterBuffer: {error}"))
            })?;
        Ok(GlInterop { register_buffer, _library: library })
    }

    /// Registers a GL buffer with CUDA (with the CUDA context current, and GL's current on this
    /// thread). Dropped, it is unregistered: before GL deletes the buffer.
    pub fn register_buffer(
        &self,
        buffer: glow::Buffer,
        flags: sys::CUgraphicsRegisterFlags,
    ) -> Result<Owned<sys::CUgraphicsResource>> {
        let mut resource = std::ptr::null_mut();
        // SAFETY: `buffer` is a live GL buffer of the current GL context.
        let resource = create(&(), "cuGraphicsGLRegisterBuffer", || unsafe {
            (self.register_buffer)(&mut resource, buffer.0.get(), flags as u32).result().map(|()| resource)
        })?;
        crate::instruments::resources::created("cuda_graphics_resource", 0);
        Ok(resource)
    }
}
// ANCHOR_END: register_buffer_fn

/// The CUDA device that is also Vulkan's and GL's, its primary context current on this thread
/// and released when dropped (after everything made in it).
pub struct CudaDevice {
    pub context: Owned<PrimaryContext>,
    pub name: String,
    pub compute_capability: (i32, i32),
    pub gl: GlInterop,
}

impl CudaDevice {
    // ANCHOR: open
    /// Finds the CUDA device whose UUID is `device_uuid` (Vulkan's `deviceUUID`, which GL's
    /// `GL_DEVICE_UUID_EXT` matched) and makes its primary context current. Fails with
    /// [`Unavailable`] when there is no driver, no device, or none of them is that one.
    pub fn open(device_uuid: &[u8; 16]) -> Result<Self> {
        let gl = GlInterop::load()?;
        // An injected failure is an error; a real one says CUDA cannot run here.
        fail::step("cuInit")?;
        cu::init().map_err(|error| {
            Unavailable(format!("cuInit failed: {error} (the NVIDIA driver found no usable GPU)"))
        })?;
        let count = fail::call("cuDeviceGetCount", cu::device::get_count)?;
        let mut seen = Vec::new();
        for ordinal in 0..count {
            let device = fail::call("cuDeviceGet", || cu::device::get(ordinal))?;
            let name = fail::call("cuDeviceGetName", || cu::device::get_name(device))?;
            let uuid = fail::call("cuDeviceGetUuid", || cu::device::get_uuid(device))?.bytes.map(|b| b as u8);
            if &uuid != device_uuid {
                seen.push(format!("{name} ({})", crate::instruments::report::uuid_hex(&uuid)));
                continue;
            }
            use sys::CUdevice_attribute::*;
            let attribute =
                |a| fail::call("cuDeviceGetAttribute", || unsafe { cu::device::get_attribute(device, a) });
            let compute_capability = (
                attribute(CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MAJOR)?,
                attribute(CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_MINOR)?,
            );
            // The primary context: the one the CUDA runtime would use too, shared per device.
            let context = create(&(), "cuDevicePrimaryCtxRetain", || unsafe {
                cu::primary_ctx::retain(device).map(|context| PrimaryContext { device, context })
            })?;
            fail::call("cuCtxSetCurrent", || unsafe { cu::ctx::set_current(context.context) })?;
            return Ok(CudaDevice { context, name, compute_capability, gl });
        }
        Err(Unavailable(format!(
            "none of the {count} CUDA device(s) is the Vulkan/GL device {}: {seen:?}",
            crate::instruments::report::uuid_hex(device_uuid)
        ))
        .into())
    }
    // ANCHOR_END: open
}

/// A device's primary context, retained: released when dropped.
#[derive(Clone, Copy)]
pub struct PrimaryContext {
    pub device: sys::CUdevice,
    pub context: sys::CUcontext,
}

/// Memory CUDA mapped from imported external memory: freed like any device allocation.
#[derive(Clone, Copy)]
pub struct MappedPointer(pub sys::CUdeviceptr);

/// A failed CUDA release is printed and otherwise ignored: on the way out there is no one to
/// hand it to. (Those counted in `instruments::resources` then stay counted alive, which a check reports.)
fn released(what: &str, result: Result<(), cu::DriverError>) -> bool {
    result.map_err(|error| eprintln!("cuda: {what}: {error}")).is_ok()
}

// ANCHOR: destroy_table
// CUDA's objects in this book, and the call that releases each. None waits for CUDA's work: the
// chapter synchronizes once, before its teardown, as it waits for Vulkan and GL.
impl Destroy for PrimaryContext {
    type By = ();
    unsafe fn destroy(self, _: &()) {
        unsafe {
            released("cuCtxSetCurrent(NULL)", cu::ctx::set_current(std::ptr::null_mut()));
            released("cuDevicePrimaryCtxRelease", cu::primary_ctx::release(self.device));
        }
    }
}

/// CUDA objects that one call frees, its failure logged (a `Drop` cannot return it).
macro_rules! destroyed_by {
    ($($handle:ty => $name:literal, $call:path;)*) => {$(
        impl Destroy for $handle {
            type By = ();
            unsafe fn destroy(self, _: &()) {
                released($name, unsafe { $call(self) });
            }
        }
    )*};
}

destroyed_by! {
    sys::CUmodule => "cuModuleUnload", cu::module::unload;
    sys::CUstream => "cuStreamDestroy", cu::stream::destroy;
    sys::CUevent => "cuEventDestroy", cu::event::destroy;
}

impl Destroy for sys::CUgraphicsResource {
    type By = ();
    unsafe fn destroy(self, _: &()) {
        let result = unsafe { sys::cuGraphicsUnregisterResource(self) }.result();
        if released("cuGraphicsUnregisterResource", result) {
            crate::instruments::resources::destroyed("cuda_graphics_resource");
        }
    }
}

impl Destroy for sys::CUexternalMemory {
    type By = ();
    unsafe fn destroy(self, _: &()) {
        let result = unsafe { cu::external_memory::destroy_external_memory(self) };
        if released("cuDestroyExternalMemory", result) {
            crate::instruments::resources::destroyed("cuda_external_memory");
        }
    }
}

impl Destroy for MappedPointer {
    type By = ();
    unsafe fn destroy(self, _: &()) {
        released("cuMemFree", unsafe { cu::memory_free(self.0) });
    }
}
// ANCHOR_END: destroy_table

/// Is `error` (or anything in its chain) CUDA saying it cannot run here?
pub fn unavailable(error: &anyhow::Error) -> Option<&Unavailable> {
    error.chain().find_map(|e| e.downcast_ref::<Unavailable>())
}
