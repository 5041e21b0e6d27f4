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
use common::base::fail;
use rustix::net::{
    AddressFamily, RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags, ReturnFlags, SendAncillaryBuffer,
    SendAncillaryMessage, SendFlags, SocketFlags, SocketType,
};
use std::io::{IoSlice, IoSliceMut};
use std::mem::MaybeUninit;
use std::os::fd::{BorrowedFd, OwnedFd};
use std::time::Duration;

// ANCHOR: limits
/// "VKGL": the first four bytes of every message. Anything else did not come from this program.
pub const MAGIC: [u8; 4] = *b"VKGL";
/// Bumped whenever a message changes shape: both sides must speak the same one.
pub const VERSION: u16 = 1;
const HEADER: usize = 12;
/// The largest message (a summary at its longest): the receive buffer's size.
pub const MAX_MESSAGE: usize = HEADER + 2 + MAX_SUMMARY;
/// The most slots a ring may have: 2 is double buffering, 3 triple; 16 is far past any use.
pub const MAX_SLOTS: u32 = 16;
/// The widest and tallest image (`--size`'s own limit).
pub const MAX_SIDE: u32 = common::base::cli::TYPED_LIMIT;
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
}

#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// Renderer -> viewer.
    Hello(Hello),
    /// Viewer -> renderer: GL's UUIDs and renderer string; the viewer accepts the Hello.
    Welcome { device_uuid: [u8; 16], driver_uuid: [u8; 16], renderer: String },
    /// Either way: "I cannot go on, because ...". The last message its sender sends.
    Refused { reason: String },
    /// Renderer -> viewer, with exactly one fd: the memory of ring slot `slot`.
    Slot { slot: u32, memory_size: u64 },
    /// Viewer -> renderer: every slot is imported; frames may start.
    Ready,
    /// Renderer -> viewer: frame `frame` is finished, in slot `slot`. The slot is the viewer's now.
    FrameReady { frame: u64, slot: u32 },
    /// Viewer -> renderer: GL is done with slot `slot`. The slot is the renderer's again.
    SlotFree { slot: u32 },
    /// Renderer -> viewer: no more frames; send your summary and go.
    Bye,
    /// Viewer -> renderer: its report, as JSON, for the renderer's report.
    Summary { json: String },
}
// ANCHOR_END: messages

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
        }
    }

    /// Its name, for errors and the failure-injection steps.
    pub fn name(&self) -> &'static str {
        KIND_NAMES[self.kind() as usize]
    }
}

const KIND_NAMES: [&str; 10] =
    ["?", "Hello", "Welcome", "Refused", "Slot", "Ready", "FrameReady", "SlotFree", "Bye", "Summary"];

/// How many fds a message of `kind` carries: one with each slot, none with anything else.
fn fds_for(kind: u16) -> usize {
    if kind == 4 { 1 } else { 0 }
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
            text(&mut body, &h.device, MAX_NAME);
        }
        Message::Welcome { device_uuid, driver_uuid, renderer } => {
            body.extend_from_slice(device_uuid);
            body.extend_from_slice(driver_uuid);
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
        Message::SlotFree { slot } => body.extend_from_slice(&slot.to_le_bytes()),
        Message::Ready | Message::Bye => {}
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
            })
        }
        2 => {
            let (device_uuid, driver_uuid) = (r.uuid("device UUID")?, r.uuid("driver UUID")?);
            Message::Welcome { device_uuid, driver_uuid, renderer: r.text("renderer", MAX_NAME)? }
        }
        3 => Message::Refused { reason: r.text("reason", MAX_REASON)? },
        4 => {
            let (slot, memory_size) = (r.slot()?, r.u64("memory size")?);
            ensure!(memory_size > 0, "slot {slot}: 0 bytes of memory");
            Message::Slot { slot, memory_size }
        }
        5 => Message::Ready,
        6 => Message::FrameReady { frame: r.u64("frame")?, slot: r.slot()? },
        7 => Message::SlotFree { slot: r.slot()? },
        8 => Message::Bye,
        9 => Message::Summary { json: r.text("summary", MAX_SUMMARY)? },
        _ => unreachable!("kinds were checked against KIND_NAMES"),
    };
    ensure!(r.0.is_empty(), "{name}: {} bytes left over after the message", r.0.len());
    Ok((message, fds.pop()))
}
// ANCHOR_END: decode

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
            "the slot's fd holds {} bytes, the message says {memory_size}",
            metadata.len()
        );
    } else if !kind.is_char_device() {
        bail!("the slot's fd is not memory ({kind:?}): refused");
    }
    Ok(OwnedFd::from(file))
}
// ANCHOR_END: memory_fd

/// One end of the connection.
pub struct Socket {
    pub fd: OwnedFd,
}

/// What [`Socket::recv`] got.
pub enum Received {
    Message(Message, Option<OwnedFd>),
    /// The other process closed its end, or died (the kernel closes a dead process's fds).
    HungUp,
    /// Nothing came within the timeout.
    TimedOut,
}

// ANCHOR: socketpair
/// Two connected sockets: one for this process, one for the child it starts. `SEQPACKET`: each
/// send is one message, delivered whole with its fds or not at all (a byte stream could split a
/// message, and its fds would arrive with whichever part came first). `CLOEXEC`: no other child
/// inherits either end by accident; the viewer's end is made inheritable for its own exec only.
pub fn socketpair() -> Result<(Socket, Socket)> {
    let flags = SocketFlags::CLOEXEC;
    let (a, b) = fail::call("socketpair", || {
        rustix::net::socketpair(AddressFamily::UNIX, SocketType::SEQPACKET, flags, None)
    })?;
    Ok((Socket { fd: a }, Socket { fd: b }))
}
// ANCHOR_END: socketpair

/// A listening socket at `path` (`--listen`), replacing a stale one a killed renderer left.
pub fn listen(path: &std::path::Path) -> Result<OwnedFd> {
    let fd = fail::call("socket (listening)", || {
        rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
    })?;
    let address = rustix::net::SocketAddrUnix::new(path).context("a socket path")?;
    let _ = std::fs::remove_file(path);
    fail::call("bind", || rustix::net::bind(&fd, &address)).with_context(|| path.display().to_string())?;
    fail::call("listen", || rustix::net::listen(&fd, 1))?;
    Ok(fd)
}

/// Connects to a renderer listening at `path` (`--connect`).
pub fn connect(path: &std::path::Path) -> Result<Socket> {
    let fd = fail::call("socket", || {
        rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
    })?;
    let address = rustix::net::SocketAddrUnix::new(path).context("a socket path")?;
    fail::call("connect", || rustix::net::connect(&fd, &address))
        .with_context(|| format!("no renderer listening at {}", path.display()))?;
    Ok(Socket { fd })
}

impl Socket {
    /// Every wait for the other process ends after `timeout` (`SO_RCVTIMEO`): a process that
    /// hangs without dying must not hang this one too.
    pub fn set_timeout(&self, timeout: Duration) -> Result<()> {
        let recv = rustix::net::sockopt::Timeout::Recv;
        fail::call("setsockopt SO_RCVTIMEO", || {
            rustix::net::sockopt::set_socket_timeout(&self.fd, recv, Some(timeout))
        })
    }

    // ANCHOR: send
    /// Sends `message` with `fds` (`SCM_RIGHTS`: the kernel gives the receiver its own fds for
    /// the same files). Ours stay ours: the caller closes them when it likes. `Ok(false)`: the
    /// other end is gone.
    pub fn send(&self, message: &Message, fds: &[BorrowedFd<'_>]) -> Result<bool> {
        fail::step(&format!("sendmsg ({})", message.name()))?;
        let bytes = encode(message);
        let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(1))];
        let mut control = SendAncillaryBuffer::new(&mut space);
        if !fds.is_empty() {
            ensure!(control.push(SendAncillaryMessage::ScmRights(fds)), "too many fds for one message");
        }
        // NOSIGNAL: a dead peer is an EPIPE to handle, not a SIGPIPE that kills us.
        match rustix::net::sendmsg(&self.fd, &[IoSlice::new(&bytes)], &mut control, SendFlags::NOSIGNAL) {
            Ok(sent) if sent == bytes.len() => Ok(true),
            Ok(sent) => bail!("sendmsg ({}) sent {sent} of {} bytes", message.name(), bytes.len()),
            Err(rustix::io::Errno::PIPE | rustix::io::Errno::CONNRESET) => Ok(false),
            Err(error) => Err(error).with_context(|| format!("sendmsg ({})", message.name())),
        }
    }
    // ANCHOR_END: send

    // ANCHOR: recv
    /// The next message, its fd an [`OwnedFd`] from the moment it arrives: every way out of
    /// here, refusal included, closes what is not handed on.
    pub fn recv(&self) -> Result<Received> {
        fail::step("recvmsg")?;
        let mut bytes = vec![0u8; MAX_MESSAGE + 1];
        // Room for two fds: a message with one too many is seen, and refused, rather than cut.
        let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
        let mut control = RecvAncillaryBuffer::new(&mut space);
        // CMSG_CLOEXEC (MSG_CMSG_CLOEXEC): received fds are not inherited by any child we start.
        let flags = RecvFlags::CMSG_CLOEXEC;
        let mut iov = [IoSliceMut::new(&mut bytes)];
        let mut got = rustix::net::recvmsg(&self.fd, &mut iov, &mut control, flags);
        if got.as_ref().is_err_and(|&error| error == rustix::io::Errno::CONNRESET) {
            // The other end closed with our last message unread. Linux says so once, before
            // what it had sent us (a refusal, say), which the next call reads; or end of file.
            got = rustix::net::recvmsg(&self.fd, &mut iov, &mut control, flags);
        }
        let got = match got {
            Ok(got) => got,
            Err(rustix::io::Errno::AGAIN) => return Ok(Received::TimedOut),
            Err(rustix::io::Errno::CONNRESET) => return Ok(Received::HungUp),
            Err(error) => return Err(error).context("recvmsg"),
        };
        let fds: Vec<OwnedFd> = control
            .drain()
            .filter_map(|m| match m {
                RecvAncillaryMessage::ScmRights(fds) => Some(fds),
                _ => None,
            })
            .flatten()
            .collect();
        if got.bytes == 0 && fds.is_empty() {
            return Ok(Received::HungUp); // end of file: every fd of the other end is closed
        }
        ensure!(!got.flags.contains(ReturnFlags::TRUNC), "a message longer than {MAX_MESSAGE} bytes");
        // CTRUNC (MSG_CTRUNC): fds that did not fit were closed by the kernel; refuse the rest.
        ensure!(!got.flags.contains(ReturnFlags::CTRUNC), "a message with more fds than any carries");
        let (message, fd) = decode(&bytes[..got.bytes], fds)?;
        Ok(Received::Message(message, fd))
    }
    // ANCHOR_END: recv
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;

    fn hello() -> Hello {
        Hello {
            device_uuid: [1; 16],
            driver_uuid: [2; 16],
            device: "llvmpipe (LLVM 19.1.7, 256 bits)".into(),
            format: FORMAT_RGBA8,
            width: 96,
            height: 64,
            memory_size: 96 * 64 * 4,
            slots: 2,
        }
    }

    fn every_kind() -> Vec<Message> {
        vec![
            Message::Hello(hello()),
            Message::Welcome { device_uuid: [3; 16], driver_uuid: [4; 16], renderer: "llvmpipe".into() },
            Message::Refused { reason: "GL runs on another device".into() },
            Message::Slot { slot: 1, memory_size: 4096 },
            Message::Ready,
            Message::FrameReady { frame: u64::MAX, slot: 15 },
            Message::SlotFree { slot: 0 },
            Message::Bye,
            Message::Summary { json: "{\"frames_shown\": 3}".into() },
        ]
    }

    /// A real fd, of a file named `tag` in a fresh directory: whether it was closed shows in
    /// /proc/self/fd, whatever other tests open meanwhile.
    fn tagged_fd(dir: &std::path::Path, tag: &str, bytes: u64) -> OwnedFd {
        let file = std::fs::File::create(dir.join(tag)).unwrap();
        file.set_len(bytes).unwrap();
        file.into()
    }

    fn open_with(tag: &str) -> usize {
        common::base::resources::open_fds().iter().filter(|fd| fd.contains(tag)).count()
    }

    #[test]
    fn every_kind_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        for message in every_kind() {
            let fds = match message {
                Message::Slot { .. } => vec![tagged_fd(dir.path(), "round-trip", 4096)],
                _ => vec![],
            };
            let had_fd = !fds.is_empty();
            let (decoded, fd) = decode(&encode(&message), fds).unwrap();
            assert_eq!(decoded, message);
            assert_eq!(fd.is_some(), had_fd);
        }
    }

    #[test]
    fn every_kind_round_trips_through_a_socket_with_its_fd() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = socketpair().unwrap();
        for message in every_kind() {
            let fd =
                matches!(message, Message::Slot { .. }).then(|| tagged_fd(dir.path(), "socket-fd", 4096));
            let fds: Vec<BorrowedFd> = fd.iter().map(|f| f.as_fd()).collect();
            assert!(a.send(&message, &fds).unwrap());
            drop(fd); // ours: closed; the receiver has its own
            let Received::Message(got, fd) = b.recv().unwrap() else { panic!("no message") };
            assert_eq!(got, message);
            if let Some(fd) = fd {
                check_memory_fd(fd, 4096).unwrap();
            }
        }
        drop(a);
        assert!(matches!(b.recv().unwrap(), Received::HungUp), "a closed end reads as a hang-up");
        assert_eq!(open_with("socket-fd"), 0, "every fd that travelled is closed");
    }

    #[test]
    fn a_silent_peer_times_out() {
        let (_a, b) = socketpair().unwrap();
        b.set_timeout(Duration::from_millis(20)).unwrap();
        assert!(matches!(b.recv().unwrap(), Received::TimedOut));
    }

    /// Each refusal, by what its error says.
    #[test]
    fn malformed_messages_are_refused_by_name() {
        let valid = encode(&Message::Hello(hello()));
        let with = |edit: &dyn Fn(&mut Vec<u8>)| {
            let mut bytes = valid.clone();
            edit(&mut bytes);
            decode(&bytes, vec![]).unwrap_err().to_string()
        };
        let hello_with = |edit: &dyn Fn(&mut Hello)| {
            let mut h = hello();
            edit(&mut h);
            decode(&encode(&Message::Hello(h)), vec![]).unwrap_err().to_string()
        };
        assert!(with(&|b| b.truncate(5)).contains("truncated"));
        assert!(with(&|b| b[0] = b'X').contains("magic"));
        assert!(with(&|b| b[4] = 2).contains("protocol version 2; this program speaks version 1"));
        assert!(with(&|b| b[6] = 99).contains("unknown kind 99"));
        assert!(with(&|b| b[6] = 0).contains("unknown kind 0"));
        assert!(with(&|b| b.push(0)).contains("the header says"));
        assert!(with(&|b| b.truncate(b.len() - 1)).contains("the header says"));
        assert!(
            with(&|b| {
                b.push(0);
                let n = (b.len() - HEADER) as u32;
                b[8..12].copy_from_slice(&n.to_le_bytes());
            })
            .contains("left over")
        );
        assert!(hello_with(&|h| h.slots = 1).contains("1 slots"));
        assert!(hello_with(&|h| h.slots = 1_000_000).contains("1000000 slots"));
        assert!(hello_with(&|h| h.width = 0).contains("each side"));
        assert!(hello_with(&|h| h.height = MAX_SIDE + 1).contains("each side"));
        assert!(hello_with(&|h| h.format = 44).contains("format 44"));
        assert!(hello_with(&|h| h.memory_size = 100).contains("100 bytes of memory"));
        assert!(hello_with(&|h| h.memory_size = u64::MAX).contains("bytes of memory"));
        // A name longer than the limit, written by hand (encode cuts it).
        let mut long = valid[..valid.len() - 2 - hello().device.len()].to_vec();
        long.extend_from_slice(&300u16.to_le_bytes());
        long.extend_from_slice(&[b'a'; 300]);
        let n = (long.len() - HEADER) as u32;
        long[8..12].copy_from_slice(&n.to_le_bytes());
        assert!(decode(&long, vec![]).unwrap_err().to_string().contains("at most 256"));
        let mut bad_utf8 = valid.clone();
        let at = bad_utf8.len() - 1;
        bad_utf8[at] = 0xff;
        assert!(decode(&bad_utf8, vec![]).unwrap_err().to_string().contains("not UTF-8"));
        let slot = |s: u32| encode(&Message::SlotFree { slot: s });
        assert!(decode(&slot(MAX_SLOTS), vec![]).unwrap_err().to_string().contains("at most 16"));
    }

    #[test]
    fn a_missing_or_extra_fd_is_refused_and_closed() {
        let dir = tempfile::tempdir().unwrap();
        let slot = encode(&Message::Slot { slot: 0, memory_size: 4096 });
        assert!(decode(&slot, vec![]).unwrap_err().to_string().contains("carries 1 fd(s), not 0"));
        let two = vec![tagged_fd(dir.path(), "extra-fd", 1), tagged_fd(dir.path(), "extra-fd2", 1)];
        assert!(decode(&slot, two).unwrap_err().to_string().contains("not 2"));
        let stray = vec![tagged_fd(dir.path(), "extra-fd3", 1)];
        assert!(decode(&encode(&Message::Ready), stray).unwrap_err().to_string().contains("not 1"));
        assert_eq!(open_with("extra-fd"), 0, "refused messages' fds are closed");
    }

    #[test]
    fn an_fd_of_the_wrong_kind_or_size_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let small = check_memory_fd(tagged_fd(dir.path(), "small", 100), 4096).unwrap_err();
        assert!(small.to_string().contains("holds 100 bytes, the message says 4096"), "{small}");
        let (a, _b) = socketpair().unwrap();
        let socket = check_memory_fd(a.fd, 4096).unwrap_err();
        assert!(socket.to_string().contains("not memory"), "{socket}");
        let directory: OwnedFd = std::fs::File::open(dir.path()).unwrap().into();
        assert!(check_memory_fd(directory, 1).unwrap_err().to_string().contains("not memory"));
        assert!(check_memory_fd(tagged_fd(dir.path(), "fits", 4096), 4096).is_ok());
    }

    /// Thousands of inputs, random, cut short and bit-flipped from valid messages, with 0 to 2
    /// fds each: the decoder never panics, refuses with an error or decodes something it can
    /// encode back to the same bytes, and every fd is closed at the end.
    #[test]
    fn the_decoder_survives_fuzzing() {
        let dir = tempfile::tempdir().unwrap();
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            // xorshift64*: deterministic, so a failure repeats.
            seed ^= seed >> 12;
            seed ^= seed << 25;
            seed ^= seed >> 27;
            seed.wrapping_mul(0x2545_f491_4f6c_dd1d)
        };
        let valid: Vec<Vec<u8>> = every_kind().iter().map(encode).collect();
        let (mut refused, mut accepted) = (0, 0);
        for i in 0..20_000u32 {
            let mut bytes = valid[(next() % valid.len() as u64) as usize].clone();
            match i % 4 {
                0 => bytes.truncate((next() % (bytes.len() as u64 + 1)) as usize),
                1 => {
                    for _ in 0..1 + next() % 4 {
                        let at = (next() % bytes.len() as u64) as usize;
                        bytes[at] ^= 1 << (next() % 8);
                    }
                }
                2 => bytes = (0..next() % 80).map(|_| next() as u8).collect(),
                _ => {
                    let at = HEADER.min(bytes.len());
                    bytes.splice(at.., (0..next() % 64).map(|_| next() as u8));
                    let n = (bytes.len() - HEADER) as u32;
                    bytes[8..12].copy_from_slice(&n.to_le_bytes());
                }
            }
            let fds = (0..next() % 3).map(|_| tagged_fd(dir.path(), "fuzz-fd", 8)).collect();
            match decode(&bytes, fds) {
                Ok((message, _fd)) => {
                    accepted += 1;
                    assert_eq!(encode(&message), bytes, "what decodes encodes back the same");
                }
                Err(error) => {
                    refused += 1;
                    assert!(!error.to_string().is_empty());
                }
            }
        }
        assert!(refused > 10_000 && accepted > 100, "refused {refused}, accepted {accepted}");
        assert_eq!(open_with("fuzz-fd"), 0, "every fuzzed fd is closed");
    }
}
