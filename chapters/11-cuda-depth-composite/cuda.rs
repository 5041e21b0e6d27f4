//! Chapter 11's CUDA side: the kernel, launched through the driver API, and the two ways its
//! output reaches GL: a registered GL pixel buffer object (path 1) and Vulkan memory imported
//! into CUDA (path 2).

use crate::scene::TraceParams;
use anyhow::{Context as _, Result, ensure};
use common::base::fail;
use common::interop::cuda::{CudaDevice, cu, sys};
use std::ffi::{CString, c_void};
use std::os::fd::{AsRawFd, IntoRawFd, OwnedFd};

/// The kernel, compiled to PTX by `cargo run -p xtask -- cuda`; the driver compiles it for the
/// GPU it finds when the module loads.
const PTX: &str = include_str!("../../shaders/cuda/trace.ptx");

/// The kernel, loaded, with a stream to launch it on and two events to time it.
pub struct CudaTracer {
    pub device: CudaDevice,
    module: sys::CUmodule,
    function: sys::CUfunction,
    pub stream: sys::CUstream,
    started: sys::CUevent,
    finished: sys::CUevent,
}

impl CudaTracer {
    // ANCHOR: load
    pub fn new(device: CudaDevice) -> Result<Self> {
        let ptx = CString::new(PTX)?;
        // SAFETY: `ptx` is NUL-terminated PTX text; CUDA copies what it needs.
        let module =
            match fail::call("cuModuleLoadData", || unsafe { cu::module::load_data(ptx.as_ptr().cast()) }) {
                Ok(module) => module,
                Err(error) => {
                    device.destroy()?;
                    return Err(error).context(
                    "cuModuleLoadData: the driver cannot compile the PTX (it came from NVRTC 12.9: drivers \
                     older than CUDA 12.9 refuse it; fix: update the NVIDIA driver)",
                );
                }
            };
        let rest = || -> Result<_> {
            let name = CString::new("trace")?;
            let function = fail::call("cuModuleGetFunction(trace)", || unsafe {
                cu::module::get_function(module, name)
            })?;
            // Non-blocking: this stream never waits for work on the legacy default stream.
            let stream =
                fail::call("cuStreamCreate", || cu::stream::create(cu::stream::StreamKind::NonBlocking))?;
            let event =
                || fail::call("cuEventCreate", || cu::event::create(sys::CUevent_flags::CU_EVENT_DEFAULT));
            Ok((function, stream, event()?, event()?))
        };
        match rest() {
            Ok((function, stream, started, finished)) => {
                Ok(CudaTracer { device, module, function, stream, started, finished })
            }
            // Rare enough (out of resources) that a stream or event made before the failure is
            // left to the context's release, which frees everything made in it.
            Err(error) => {
                unsafe { cu::module::unload(module) }.ok();
                device.destroy()?;
                Err(error)
            }
        }
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
            fail::call("cuEventRecord (start)", || cu::event::record(self.started, self.stream))?;
            fail::call("cuLaunchKernel(trace)", || {
                cu::launch_kernel(self.function, grid, (16, 16, 1), 0, self.stream, &mut arguments)
            })?;
            fail::call("cuEventRecord (end)", || cu::event::record(self.finished, self.stream))?;
        }
        Ok(())
    }
    // ANCHOR_END: launch

    /// Waits for the last launch, and returns how long the GPU ran it.
    pub fn kernel_ms(&self) -> Result<f64> {
        unsafe {
            fail::call("cuEventSynchronize", || cu::event::synchronize(self.finished))?;
            Ok(fail::call("cuEventElapsedTime", || cu::event::elapsed(self.started, self.finished))? as f64)
        }
    }

    /// Blocks this thread until everything queued on the stream has run.
    pub fn synchronize(&self) -> Result<()> {
        fail::call("cuStreamSynchronize", || unsafe { cu::stream::synchronize(self.stream) })
    }

    /// Everything made in the context, newest first, then the context itself.
    pub fn destroy(self) -> Result<()> {
        self.synchronize()?;
        unsafe {
            cu::event::destroy(self.finished)?;
            cu::event::destroy(self.started)?;
            cu::stream::destroy(self.stream)?;
            cu::module::unload(self.module)?;
        }
        self.device.destroy()
    }
}

// ANCHOR: registered_pbo
/// Path 1: GL's pixel buffer object, registered with CUDA once.
pub struct RegisteredPbo {
    resource: sys::CUgraphicsResource,
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
        unsafe {
            fail::call("cuGraphicsMapResources", || {
                sys::cuGraphicsMapResources(1, &mut self.resource, tracer.stream).result()
            })?;
            let (mut pointer, mut size) = (0, 0);
            let mapped = fail::call("cuGraphicsResourceGetMappedPointer", || {
                sys::cuGraphicsResourceGetMappedPointer_v2(&mut pointer, &mut size, self.resource).result()
            });
            let launched = mapped.and_then(|()| {
                ensure!(size as u64 >= bytes, "the mapped PBO holds {size} bytes, not {bytes}");
                tracer.launch(pointer, params)
            });
            // Unmapped even when the launch failed: a mapped buffer cannot be deleted by GL. (Like
            // every call that gives something back, not a step `VKGL_FAIL_AT` fails.)
            sys::cuGraphicsUnmapResources(1, &mut self.resource, tracer.stream)
                .result()
                .context("cuGraphicsUnmapResources")?;
            launched.map(|()| pointer)
        }
    }
}

impl Drop for RegisteredPbo {
    /// Unregistered before GL deletes the buffer it names (its owner drops it later), once
    /// CUDA's work is done. A failure is printed, and the registration stays counted alive, which
    /// the chapter's `cuda_and_shared_resources_released` check then reports.
    fn drop(&mut self) {
        let released =
            unsafe { sys::cuCtxSynchronize().result().context("cuCtxSynchronize") }.and_then(|()| {
                unsafe { sys::cuGraphicsUnregisterResource(self.resource) }
                    .result()
                    .context("cuGraphicsUnregisterResource")
            });
        match released {
            Ok(()) => common::base::resources::destroyed("cuda_graphics_resource"),
            Err(error) => eprintln!("cuda: {error:#}"),
        }
    }
}
// ANCHOR_END: registered_pbo

// ANCHOR: imported_memory
/// Path 2: Vulkan's exportable memory, seen by CUDA as a device pointer.
pub struct ImportedMemory {
    external: sys::CUexternalMemory,
    pub pointer: sys::CUdeviceptr,
}

impl ImportedMemory {
    /// `size` is Vulkan's `allocationSize`; `bytes` how much of it to map, from offset 0.
    pub fn new(fd: OwnedFd, size: u64, bytes: u64) -> Result<Self> {
        // OPAQUE_FD, as Vulkan exported it. On success CUDA owns the fd (and closes it when the
        // external memory is destroyed); on failure it is still ours, and `fd` closes it.
        let external = fail::call("cuImportExternalMemory(OPAQUE_FD)", || unsafe {
            cu::external_memory::import_external_memory_opaque_fd(fd.as_raw_fd(), size)
        })?;
        // SAFETY: the import succeeded: the fd is CUDA's now, and closing it too would be a double close.
        let _ = fd.into_raw_fd();
        common::base::resources::created("cuda_external_memory", 0); // its bytes are Vulkan's allocation
        let mapped = fail::call("cuExternalMemoryGetMappedBuffer", || unsafe {
            cu::external_memory::get_mapped_buffer(external, 0, bytes)
        });
        match mapped {
            Ok(pointer) => Ok(ImportedMemory { external, pointer }),
            Err(error) => {
                unsafe { cu::external_memory::destroy_external_memory(external) }.ok();
                common::base::resources::destroyed("cuda_external_memory");
                Err(error)
            }
        }
    }
}

impl Drop for ImportedMemory {
    /// Once CUDA's work is done, the mapping is freed like any device allocation, then the
    /// external memory destroyed: before Vulkan frees the allocation under it (its owner is
    /// dropped later). A failure is printed, and the memory stays counted alive.
    fn drop(&mut self) {
        let released = unsafe {
            sys::cuCtxSynchronize()
                .result()
                .context("cuCtxSynchronize")
                .and_then(|()| cu::memory_free(self.pointer).context("cuMemFree"))
                .and_then(|()| {
                    cu::external_memory::destroy_external_memory(self.external)
                        .context("cuDestroyExternalMemory")
                })
        };
        match released {
            Ok(()) => common::base::resources::destroyed("cuda_external_memory"),
            Err(error) => eprintln!("cuda: {error:#}"),
        }
    }
}
// ANCHOR_END: imported_memory
