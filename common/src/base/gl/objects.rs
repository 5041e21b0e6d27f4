//! Small GL helpers every drawing chapter uses: programs compiled from GLSL, and an offscreen
//! colour target.

use anyhow::{Result, bail};
use glow::HasContext;

/// Compiles and links a program from GLSL sources; a failure carries GL's info log.
pub fn program(gl: &glow::Context, vertex: &str, fragment: &str) -> Result<glow::Program> {
    program_from(
        gl,
        &[(glow::VERTEX_SHADER, vertex, "vertex"), (glow::FRAGMENT_SHADER, fragment, "fragment")],
    )
}

/// As [`program`], with a geometry shader between the two.
pub fn program_with_geometry(
    gl: &glow::Context,
    vertex: &str,
    geometry: &str,
    fragment: &str,
) -> Result<glow::Program> {
    let stages = [
        (glow::VERTEX_SHADER, vertex, "vertex"),
        (glow::GEOMETRY_SHADER, geometry, "geometry"),
        (glow::FRAGMENT_SHADER, fragment, "fragment"),
    ];
    program_from(gl, &stages)
}

/// A program of one compute shader (chapter 12's composite).
pub fn compute_program(gl: &glow::Context, compute: &str) -> Result<glow::Program> {
    program_from(gl, &[(glow::COMPUTE_SHADER, compute, "compute")])
}

fn program_from(gl: &glow::Context, stages: &[(u32, &str, &str)]) -> Result<glow::Program> {
    unsafe {
        let program = gl.create_program().map_err(anyhow::Error::msg)?;
        crate::base::resources::created("gl_program", 0);
        let mut shaders = Vec::new();
        for &(kind, source, name) in stages {
            let shader = gl.create_shader(kind).map_err(anyhow::Error::msg)?;
            gl.shader_source(shader, source);
            gl.compile_shader(shader);
            if !gl.get_shader_compile_status(shader) {
                let log = gl.get_shader_info_log(shader);
                gl.delete_shader(shader);
                shaders.into_iter().for_each(|s| gl.delete_shader(s));
                gl.delete_program(program);
                bail!("the {name} shader does not compile:\n{log}");
            }
            gl.attach_shader(program, shader);
            shaders.push(shader);
        }
        gl.link_program(program);
        for shader in shaders {
            gl.detach_shader(program, shader);
            gl.delete_shader(shader);
        }
        if !gl.get_program_link_status(program) {
            let log = gl.get_program_info_log(program);
            gl.delete_program(program);
            bail!("the program does not link:\n{log}");
        }
        Ok(program)
    }
}

/// An offscreen RGBA8 colour target for headless drawing, read back with [`crate::base::output`].
/// Deleted when dropped.
pub struct RenderTarget {
    pub framebuffer: glow::Framebuffer,
    pub colour: glow::Renderbuffer,
    pub width: u32,
    pub height: u32,
    gl: std::rc::Rc<glow::Context>,
}

impl RenderTarget {
    pub fn new(gl: &std::rc::Rc<glow::Context>, width: u32, height: u32) -> Result<Self> {
        unsafe {
            let colour = gl.create_renderbuffer().map_err(anyhow::Error::msg)?;
            gl.bind_renderbuffer(glow::RENDERBUFFER, Some(colour));
            gl.renderbuffer_storage(glow::RENDERBUFFER, glow::RGBA8, width as i32, height as i32);
            gl.bind_renderbuffer(glow::RENDERBUFFER, None);
            crate::base::resources::created("gl_renderbuffer: RGBA8", 4 * width as u64 * height as u64);
            let framebuffer = gl.create_named_framebuffer().map_err(anyhow::Error::msg)?;
            gl.named_framebuffer_renderbuffer(
                Some(framebuffer),
                glow::COLOR_ATTACHMENT0,
                glow::RENDERBUFFER,
                Some(colour),
            );
            let status = gl.check_named_framebuffer_status(Some(framebuffer), glow::FRAMEBUFFER);
            if status != glow::FRAMEBUFFER_COMPLETE {
                gl.delete_framebuffer(framebuffer);
                gl.delete_renderbuffer(colour);
                crate::base::resources::destroyed("gl_renderbuffer: RGBA8");
                bail!("offscreen framebuffer incomplete: {status:#x}");
            }
            Ok(RenderTarget { framebuffer, colour, width, height, gl: gl.clone() })
        }
    }

    /// Binds it for drawing and reading, with a viewport that covers it.
    pub fn bind(&self, gl: &glow::Context) {
        unsafe {
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(self.framebuffer));
            gl.viewport(0, 0, self.width as i32, self.height as i32);
        }
    }

    /// What dropping it does, where the reader sees it.
    pub fn delete(self, _gl: &glow::Context) {
        drop(self);
    }
}

impl Drop for RenderTarget {
    fn drop(&mut self) {
        unsafe {
            self.gl.bind_framebuffer(glow::FRAMEBUFFER, None);
            self.gl.delete_framebuffer(self.framebuffer);
            self.gl.delete_renderbuffer(self.colour);
            crate::base::resources::destroyed("gl_renderbuffer: RGBA8");
        }
    }
}
