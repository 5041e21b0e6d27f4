//! Chapter 14's viewer: GL in a process of its own. It learns from the renderer's Hello which
//! device to open GL on, imports the ring's fds as textures (and, where both sides share them,
//! each slot's "frame written" semaphore), and for each "frame k is in slot i" reads the slot
//! back, checks it is frame k's picture, and answers "slot i is free". Without `--headless`, where
//! there is a display, it also shows each frame in a window as it arrives. With `--reconnect` it
//! outlives its renderer and waits for the next one.

use anyhow::{Result, bail, ensure};
use common::base::cli::Size;
use common::base::gl::{GlContext, framebuffer_over};
use common::base::window::{Key, NamedKey, Window};
use common::frame::ring::{is_picture_of, read_slot, wait_until_written, window_shows};
use common::instruments::census::{self, Sample};
use common::instruments::{fail, output, resources};
use common::interop::handoff::import_semaphore;
use common::interop::wire::{self, Broken, Message, Received, Socket};
use common::interop::{self, exportable::MemoryTerms};
use common::{Report, gl_in_window};
use glow::HasContext;
use std::os::fd::{AsFd as _, FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::time::Duration;

/// Where the viewer finds its renderer.
pub enum Renderer {
    /// The end of the renderer's socket pair this process inherited (`--viewer-fd`).
    Inherited(i32),
    /// A renderer listening at this path (`--connect`).
    At(PathBuf),
}

/// The viewer's settings, from the chapter's flags.
pub struct Settings {
    /// The chapter's name: the window's title and the picture's file name.
    pub chapter: &'static str,
    pub renderer: Renderer,
    pub timeout: Duration,
    /// Outlive the renderer: wait for the next one at the same path.
    pub reconnect: bool,
    pub headless: bool,
    pub out_dir: PathBuf,
}

/// What the viewer keeps from one renderer to the next (`--reconnect`).
#[derive(Default)]
struct Viewed {
    /// Made at the first Hello; every later renderer must run on the same device.
    gl: Option<GlContext>,
    /// The window GL draws into, if there is one: dropped after the context (declared after it).
    window: Option<Window>,
    /// Did the window show each frame (its top-left pixel, the frame's background)?
    window_right: bool,
    shown: u64,
    all_right: bool,
    no_fd_leaked: bool,
    /// The last complete frame read, and its number.
    last: Option<(u64, Vec<u8>)>,
    /// The viewer's resources after each renderer, for the soak.
    sessions: Vec<Sample>,
    /// Renderers refused for breaking the protocol (`--reconnect` waits for the next).
    refused: u64,
}

pub fn run(args: &Settings, report: &mut Report) -> Result<()> {
    let mut viewed = Viewed { window_right: true, all_right: true, no_fd_leaked: true, ..Default::default() };
    loop {
        let socket = match &args.renderer {
            &Renderer::Inherited(fd) => {
                // Is it an open socket at all? A mistyped --viewer-fd must not become someone
                // else's fd (asked of /proc by number: no fd is made of it until it is known open).
                let file = std::fs::metadata(format!("/proc/self/fd/{fd}"));
                use std::os::unix::fs::FileTypeExt as _;
                ensure!(
                    file.is_ok_and(|file| file.file_type().is_socket()),
                    "--viewer-fd {fd} is not an open socket"
                );
                // SAFETY: the renderer started us with this end of its socket pair, for us alone.
                Socket { fd: unsafe { OwnedFd::from_raw_fd(fd) } }
            }
            Renderer::At(path) if viewed.first() => wire::connect(path)?,
            // The next renderer: its socket appears when it starts listening.
            Renderer::At(path) => match wire::connect_within(path, args.timeout) {
                Ok(socket) => socket,
                Err(error) => {
                    eprintln!(
                        "viewer: no renderer came back within {:?} ({error:#}); stopping",
                        args.timeout
                    );
                    return record(report, &viewed);
                }
            },
        };
        match view(args, report, &socket, &mut viewed) {
            Err(error) => {
                // The renderer learns why, rather than only that we hung up (which it would survive).
                let _ = socket.send(&Message::Refused { reason: format!("{error:#}") }, &[]);
                // A renderer that lied (`--reconnect`): refused, and the next one waited for.
                if args.reconnect && error.is::<wire::Broken>() {
                    eprintln!("viewer: refused the renderer: {error:#}; waiting for the next (--reconnect)");
                    viewed.refused += 1;
                    continue;
                }
                return Err(error);
            }
            Ok(true) if args.reconnect && matches!(args.renderer, Renderer::At(_)) => {
                eprintln!("viewer: waiting for the next renderer (--reconnect)");
            }
            Ok(true) => return record(report, &viewed), // the renderer is gone: so are we
            Ok(false) => return Ok(()),                 // recorded before the summary went
        }
    }
}

impl Viewed {
    /// Is this the first renderer? It must be listening already; a later one may be on its way.
    fn first(&self) -> bool {
        self.sessions.is_empty() && self.refused == 0
    }
}

/// The viewer's checks and counts, over every renderer it served: recorded once, at its end.
fn record(report: &mut Report, viewed: &Viewed) -> Result<()> {
    report.check("every_frame_is_the_one_announced", viewed.all_right);
    report.check("no_fd_leaked", viewed.no_fd_leaked);
    if viewed.window.is_some() {
        report.check("the_window_shows_each_frame", viewed.window_right);
    }
    report.set("window", viewed.window.is_some());
    report.set("frames_shown", viewed.shown);
    if !viewed.sessions.is_empty() {
        report.set("sessions", &viewed.sessions);
    }
    if viewed.refused > 0 {
        report.set("renderers_refused", viewed.refused);
    }
    Ok(())
}

/// One renderer, from its Hello to its Bye (`Ok(false)`) or its hang-up (`Ok(true)`).
fn view(args: &Settings, report: &mut Report, socket: &Socket, viewed: &mut Viewed) -> Result<bool> {
    socket.set_timeout(args.timeout)?;
    // Only this user's renderer: the fds it sends become our GL's memory.
    socket.ensure_same_user()?;
    // 1. Hear the renderer's Hello
    let hello = match socket.recv()? {
        Received::Message(Message::Hello(hello), _) => hello,
        Received::Message(Message::Refused { reason }, _) => {
            bail!(Broken(format!("the renderer refused: {reason}")))
        }
        Received::Message(other, _) => {
            bail!(Broken(format!("the renderer began with {}, not Hello", other.name())))
        }
        // A renderer that died as we connected (its listening socket closes last): the next one.
        Received::HungUp if !viewed.first() => return Ok(true),
        Received::HungUp => bail!(Broken("the renderer hung up before saying Hello".into())),
        Received::TimedOut => bail!(Broken(format!("the renderer said nothing for {:?}", args.timeout))),
    };
    let (width, height) = (hello.width, hello.height);

    // 2. Open GL on the renderer's device, or refuse
    // ANCHOR: same_device
    let vulkan = hello.device();
    if viewed.gl.is_none() {
        // In a window where there is a display (the window system then picks GL's device, which
        // the UUID check below holds to the renderer's), else headless GL on the renderer's device.
        let title = format!("{} (viewer)", args.chapter);
        let (window, gl_context) = gl_in_window(&title, Size { width, height }, &vulkan, args.headless)?;
        report.gl = Some(gl_context.report());
        viewed.gl = Some(gl_context);
        viewed.window = window;
    }
    let gl_context = viewed.gl.as_ref().expect("made above");
    let gl = &gl_context.gl;
    report.uuids_match = Some(common::base::gl::uuids_match(&vulkan, gl_context));
    // Another device's fd would import as garbage, or crash the driver: refuse, naming both.
    common::base::gl::ensure_same_device(&vulkan, gl_context)
        .map_err(|error| Broken(format!("{error:#}")))?;
    // ANCHOR_END: same_device
    let largest = unsafe { gl.get_parameter_i32(glow::MAX_TEXTURE_SIZE) }.max(0) as u32;
    ensure!(
        width <= largest && height <= largest,
        Broken(format!("{width}x{height}: GL_MAX_TEXTURE_SIZE is {largest} here"))
    );
    // Semaphores where the renderer offers them and GL can import them; else the host path.
    let semaphores = hello.semaphores && gl_context.semaphores.is_some();
    let welcome = Message::Welcome {
        device_uuid: gl_context.device_uuid,
        driver_uuid: gl_context.driver_uuid,
        renderer: gl_context.renderer.clone(),
        semaphores,
    };
    ensure!(socket.send(&welcome, &[])?, "the renderer hung up during the handshake");
    report.sync = Some(if semaphores { "semaphores" } else { "host" });
    let fds_before = resources::open_fd_targets();

    // 3. Import the ring
    // ANCHOR: import
    // What GL must be told of each slot's memory: its size, and that it is one image's alone.
    let memory = MemoryTerms { size: hello.memory_size, dedicated: true };
    let mut ring = Vec::new();
    for expected in 0..hello.slots {
        let (slot, memory_size, fd) = match socket.recv()? {
            Received::Message(Message::Slot { slot, memory_size }, Some(fd)) => (slot, memory_size, fd),
            Received::Message(other, _) => {
                bail!(Broken(format!("expected slot {expected}, the renderer sent {}", other.name())))
            }
            Received::HungUp | Received::TimedOut => {
                bail!(Broken("the renderer went away while sending the slots".into()))
            }
        };
        // From here until the import succeeds, the fd is ours: every `?` below closes it.
        ensure!(
            slot == expected,
            Broken(format!("the renderer sent slot {slot} where slot {expected} was due"))
        );
        let size = hello.memory_size;
        ensure!(
            memory_size == size,
            Broken(format!("slot {slot} is {memory_size} bytes; the Hello said {size}"))
        );
        let fd = wire::check_memory_fd(fd, memory_size)?;
        fail::keep_a_copy_if_asked(fd.as_fd())?; // the leak check's own test: VKGL_KEEP_A_RECEIVED_FD
        // A successful import takes the fd (GL closes it with the memory object); a failed one
        // does not, and `import_texture_2d` closes it.
        let texture = interop::import_texture_2d(gl_context, memory, fd, glow::RGBA8, (width, height))?;
        // In a window: a framebuffer on the slot's texture, to blit from (COLOR_ATTACHMENT usage).
        let what = "glCreateFramebuffers (a slot, to show it)";
        let framebuffer =
            viewed.window.as_ref().map(|_| framebuffer_over(gl, what, *texture.texture)).transpose()?;
        // The slot's "frame written" semaphore follows its memory, where both sides share them.
        let frame_written = match semaphores {
            false => None,
            true => match socket.recv()? {
                Received::Message(Message::SlotSemaphore { slot: s }, Some(fd)) if s == slot => {
                    Some(import_semaphore(gl_context, wire::check_semaphore_fd(fd)?)?)
                }
                Received::Message(other, _) => {
                    bail!(Broken(format!("expected slot {slot}'s semaphore, got {}", other.name())))
                }
                Received::HungUp | Received::TimedOut => {
                    bail!(Broken("the renderer went away while sending the slots".into()))
                }
            },
        };
        ring.push((framebuffer, texture, frame_written)); // dropped in that order
    }
    ensure!(socket.send(&Message::Ready, &[])?, "the renderer hung up after sending the slots");
    // ANCHOR_END: import
    let sync = if semaphores { "semaphores" } else { "host" };
    eprintln!("viewer: showing frames ({} slots of {width}x{height}, sync {sync})", hello.slots);

    // 4. Show each frame, then free its slot
    // ANCHOR: frames
    let mut previous = None; // this renderer's frames only: a new one counts from 0 again
    let mut closed = false; // the window: the frames sent after it are not shown, nor freed
    let gone = loop {
        let (frame, slot) = match socket.recv()? {
            Received::Message(Message::FrameReady { .. }, _) if closed => continue,
            Received::Message(Message::FrameReady { frame, slot }, _) => (frame, slot),
            Received::Message(Message::Ping { n }, _) => match socket.send(&Message::Pong { n }, &[])? {
                true => continue,
                false => break Some("hung up"),
            },
            Received::Message(Message::Bye, _) => break None,
            Received::Message(other, _) => {
                bail!(Broken(format!("the renderer sent {} during the frames", other.name())))
            }
            Received::HungUp => break Some("hung up"),
            Received::TimedOut => break Some("fell silent"),
        };
        let (framebuffer, texture, frame_written) =
            ring.get(slot as usize).ok_or_else(|| Broken(format!("slot {slot} of {}", hello.slots)))?;
        if let Some(previous) = previous.replace(frame) {
            ensure!(frame > previous, Broken(format!("frame {frame} came after frame {previous}")));
        }
        if let Some(frame_written) = frame_written {
            wait_until_written(gl_context, texture, frame_written);
        }
        // ANCHOR: show
        // In a window: copy the slot into the back buffer, scaled to the window, upside down (row
        // 0 is Vulkan's top row, GL's bottom one). The copy is GL's work on the slot: the fence
        // below covers it, and the slot is freed only once it is done.
        let window_size = viewed.window.as_ref().map(Window::size);
        if let (Some(framebuffer), Some((ww, wh))) = (framebuffer, window_size) {
            let (w, h, ww, wh) = (width as i32, height as i32, ww as i32, wh as i32);
            let (all, linear) = (glow::COLOR_BUFFER_BIT, glow::LINEAR);
            unsafe {
                gl.blit_named_framebuffer(Some(**framebuffer), None, 0, 0, w, h, 0, wh, ww, 0, all, linear)
            };
        }
        // ANCHOR_END: show
        let pixels = read_slot(gl_context, texture, (width, height), args.timeout)?;
        viewed.all_right &= is_picture_of(&pixels, frame, width, height);
        viewed.shown += 1;
        viewed.last = Some((frame, pixels));
        if !socket.send(&Message::SlotFree { slot, sent_ns: wire::monotonic_ns() }, &[])? {
            break Some("hung up");
        }
        // The back buffer holds a copy: show it (after the slot went back, so that waiting for
        // the display never holds up the renderer), then hear Esc and the close button.
        if let (Some(window), Some((ww, wh))) = (viewed.window.as_mut(), window_size) {
            viewed.window_right &= window_shows(gl, frame, (width, height), (ww, wh));
            window.swap_buffers(gl_context)?;
            let escape = window.poll(gl_context).any(|key| key == Key::Named(NamedKey::Escape));
            if escape || window.close_requested() {
                eprintln!("viewer: the window was closed after frame {frame}");
                ensure!(socket.send(&Message::Closed, &[])?, "the renderer hung up as the window closed");
                closed = true; // until the renderer's Bye, or its hang-up
            }
        }
    };
    // ANCHOR_END: frames

    // 5. Keep the last complete frame
    if let Some((frame, pixels)) = &viewed.last {
        output::save_rgba8(report, &args.out_dir, args.chapter, (width, height), pixels)?;
        report.set("last_frame", frame);
    }
    if let Some(why) = gone {
        let kept = viewed.last.as_ref().map_or("no frame".to_owned(), |(frame, _)| format!("frame {frame}"));
        eprintln!(
            "viewer: the renderer {why}; keeping {kept}, the last one shown, and letting go of the ring"
        );
    }

    // 6. Clean up
    drop(ring); // each framebuffer, texture and its memory object, then its semaphore
    gl_context.check_error("cleaning up")?;
    // Each slot's fd was GL's from its import, and went with its memory object.
    viewed.no_fd_leaked &= resources::no_fd_leaked("viewer", &fds_before);
    report.set("renderer_gone", gone.is_some());
    if args.reconnect {
        viewed.sessions.push(census::sample(Some(gl_context)));
    }
    if gone.is_none() {
        record(report, viewed)?;
        let mut summary = serde_json::to_value(&*report)?;
        summary["gl_errors"] = common::base::gl::gl_error_count().into();
        let summary = Message::Summary { json: summary.to_string() };
        ensure!(socket.send(&summary, &[])?, "the renderer hung up before the summary");
    }
    Ok(gone.is_some())
}
