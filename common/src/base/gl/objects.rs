//! Small GL helpers every drawing chapter uses: GL objects that delete themselves, programs
//! compiled from GLSL, and an offscreen colour target.

use super::{MemoryObjectFns, SemaphoreFns};
use crate::instruments::fail;
use anyhow::{Result, bail};
use glow::HasContext;
use std::rc::Rc;

// ANCHOR: owned
/// A GL object that deletes itself when dropped, with the `glDelete*` of its own type: a texture
/// cannot be deleted as a buffer, nor a memory object as a semaphore. `*object` is the name, for
/// GL calls.
pub struct Owned<T: Object> {
    pub name: T,
    by: T::By,
    /// Its count in `instruments::resources`, for the kinds counted there (see [`Owned::counted`]).
    counted: Option<crate::instruments::resources::Counted>,
}

/// A kind of GL object, and how it is deleted.
pub trait Object: Copy {
    /// Its kind in `instruments::resources`' live counts ("gl_object: buffer").
    const KIND: &'static str;
    /// What makes the `glDelete*` call: the context for glow's kinds, the entry points loaded by
    /// hand for the `GL_EXT_memory_object` / `GL_EXT_semaphore` kinds glow does not know.
    type By: Clone;
    /// # Safety
    /// `self` is a live object of `by`'s context, and nothing uses it afterwards.
    unsafe fn delete(self, by: &Self::By);
}

/// Creates a GL object with `create`, as one fallible step whose error names `what`
/// (`"glCreateBuffers for the overlay lines"`), and owns it from then on. `by` is the context
/// (`&gl_context.gl`), or the loaded extension entry points for a memory object or semaphore.
pub fn create<B: Clone, T: Object<By = B>>(
    by: &B,
    what: &str,
    create: impl FnOnce(&B) -> std::result::Result<T, String>,
) -> Result<Owned<T>> {
    let name = fail::call(what, || create(by))?;
    crate::instruments::resources::alive(T::KIND);
    Ok(Owned { name, by: by.clone(), counted: None })
}

impl<T: Object> Owned<T> {
    /// Counted in `instruments::resources` as one `kind` holding `bytes`, until it is deleted.
    pub fn counted(mut self, kind: &str, bytes: u64) -> Self {
        self.counted = Some(crate::instruments::resources::count(kind, bytes));
        self
    }
}

/// `n` GL objects of one kind, made as one fallible step (a timer's queries).
pub fn create_n<T: Object<By = Rc<glow::Context>>>(
    gl: &Rc<glow::Context>,
    what: &str,
    n: usize,
    create: impl Fn(&glow::Context) -> std::result::Result<T, String>,
) -> Result<Vec<Owned<T>>> {
    fail::step(what)?;
    let mut made = Vec::with_capacity(n);
    for _ in 0..n {
        let name = create(gl).map_err(|error| anyhow::Error::msg(error).context(what.to_owned()))?;
        crate::instruments::resources::alive(T::KIND);
        made.push(Owned { name, by: gl.clone(), counted: None });
    }
    Ok(made)
}

impl<T: Object> Drop for Owned<T> {
    fn drop(&mut self) {
        // SAFETY: made by `create` on this context, and owned by nothing else.
        unsafe { self.name.delete(&self.by) };
        crate::instruments::resources::gone(T::KIND);
        // `counted`, a field, is dropped next: the count goes with the object.
    }
}
// ANCHOR_END: owned

impl<T: Object> std::ops::Deref for Owned<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.name
    }
}

macro_rules! objects {
    ($($ty:ident, $kind:literal => $delete:ident),* $(,)?) => {
        $(impl Object for glow::$ty {
            const KIND: &'static str = concat!("gl_object: ", $kind);
            type By = Rc<glow::Context>;
            unsafe fn delete(self, gl: &Rc<glow::Context>) {
                unsafe { gl.$delete(self) }
            }
        })*
    };
}

// glow's own types: its `glow::Buffer` ... are aliases through a trait, which Rust cannot tell apart.
objects! {
    NativeBuffer, "buffer" => delete_buffer,
    NativeTexture, "texture" => delete_texture,
    // A framebuffer bound when deleted is unbound by GL itself (as if glBindFramebuffer(0) had
    // been called): deleting one leaves no binding behind.
    NativeFramebuffer, "framebuffer" => delete_framebuffer,
    NativeRenderbuffer, "renderbuffer" => delete_renderbuffer,
    NativeVertexArray, "vertex array" => delete_vertex_array,
    NativeShader, "shader" => delete_shader,
    NativeQuery, "query" => delete_query,
    NativeFence, "fence" => delete_sync,
}

impl Object for glow::NativeProgram {
    const KIND: &'static str = "gl_object: program";
    type By = Rc<glow::Context>;
    unsafe fn delete(self, gl: &Rc<glow::Context>) {
        unsafe {
            // The program in use is only flagged for deletion: unbind it first, so that it goes
            // now, not whenever another program is bound.
            if gl.get_parameter_i32(glow::CURRENT_PROGRAM) as u32 == self.0.get() {
                gl.use_program(None);
            }
            gl.delete_program(self);
        }
    }
}

// ANCHOR: ext_objects
/// A GL memory object (`GL_EXT_memory_object`): GL's handle on an imported allocation, as
/// `VkDeviceMemory` is Vulkan's. glow has no type for it, so this is its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryObject(pub u32);

impl Object for MemoryObject {
    const KIND: &'static str = "gl_object: memory object";
    type By = MemoryObjectFns;
    unsafe fn delete(self, ext: &MemoryObjectFns) {
        // Lets go of the imported memory (and of the fd GL took with it), once no texture or
        // buffer stored in it is left.
        unsafe { (ext.DeleteMemoryObjectsEXT)(1, &self.0) }
    }
}

/// A GL semaphore (`GL_EXT_semaphore`), holding a payload imported from Vulkan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Semaphore(pub u32);

impl Object for Semaphore {
    const KIND: &'static str = "gl_semaphore";
    type By = SemaphoreFns;
    unsafe fn delete(self, ext: &SemaphoreFns) {
        unsafe { (ext.DeleteSemaphoresEXT)(1, &self.0) }
    }
}

/// A name from a `glCreate*EXT` / `glGen*EXT` call, which reports no error but leaves 0 when it
/// makes nothing.
pub fn made(name: u32, call: &str) -> std::result::Result<u32, String> {
    if name == 0 { Err(format!("{call} made no object")) } else { Ok(name) }
}
// ANCHOR_END: ext_objects

/// Compiles and links a program from GLSL sources; a failure carries GL's info log.
pub fn program(gl: &Rc<glow::Context>, vertex: &str, fragment: &str) -> Result<Owned<glow::Program>> {
    program_from(
        gl,
        &[(glow::VERTEX_SHADER, vertex, "vertex"), (glow::FRAGMENT_SHADER, fragment, "fragment")],
    )
}

/// As [`program`], with a geometry shader between the two.
pub fn program_with_geometry(
    gl: &Rc<glow::Context>,
    vertex: &str,
    geometry: &str,
    fragment: &str,
) -> Result<Owned<glow::Program>> {
    let stages = [
        (glow::VERTEX_SHADER, vertex, "vertex"),
        (glow::GEOMETRY_SHADER, geometry, "geometry"),
        (glow::FRAGMENT_SHADER, fragment, "fragment"),
    ];
    program_from(gl, &stages)
}

/// `source` with each `#include "name"` line replaced by the text of the file of that name in
/// `files`, which may include others in turn (each file once, as `#pragma once` would). GL has no
/// `#include` of its own; this lets a GL shader include a file a Vulkan shader includes through
/// glslc, so that the shared code is written once. Names are relative to `shaders/`, as glslc's
/// `-I .` resolves them.
pub fn with_includes(source: &str, files: &[(&str, &str)]) -> Result<String> {
    fn expand(text: &str, files: &[(&str, &str)], done: &mut Vec<String>, out: &mut String) -> Result<()> {
        for line in text.lines() {
            let Some(rest) = line.trim_start().strip_prefix("#include") else {
                out.push_str(line);
                out.push('\n');
                continue;
            };
            let name = rest.trim().trim_matches('"');
            let Some((_, included)) = files.iter().find(|(file, _)| *file == name) else {
                bail!("`{}` includes {name}, which the program does not pass", line.trim());
            };
            if !done.iter().any(|d| d == name) {
                done.push(name.to_string());
                expand(included, files, done, out)?;
            }
        }
        Ok(())
    }
    let mut out = String::new();
    expand(source, files, &mut Vec::new(), &mut out)?;
    Ok(out)
}

/// A program of one compute shader (chapter 12's composite).
pub fn compute_program(gl: &Rc<glow::Context>, compute: &str) -> Result<Owned<glow::Program>> {
    program_from(gl, &[(glow::COMPUTE_SHADER, compute, "compute")])
}

/// Each stage's shader and the program are owned from creation on: a shader that does not
/// compile, or a program that does not link, deletes what was made.
fn program_from(gl: &Rc<glow::Context>, stages: &[(u32, &str, &str)]) -> Result<Owned<glow::Program>> {
    let program = create(gl, "glCreateProgram", |gl| unsafe { gl.create_program() })?;
    crate::instruments::resources::created("gl_program", 0);
    let mut shaders = Vec::new();
    for &(kind, source, name) in stages {
        let shader = create(gl, &format!("glCreateShader for the {name} shader"), |gl| unsafe {
            gl.create_shader(kind)
        })?;
        unsafe {
            gl.shader_source(*shader, source);
            gl.compile_shader(*shader);
        }
        // As if it had not compiled (a driver's compiler may refuse what another accepts).
        fail::step(&format!("compiling the {name} shader"))?;
        if !unsafe { gl.get_shader_compile_status(*shader) } {
            let log = unsafe { gl.get_shader_info_log(*shader) };
            bail!("the {name} shader does not compile:\n{log}");
        }
        unsafe { gl.attach_shader(*program, *shader) };
        shaders.push(shader);
    }
    unsafe { gl.link_program(*program) };
    for shader in &shaders {
        // Linked in, or not: the program needs its shaders no longer. (Dropped below.)
        unsafe { gl.detach_shader(*program, **shader) };
    }
    drop(shaders);
    fail::step("linking the program")?;
    if !unsafe { gl.get_program_link_status(*program) } {
        let log = unsafe { gl.get_program_info_log(*program) };
        bail!("the program does not link:\n{log}");
    }
    Ok(program)
}

/// A renderbuffer of `width` x `height` pixels, made as the step `what`: `format` is GL's enum
/// with its name and bytes a pixel, by which the report counts it (`gl_renderbuffer: RGBA8`).
/// Deleted when dropped.
pub fn renderbuffer(
    gl: &Rc<glow::Context>,
    what: &str,
    (format, name, bytes_per_pixel): (u32, &str, u64),
    (width, height): (u32, u32),
) -> Result<Owned<glow::Renderbuffer>> {
    let bytes = bytes_per_pixel * width as u64 * height as u64;
    let renderbuffer = create(gl, what, |gl| unsafe { gl.create_renderbuffer() })?
        .counted(&format!("gl_renderbuffer: {name}"), bytes);
    unsafe {
        gl.bind_renderbuffer(glow::RENDERBUFFER, Some(*renderbuffer));
        gl.renderbuffer_storage(glow::RENDERBUFFER, format, width as i32, height as i32);
        gl.bind_renderbuffer(glow::RENDERBUFFER, None);
    }
    Ok(renderbuffer)
}

/// A framebuffer whose colour is `texture`, made as the step `what`: to draw into the texture,
/// or to blit or read from it. Checked complete. Delete it before the texture: a framebuffer
/// keeps a deleted texture, and so its memory, alive.
pub fn framebuffer_over(
    gl: &Rc<glow::Context>,
    what: &str,
    texture: glow::Texture,
) -> Result<Owned<glow::Framebuffer>> {
    let framebuffer = create(gl, what, |gl| unsafe { gl.create_named_framebuffer() })?;
    unsafe {
        gl.named_framebuffer_texture(Some(*framebuffer), glow::COLOR_ATTACHMENT0, Some(texture), 0);
        let status = gl.check_named_framebuffer_status(Some(*framebuffer), glow::FRAMEBUFFER);
        if status != glow::FRAMEBUFFER_COMPLETE {
            bail!("{what}: the framebuffer is incomplete ({status:#x})"); // deleted on the way out
        }
    }
    Ok(framebuffer)
}

/// An offscreen RGBA8 colour target for headless drawing, read back with [`crate::instruments::output`].
/// Deleted when dropped: the framebuffer, then its renderbuffer (fields drop in order).
pub struct RenderTarget {
    pub framebuffer: Owned<glow::Framebuffer>,
    pub colour: Owned<glow::Renderbuffer>,
    pub width: u32,
    pub height: u32,
}

impl RenderTarget {
    pub fn new(gl: &Rc<glow::Context>, width: u32, height: u32) -> Result<Self> {
        let what = "glCreateRenderbuffers for the colour target";
        let colour = renderbuffer(gl, what, (glow::RGBA8, "RGBA8", 4), (width, height))?;
        let framebuffer = create(gl, "glCreateFramebuffers for the colour target", |gl| unsafe {
            gl.create_named_framebuffer()
        })?;
        let target = RenderTarget { framebuffer, colour, width, height };
        unsafe {
            gl.named_framebuffer_renderbuffer(
                Some(*target.framebuffer),
                glow::COLOR_ATTACHMENT0,
                glow::RENDERBUFFER,
                Some(*target.colour),
            );
            let status = gl.check_named_framebuffer_status(Some(*target.framebuffer), glow::FRAMEBUFFER);
            if status != glow::FRAMEBUFFER_COMPLETE {
                bail!("offscreen framebuffer incomplete: {status:#x}"); // `target` deletes both
            }
        }
        Ok(target)
    }

    /// Binds it for drawing and reading, with a viewport that covers it.
    pub fn bind(&self, gl: &glow::Context) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(*self.framebuffer));
            gl.viewport(0, 0, self.width as i32, self.height as i32);
        }
    }
}
