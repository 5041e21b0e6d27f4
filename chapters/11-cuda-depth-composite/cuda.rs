//! Chapter 11's CUDA side: the kernel, launched through the driver API, and the two ways its
//! output reaches GL: a registered GL pixel buffer object (path 1) and Vulkan memory imported
//! into CUDA (path 2).

use crate::scene::TraceParams;
use anyhow::{Context as _, Result, ensure};
use common::base::owned::{Owned, create};
use common::instruments::fail;
use common::interop::cuda::{CudaDevice, MappedPointer, cu, sys};
use std::ffi::{CString, c_void};
use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};

/// The kernel, compiled to PTX by `cargo run -p xtask -- cuda`; the driver compiles it for the
/// GPU it finds when the module loads.
const PTX: &str = include_str!("../../shaders/cuda/trace.ptx");

/// The kernel, loaded, with a stream to launch it on and two events to time it. Dropped, its
/// fields go in the order written: the events, the stream, the module, then the context they
/// were made in. CUDA must be done with them (see [`CudaTracer::synchronize`]).
pub struct CudaTracer {
    started: Owned<sys::CUevent>,
    finished: Owned<sys::CUevent>,
    pub stream: Owned<sys::CUstream>,
    function: sys::CUfunction,
    _module: Owned<sys::CUmodule>,
    pub device: CudaDevice,
}

impl CudaTracer {
    // ANCHOR: load
    /// Each object is owned as it is made: a failure drops what exists, `device` last.
    pub fn new(device: CudaDevice) -> Result<Self> {
        let ptx = CString::new(PTX)?;
        // SAFETY: `ptx` is NUL-terminated PTX text; CUDA copies what it needs.
        let module =
            create(&(), "cuModuleLoadData", || unsafe { cu::module::load_data(ptx.as_ptr().cast()) })
                .context(
                    "cuModuleLoadData: the driver cannot compile the PTX (it came from NVRTC 12.9: drivers \
                 older than CUDA 12.9 refuse it; fix: update the NVIDIA driver)",
                )?;
        let name = CString::new("trace")?;
        let function =
            fail::call("cuModuleGetFunction(trace)", || unsafe { cu::module::get_function(*module, name) })?;
        // Non-blocking: this stream never waits for work on the legacy default stream.
        let stream =
            create(&(), "cuStreamCreate", || cu::stream::create(cu::stream::StreamKind::NonBlocking))?;
        let event =
            || create(&(), "cuEventCreate", || cu::event::create(sys::CUevent_flags::CU_EVENT_DEFAULT));
        let (started, finished) = (event()?, event()?);
        Ok(CudaTracer { started, finished, stream, function, _module: module, device })
    }
    // ANCHOR_END: load

    // ANCHOR: launch
    /// Queues the kernel on the stream: one thread per pixel, 16 x 16 per block, writing
    /// `params.width * params.height` colours and as many distances at `traced`.
    pub fn launch(&self, traced: sys::CUdeviceptr, params: &TraceParams) -> Result<()> {
        let (mut traced, mut params) = (traced, *params);
        // cuLaunchKernel takes a pointer to each argument, in the kernel's order.
        let mut arguments: [*mut c_void; 2] = [(&raw mut traced).cast(), (&raw mut params).cast()];
        let grid = (params.width.div_ceil(16), params.height.div_ceil(16), 1);
        unsafe {
            fail::call("cuEventRecord (start)", || cu::event::record(*self.started, *self.stream))?;
            fail::call("cuLaunchKernel(trace)", || {
                cu::launch_kernel(self.function, grid, (16, 16, 1), 0, *self.stream, &mut arguments)
            })?;
            fail::call("cuEventRecord (end)", || cu::event::record(*self.finished, *self.stream))?;
        }
        Ok(())
    }
    // ANCHOR_END: launch

    /// Waits for the last launch, and returns how long the GPU ran it.
    pub fn kernel_ms(&self) -> Result<f64> {
        unsafe {
            fail::call("cuEventSynchronize", || cu::event::synchronize(*self.finished))?;
            Ok(fail::call("cuEventElapsedTime", || cu::event::elapsed(*self.started, *self.finished))? as f64)
        }
    }

    /// Blocks this thread until everything queued on the stream has run: the chapter's one wait
    /// for CUDA before its teardown.
    pub fn synchronize(&self) -> Result<()> {
        fail::call("cuStreamSynchronize", || unsafe { cu::stream::synchronize(*self.stream) })
    }
}

/// CUDA's counterpart of `Commands`' wait on drop: made after everything the kernel uses, so
/// that on an early return it is dropped first, and waits for the stream before any of it goes.
pub struct StreamDrained<'a>(pub &'a CudaTracer);

impl Drop for StreamDrained<'_> {
    fn drop(&mut self) {
        let _ = unsafe { cu::stream::synchronize(*self.0.stream) };
    }
}

// ANCHOR: registered_pbo
/// Path 1: GL's pixel buffer object, registered with CUDA once; unregistered when dropped,
/// before GL deletes the buffer it names (its owner drops it later).
pub struct RegisteredPbo {
    resource: Owned<sys::CUgraphicsResource>,
}

impl RegisteredPbo {
    pub fn new(tracer: &CudaTracer, pbo: glow::Buffer) -> Result<Self> {
        // WRITE_DISCARD: CUDA only writes it, and overwrites all of it, so the driver need not
        // keep GL's contents when CUDA maps it.
        let flags = sys::CUgraphicsRegisterFlags::CU_GRAPHICS_REGISTER_FLAGS_WRITE_DISCARD;
        Ok(RegisteredPbo { resource: tracer.device.gl.register_buffer(pbo, flags)? })
    }

    /// Map, get the pointer, launch, unmap: every frame. While mapped, GL must not touch the
    /// buffer; the unmap orders the kernel before any GL command issued after it.
    pub fn trace(
        &mut self,
        tracer: &CudaTracer,
        params: &TraceParams,
        bytes: u64,
    ) -> Result<sys::CUdeviceptr> {
        let mut resource = *self.resource;
        unsafe {
            fail::call("cuGraphicsMapResources", || {
                sys::cuGraphicsMapResources(1, &mut resource, *tracer.stream).result()
            })?;
            let (mut pointer, mut size) = (0, 0);
            let mapped = fail::call("cuGraphicsResourceGetMappedPointer", || {
                sys::cuGraphicsResourceGetMappedPointer_v2(&mut pointer, &mut size, resource).result()
            });
            let launched = mapped.and_then(|()| {
                ensure!(size as u64 >= bytes, "the mapped PBO holds {size} bytes, not {bytes}");
                tracer.launch(pointer, params)
            });
            // Unmapped even when the launch failed: a mapped buffer cannot be deleted by GL. (Like
            // every call that gives something back, not a step `VKGL_FAIL_AT` fails.)
            sys::cuGraphicsUnmapResources(1, &mut resource, *tracer.stream)
                .result()
                .context("cuGraphicsUnmapResources")?;
            launched.map(|()| pointer)
        }
    }
}

// ANCHOR_END: registered_pbo

// ANCHOR: imported_memory
/// Path 2: Vulkan's exportable memory, seen by CUDA as a device pointer. Dropped, the mapping
/// is freed like any device allocation, then the external memory destroyed (fields, in order):
/// before Vulkan frees the allocation under it (its owner is dropped later).
pub struct ImportedMemory {
    pub pointer: Owned<MappedPointer>,
    _external: Owned<sys::CUexternalMemory>,
}

impl ImportedMemory {
    /// `size` is Vulkan's `allocationSize`; `bytes` how much of it to map, from offset 0.
    pub fn new(fd: OwnedFd, size: u64, bytes: u64) -> Result<Self> {
        // OPAQUE_FD, as Vulkan exported it. On success CUDA owns the fd (and closes it when the
        // external memory is destroyed); on failure it is still ours, and `fd` closes it.
        let external = create(&(), "cuImportExternalMemory(OPAQUE_FD)", || unsafe {
            cu::external_memory::import_external_memory_opaque_fd(fd.as_raw_fd(), size)
        })?;
        // SAFETY: the import succeeded: the fd is CUDA's now, and closing it too would be a double close.
        let _ = fd.into_raw_fd();
        common::instruments::resources::created("cuda_external_memory", 0); // its bytes are Vulkan's allocation
        let pointer = create(&(), "cuExternalMemoryGetMappedBuffer", || unsafe {
            cu::external_memory::get_mapped_buffer(*external, 0, bytes).map(MappedPointer)
        })?;
        Ok(ImportedMemory { pointer, _external: external })
    }
}
// ANCHOR_END: imported_memory
