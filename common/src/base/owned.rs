//! A Vulkan (or CUDA) object that destroys itself (taught in chapter 01): the twin of
//! `base::gl::Owned`. Every Vulkan and CUDA object the chapters and `common` make is held by one
//! from the moment it exists, so an early return (`?`) destroys what was made, and a struct of
//! them drops them in the order its fields are written. (CUDA's kinds: `interop::cuda`.)

use crate::instruments::fail;
use crate::instruments::resources::Counted;
use anyhow::Result;
use ash::vk;

// ANCHOR: owned
/// A Vulkan handle and what destroys it (the device, or an extension's loader): dropped, it
/// makes its own `vkDestroy*` / `vkFree*` call, so a buffer cannot be destroyed as an image.
/// `*owned` is the handle, for Vulkan calls. The GPU must be done with it when it is dropped
/// (the book's "Waiting before teardown" says when that is).
pub struct Owned<T: Destroy> {
    handle: T,
    by: T::By,
    /// Its count in `instruments::resources`, for the kinds counted there (see [`Owned::counted`]).
    counted: Option<Counted>,
}

/// A kind of handle, and the call that destroys it.
pub trait Destroy: Copy {
    /// What makes the call: `ash::Device`, or the loader of the extension the handle comes from
    /// (`()` for CUDA's, whose calls need nothing but the current context).
    type By: Clone;
    /// # Safety
    /// `self` was made by `by`, is not in use by the GPU, and nothing uses it afterwards.
    unsafe fn destroy(self, by: &Self::By);
}

/// Makes a Vulkan object with `create`, as one fallible step whose error names `what`
/// (`"vkCreateBuffer for the vertex buffer"`), and owns it from then on.
pub fn create<T: Destroy, E>(
    by: &T::By,
    what: &str,
    create: impl FnOnce() -> std::result::Result<T, E>,
) -> Result<Owned<T>>
where
    E: std::fmt::Display + std::fmt::Debug + Send + Sync + 'static,
{
    let handle = fail::call(what, create)?;
    Ok(Owned { handle, by: by.clone(), counted: None })
}

impl<T: Destroy> Owned<T> {
    /// Counted in `instruments::resources` as one `kind` holding `bytes`, until it is destroyed.
    pub fn counted(mut self, kind: &str, bytes: u64) -> Self {
        self.counted = Some(crate::instruments::resources::count(kind, bytes));
        self
    }
}

impl<T: Destroy> Drop for Owned<T> {
    fn drop(&mut self) {
        // SAFETY: made by `create` with `by`, and owned by nothing else; the GPU is done with it
        // (the caller's promise, kept by waiting before teardown).
        unsafe { self.handle.destroy(&self.by) };
        // `counted`, a field, is dropped next: the count goes with the object.
    }
}
// ANCHOR_END: owned

impl<T: Destroy + std::fmt::Debug> std::fmt::Debug for Owned<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        self.handle.fmt(f)
    }
}

impl<T: Destroy> std::ops::Deref for Owned<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.handle
    }
}

macro_rules! destroyed_by_device {
    ($($ty:ident => $destroy:ident),* $(,)?) => {
        $(impl Destroy for vk::$ty {
            type By = ash::Device;
            unsafe fn destroy(self, device: &ash::Device) {
                unsafe { device.$destroy(self, None) }
            }
        })*
    };
}

// ANCHOR: destroy_table
// Every kind of Vulkan object this book makes, and the call that destroys it. (Command buffers
// and descriptor sets go with their pools; the device and the instance with `VulkanContext`.)
destroyed_by_device! {
    Buffer => destroy_buffer,
    Image => destroy_image,
    ImageView => destroy_image_view,
    DeviceMemory => free_memory, // unmapped too, if it is mapped
    Semaphore => destroy_semaphore,
    Fence => destroy_fence,
    CommandPool => destroy_command_pool,
    ShaderModule => destroy_shader_module,
    DescriptorSetLayout => destroy_descriptor_set_layout,
    DescriptorPool => destroy_descriptor_pool,
    PipelineLayout => destroy_pipeline_layout,
    Pipeline => destroy_pipeline,
    QueryPool => destroy_query_pool,
    Sampler => destroy_sampler,
}

impl Destroy for vk::AccelerationStructureKHR {
    type By = ash::khr::acceleration_structure::Device;
    unsafe fn destroy(self, loader: &Self::By) {
        unsafe { loader.destroy_acceleration_structure(self, None) }
    }
}
// ANCHOR_END: destroy_table
