//! Chapter 14's wire: the messages the renderer and the viewer exchange over a Unix-domain
//! socket, and the file descriptors that travel with them (`SCM_RIGHTS`).
//!
//! Every message is one `SOCK_SEQPACKET` datagram: a 12-byte header (magic, version, kind, body
//! length) and a body whose length must be exactly what the header says and what the kind needs.
//! Anything else is refused before it is looked at: wrong magic or version, unknown kind, a length
//! that does not add up, strings too long or not UTF-8, counts out of range, an fd missing or one
//! too many. The decoder never panics (the fuzz test below feeds it garbage), and a refused
//! message's fds are closed with it.

use anyhow::{Context as _, Result, bail, ensure};
use std::os::fd::OwnedFd;

// ANCHOR: limits
/// "VKGL": the first four bytes of every message. Anything else did not come from this program.
pub const MAGIC: [u8; 4] = *b"VKGL";
/// Bumped whenever a message changes shape: both sides must speak the same one.
pub const VERSION: u16 = 3;
const HEADER: usize = 12;
/// The largest message (a summary at its longest): the receive buffer's size.
pub const MAX_MESSAGE: usize = HEADER + 2 + MAX_SUMMARY;
/// The most slots a ring may have: 2 is double buffering, 3 triple; 16 is far past any use.
pub const MAX_SLOTS: u32 = 16;
/// The widest and tallest image (`--size`'s own limit).
pub const MAX_SIDE: u32 = crate::base::cli::TYPED_LIMIT;
const MAX_NAME: usize = 256;
const MAX_REASON: usize = 2048;
const MAX_SUMMARY: usize = 32 * 1024;
/// The one format shared so far: `VK_FORMAT_R8G8B8A8_UNORM` (GL_RGBA8), 4 bytes a pixel.
pub const FORMAT_RGBA8: u32 = 37;
// ANCHOR_END: limits

// ANCHOR: messages
/// What the renderer says first: who it is, and what it will share.
#[derive(Clone, Debug, PartialEq)]
pub struct Hello {
    /// Vulkan's `deviceUUID` and `driverUUID`: GL must report the same two to import the memory.
    pub device_uuid: [u8; 16],
    pub driver_uuid: [u8; 16],
    /// The Vulkan device's name, for the refusal that names both devices.
    pub device: String,
    /// A `VkFormat` (only [`FORMAT_RGBA8`] so far).
    pub format: u32,
    pub width: u32,
    pub height: u32,
    /// Each slot's `allocationSize`: what GL must be told the memory object's size is.
    pub memory_size: u64,
    /// How many images in the ring (frames in flight), 2 to [`MAX_SLOTS`].
    pub slots: u32,
    /// Whether Vulkan can share semaphores (`VK_KHR_external_semaphore_fd`): an offer.
    pub semaphores: bool,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// Renderer -> viewer.
    Hello(Hello),
    /// Viewer -> renderer: GL's UUIDs and renderer string; the viewer accepts the Hello, and
    /// the semaphores if they were offered and GL can import them (`GL_EXT_semaphore_fd`).
    Welcome { device_uuid: [u8; 16], driver_uuid: [u8; 16], renderer: String, semaphores: bool },
    /// Either way: "I cannot go on, because ...". The last message its sender sends.
    Refused { reason: String },
    /// Renderer -> viewer, with exactly one fd: the memory of ring slot `slot`.
    Slot { slot: u32, memory_size: u64 },
    /// Renderer -> viewer, with exactly one fd, after slot `slot`'s `Slot` when both sides
    /// share semaphores: its "frame written" semaphore, which Vulkan signals and GL waits on.
    SlotSemaphore { slot: u32 },
    /// Viewer -> renderer: every slot is imported; frames may start.
    Ready,
    /// Renderer -> viewer: frame `frame` is finished, in slot `slot`. The slot is the viewer's now.
    FrameReady { frame: u64, slot: u32 },
    /// Viewer -> renderer: GL is done with slot `slot`. The slot is the renderer's again.
    /// `sent_ns`: when the viewer sent it (`CLOCK_MONOTONIC`, one clock for every process on
    /// the machine), for the hand-over latency.
    SlotFree { slot: u32, sent_ns: u64 },
    /// Renderer -> viewer: answer with `Pong` at once (the cost of a round trip).
    Ping { n: u64 },
    /// Viewer -> renderer: the answer to `Ping { n }`.
    Pong { n: u64 },
    /// Renderer -> viewer: no more frames; send your summary and go.
    Bye,
    /// Viewer -> renderer: its report, as JSON, for the renderer's report.
    Summary { json: String },
    /// Viewer -> renderer, instead of a `SlotFree`: its window was closed (Esc, or the window
    /// manager). No more frames: the renderer stops, lets go of those in flight and says `Bye`.
    Closed,
}
// ANCHOR_END: messages

impl Hello {
    /// The renderer's Vulkan device, as far as GL's choice of device and the UUID check need it.
    pub fn device(&self) -> crate::base::vulkan::DeviceInfo {
        crate::base::vulkan::DeviceInfo {
            name: self.device.clone(),
            driver: String::new(),
            api_version: 0,
            device_type: ash::vk::PhysicalDeviceType::OTHER,
            device_uuid: self.device_uuid,
            driver_uuid: self.driver_uuid,
        }
    }
}

impl Message {
    fn kind(&self) -> u16 {
        match self {
            Message::Hello(_) => 1,
            Message::Welcome { .. } => 2,
            Message::Refused { .. } => 3,
            Message::Slot { .. } => 4,
            Message::Ready => 5,
            Message::FrameReady { .. } => 6,
            Message::SlotFree { .. } => 7,
            Message::Bye => 8,
            Message::Summary { .. } => 9,
            Message::SlotSemaphore { .. } => 10,
            Message::Ping { .. } => 11,
            Message::Pong { .. } => 12,
            Message::Closed => 13,
        }
    }

    /// Its name, for errors and the failure-injection steps.
    pub fn name(&self) -> &'static str {
        KIND_NAMES[self.kind() as usize]
    }
}

const KIND_NAMES: [&str; 14] = [
    "?",
    "Hello",
    "Welcome",
    "Refused",
    "Slot",
    "Ready",
    "FrameReady",
    "SlotFree",
    "Bye",
    "Summary",
    "SlotSemaphore",
    "Ping",
    "Pong",
    "Closed",
];

/// How many fds a message of `kind` carries: one with each slot and each slot's semaphore,
/// none with anything else.
fn fds_for(kind: u16) -> usize {
    if kind == 4 || kind == 10 { 1 } else { 0 }
}

// ANCHOR: encode
/// The bytes of `message`: header, then body, integers little-endian, strings as a u16 length
/// and UTF-8.
pub fn encode(message: &Message) -> Vec<u8> {
    let mut body = Vec::new();
    let text = |body: &mut Vec<u8>, s: &str, max: usize| {
        let s = &s.as_bytes()[..s.len().min(max)]; // a reason too long is cut, never refused
        let s = std::str::from_utf8(s).map_or_else(|e| &s[..e.valid_up_to()], |s| s.as_bytes());
        body.extend_from_slice(&(s.len() as u16).to_le_bytes());
        body.extend_from_slice(s);
    };
    match message {
        Message::Hello(h) => {
            body.extend_from_slice(&h.device_uuid);
            body.extend_from_slice(&h.driver_uuid);
            for n in [h.format, h.width, h.height] {
                body.extend_from_slice(&n.to_le_bytes());
            }
            body.extend_from_slice(&h.memory_size.to_le_bytes());
            body.extend_from_slice(&h.slots.to_le_bytes());
            body.extend_from_slice(&(h.semaphores as u32).to_le_bytes());
            text(&mut body, &h.device, MAX_NAME);
        }
        Message::Welcome { device_uuid, driver_uuid, renderer, semaphores } => {
            body.extend_from_slice(device_uuid);
            body.extend_from_slice(driver_uuid);
            body.extend_from_slice(&(*semaphores as u32).to_le_bytes());
            text(&mut body, renderer, MAX_NAME);
        }
        Message::Refused { reason } => text(&mut body, reason, MAX_REASON),
        Message::Slot { slot, memory_size } => {
            body.extend_from_slice(&slot.to_le_bytes());
            body.extend_from_slice(&memory_size.to_le_bytes());
        }
        Message::FrameReady { frame, slot } => {
            body.extend_from_slice(&frame.to_le_bytes());
            body.extend_from_slice(&slot.to_le_bytes());
        }
        Message::SlotFree { slot, sent_ns } => {
            body.extend_from_slice(&slot.to_le_bytes());
            body.extend_from_slice(&sent_ns.to_le_bytes());
        }
        Message::SlotSemaphore { slot } => body.extend_from_slice(&slot.to_le_bytes()),
        Message::Ping { n } | Message::Pong { n } => body.extend_from_slice(&n.to_le_bytes()),
        Message::Ready | Message::Bye | Message::Closed => {}
        Message::Summary { json } => text(&mut body, json, MAX_SUMMARY),
    }
    let mut bytes = Vec::with_capacity(HEADER + body.len());
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&VERSION.to_le_bytes());
    bytes.extend_from_slice(&message.kind().to_le_bytes());
    bytes.extend_from_slice(&(body.len() as u32).to_le_bytes());
    bytes.extend_from_slice(&body);
    bytes
}
// ANCHOR_END: encode

/// Reads a body front to back; every read checks there are enough bytes left.
struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn bytes(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        ensure!(self.0.len() >= n, "truncated: {what} needs {n} bytes, {} left", self.0.len());
        let (taken, rest) = self.0.split_at(n);
        self.0 = rest;
        Ok(taken)
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.bytes(4, what)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.bytes(8, what)?.try_into().expect("8 bytes")))
    }
    fn uuid(&mut self, what: &str) -> Result<[u8; 16]> {
        Ok(self.bytes(16, what)?.try_into().expect("16 bytes"))
    }
    fn text(&mut self, what: &str, max: usize) -> Result<String> {
        let len = u16::from_le_bytes(self.bytes(2, what)?.try_into().expect("2 bytes")) as usize;
        ensure!(len <= max, "{what} is {len} bytes long, at most {max} allowed");
        let bytes = self.bytes(len, what)?;
        Ok(std::str::from_utf8(bytes).with_context(|| format!("{what} is not UTF-8"))?.to_owned())
    }
    fn flag(&mut self, what: &str) -> Result<bool> {
        match self.u32(what)? {
            0 => Ok(false),
            1 => Ok(true),
            n => bail!("{what} is {n}: 0 or 1"),
        }
    }
    fn slot(&mut self) -> Result<u32> {
        let slot = self.u32("slot")?;
        ensure!(slot < MAX_SLOTS, "slot {slot}: there are at most {MAX_SLOTS}");
        Ok(slot)
    }
}

// ANCHOR: decode
/// The message in `bytes`, which arrived with `fds`; and its fd, if its kind carries one. Refuses
/// (an error, every fd closed) anything that is not exactly a message of this version.
pub fn decode(bytes: &[u8], mut fds: Vec<OwnedFd>) -> Result<(Message, Option<OwnedFd>)> {
    ensure!(bytes.len() >= HEADER, "truncated: {} bytes, a header alone is {HEADER}", bytes.len());
    let (header, body) = bytes.split_at(HEADER);
    ensure!(header[..4] == MAGIC, "not a message of this program (magic {:02x?})", &header[..4]);
    let version = u16::from_le_bytes([header[4], header[5]]);
    ensure!(version == VERSION, "protocol version {version}; this program speaks version {VERSION}");
    let kind = u16::from_le_bytes([header[6], header[7]]);
    let name = *KIND_NAMES
        .get(kind as usize)
        .filter(|_| kind != 0)
        .with_context(|| format!("unknown kind {kind}"))?;
    let length = u32::from_le_bytes(header[8..12].try_into().expect("4 bytes")) as usize;
    ensure!(length == body.len(), "{name}: the header says {length} body bytes, {} came", body.len());
    ensure!(
        fds.len() == fds_for(kind),
        "{name} carries {} fd(s), not {}",
        fds_for(kind),
        fds.len() // dropped on the way out: closed
    );
    let mut r = Reader(body);
    let message = match kind {
        1 => {
            let (device_uuid, driver_uuid) = (r.uuid("device UUID")?, r.uuid("driver UUID")?);
            let (format, width, height) = (r.u32("format")?, r.u32("width")?, r.u32("height")?);
            let (memory_size, slots) = (r.u64("memory size")?, r.u32("slot count")?);
            let semaphores = r.flag("semaphores")?;
            let device = r.text("device name", MAX_NAME)?;
            ensure!(
                format == FORMAT_RGBA8,
                "format {format}: only {FORMAT_RGBA8} (R8G8B8A8_UNORM) is shared"
            );
            ensure!(
                (1..=MAX_SIDE).contains(&width) && (1..=MAX_SIDE).contains(&height),
                "{width}x{height}: each side must be 1 to {MAX_SIDE}"
            );
            let pixels = width as u64 * height as u64 * 4;
            // Drivers pad and align image memory, but not to four times the pixels.
            ensure!(
                (pixels..=pixels * 4 + (1 << 20)).contains(&memory_size),
                "{memory_size} bytes of memory for {width}x{height} RGBA8 ({pixels} bytes of pixels)"
            );
            ensure!((2..=MAX_SLOTS).contains(&slots), "{slots} slots: a ring has 2 to {MAX_SLOTS}");
            Message::Hello(Hello {
                device_uuid,
                driver_uuid,
                device,
                format,
                width,
                height,
                memory_size,
                slots,
                semaphores,
            })
        }
        2 => {
            let (device_uuid, driver_uuid) = (r.uuid("device UUID")?, r.uuid("driver UUID")?);
            let semaphores = r.flag("semaphores")?;
            Message::Welcome { device_uuid, driver_uuid, renderer: r.text("renderer", MAX_NAME)?, semaphores }
        }
        3 => Message::Refused { reason: r.text("reason", MAX_REASON)? },
        4 => {
            let (slot, memory_size) = (r.slot()?, r.u64("memory size")?);
            ensure!(memory_size > 0, "slot {slot}: 0 bytes of memory");
            Message::Slot { slot, memory_size }
        }
        5 => Message::Ready,
        6 => Message::FrameReady { frame: r.u64("frame")?, slot: r.slot()? },
        7 => Message::SlotFree { slot: r.slot()?, sent_ns: r.u64("sent at")? },
        8 => Message::Bye,
        13 => Message::Closed,
        9 => Message::Summary { json: r.text("summary", MAX_SUMMARY)? },
        10 => Message::SlotSemaphore { slot: r.slot()? },
        11 => Message::Ping { n: r.u64("ping")? },
        12 => Message::Pong { n: r.u64("pong")? },
        _ => unreachable!("kinds were checked against KIND_NAMES"),
    };
    ensure!(r.0.is_empty(), "{name}: {} bytes left over after the message", r.0.len());
    Ok((message, fds.pop()))
}
// ANCHOR_END: decode

// ANCHOR: broken
/// The other process broke the protocol: what it sent, or when, or who it is, is not what this
/// program would send. An error of the other side's, not ours: a listening renderer refuses that
/// viewer and serves the next, as a `--reconnect` viewer does with a renderer.
#[derive(Debug)]
pub struct Broken(pub String);

impl std::fmt::Display for Broken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Broken {}
// ANCHOR_END: broken

// ANCHOR: memory_fd
/// Refuses an fd that cannot be `memory_size` bytes of exported memory: a socket, a pipe or a
/// directory, or a file (Mesa exports a memfd) smaller than the message says. A character device
/// (NVIDIA exports those) says nothing of its size; GL's import is the check then.
pub fn check_memory_fd(fd: OwnedFd, memory_size: u64) -> Result<OwnedFd> {
    use std::os::unix::fs::FileTypeExt as _;
    let file = std::fs::File::from(fd); // the same fd, for std's fstat; handed back below
    let metadata = file.metadata().context("fstat on the slot's fd")?;
    let kind = metadata.file_type();
    if kind.is_file() {
        ensure!(
            metadata.len() >= memory_size,
            Broken(format!("the slot's fd holds {} bytes, the message says {memory_size}", metadata.len()))
        );
    } else if !kind.is_char_device() {
        bail!(Broken(format!("the slot's fd is not memory ({kind:?}): refused")));
    }
    Ok(OwnedFd::from(file))
}

/// Refuses an fd that cannot be an exported semaphore: a socket, a pipe, a directory or a
/// regular file. Mesa exports a DRM syncobj (an anonymous inode), NVIDIA a character device;
/// GL's import is the check of either.
pub fn check_semaphore_fd(fd: OwnedFd) -> Result<OwnedFd> {
    use std::os::unix::fs::FileTypeExt as _;
    let file = std::fs::File::from(fd);
    let kind = file.metadata().context("fstat on the semaphore's fd")?.file_type();
    if kind.is_file() || kind.is_dir() || kind.is_fifo() || kind.is_socket() || kind.is_symlink() {
        bail!(Broken(format!("the semaphore's fd is not a semaphore ({kind:?}): refused")));
    }
    Ok(OwnedFd::from(file))
}
// ANCHOR_END: memory_fd

/// Now, on `CLOCK_MONOTONIC`, in nanoseconds: the clock both processes read the same.
pub fn monotonic_ns() -> u64 {
    let now = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    now.tv_sec as u64 * 1_000_000_000 + now.tv_nsec as u64
}

mod socket;
pub use socket::*;

#[cfg(test)]
mod tests;
