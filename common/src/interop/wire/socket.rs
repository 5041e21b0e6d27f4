//! Chapter 14's socket: one end of the connection between the renderer and the viewer, how it
//! is made (a socket pair for a viewer the renderer starts, a path for `--listen`/`--connect`),
//! and how a message and its fds go through it (`sendmsg`/`recvmsg` with `SCM_RIGHTS`).

use super::{Broken, MAX_MESSAGE, Message, decode, encode};
use crate::instruments::fail;
use anyhow::{Context as _, Result, bail, ensure};
use rustix::net::{
    AddressFamily, RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags, ReturnFlags, SendAncillaryBuffer,
    SendAncillaryMessage, SendFlags, SocketFlags, SocketType,
};
use std::io::{IoSlice, IoSliceMut};
use std::mem::MaybeUninit;
use std::os::fd::{BorrowedFd, OwnedFd};
use std::time::Duration;

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

// ANCHOR: listen
/// A listening socket at `path` (`--listen`), replacing a stale one a killed renderer left.
/// Whoever can connect to it is handed GPU memory: it is made readable and writable by its
/// owner alone (mode 0600) before it listens, so no one else ever connects, and each peer's
/// user is checked too ([`Socket::ensure_same_user`]), in case the path's mode was loosened.
pub fn listen(path: &std::path::Path) -> Result<OwnedFd> {
    use std::os::unix::fs::PermissionsExt as _;
    let fd = fail::call("socket (listening)", || {
        rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
    })?;
    let address = rustix::net::SocketAddrUnix::new(path).context("a socket path")?;
    let _ = std::fs::remove_file(path);
    fail::call("bind", || rustix::net::bind(&fd, &address)).with_context(|| path.display().to_string())?;
    // bind() made the file with the umask's mode (0755 under umask 022); until listen(), a
    // connect() is refused whatever the mode, so changing it now leaves no moment it is open.
    let owner_only = std::fs::Permissions::from_mode(0o600);
    fail::call("chmod 0600 (the socket)", || std::fs::set_permissions(path, owner_only))
        .with_context(|| path.display().to_string())?;
    fail::call("listen", || rustix::net::listen(&fd, 1))?;
    Ok(fd)
}
// ANCHOR_END: listen

/// Where `--listen` and `--connect` meet when given no path: a directory of this user's alone.
/// `$XDG_RUNTIME_DIR` (`/run/user/UID`, mode 0700, made by the login manager, emptied at
/// logout), where Wayland and PipeWire put theirs. Without it (a container, a cron job), a
/// directory `vkgl-interop-UID` in the temporary directory, made with mode 0700 if missing, and
/// refused if another user owns it or can enter it (as tmux does with `/tmp/tmux-UID`).
pub fn default_path() -> Result<std::path::PathBuf> {
    use std::os::unix::fs::{DirBuilderExt as _, MetadataExt as _, PermissionsExt as _};
    const NAME: &str = "14-two-processes.sock";
    if let Some(dir) = std::env::var_os("XDG_RUNTIME_DIR").filter(|dir| !dir.is_empty()) {
        return Ok(std::path::PathBuf::from(dir).join(NAME));
    }
    let uid = rustix::process::getuid().as_raw();
    let dir = std::env::temp_dir().join(format!("vkgl-interop-{uid}"));
    match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
        Err(error) if error.kind() != std::io::ErrorKind::AlreadyExists => {
            return Err(error).with_context(|| format!("making {}", dir.display()));
        }
        _ => {}
    }
    // symlink_metadata: a link planted in its place is refused, not followed.
    let metadata = std::fs::symlink_metadata(&dir).with_context(|| dir.display().to_string())?;
    let mode = metadata.permissions().mode();
    ensure!(
        metadata.is_dir() && metadata.uid() == uid && mode & 0o077 == 0,
        "{} is not a directory of this user's alone (owner uid {}, mode {:o}): set XDG_RUNTIME_DIR, \
         or give --listen and --connect a path",
        dir.display(),
        metadata.uid(),
        mode & 0o7777
    );
    Ok(dir.join(NAME))
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

/// The next client of `listener` (`--listen`), within `timeout`.
pub fn accept(listener: &OwnedFd, timeout: Duration) -> Result<Socket> {
    let recv = rustix::net::sockopt::Timeout::Recv;
    fail::call("setsockopt SO_RCVTIMEO (listening)", || {
        rustix::net::sockopt::set_socket_timeout(listener, recv, Some(timeout))
    })?;
    let fd = fail::call("accept", || rustix::net::accept_with(listener, SocketFlags::CLOEXEC))
        .with_context(|| format!("no viewer connected within {timeout:?}"))?;
    Ok(Socket { fd })
}

/// [`connect`], tried again every 20 ms until a renderer listens at `path` or `timeout` passes.
pub fn connect_within(path: &std::path::Path, timeout: Duration) -> Result<Socket> {
    let started = std::time::Instant::now();
    loop {
        match connect(path) {
            Ok(socket) => return Ok(socket),
            Err(error) if started.elapsed() > timeout => return Err(error),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

impl Socket {
    // ANCHOR: peer
    /// Refuses a peer run by another user (`SO_PEERCRED`: the kernel's record of who connected,
    /// which the peer cannot forge). Mode 0600 already keeps others out; this holds even where
    /// the path's mode or directory was loosened, or the socket was passed on.
    pub fn ensure_same_user(&self) -> Result<()> {
        let peer = fail::call("getsockopt SO_PEERCRED", || rustix::net::sockopt::socket_peercred(&self.fd))?;
        let ours = rustix::process::getuid();
        ensure!(
            peer.uid == ours,
            Broken(format!(
                "pid {} runs as uid {}, not this program's uid {}",
                peer.pid.as_raw_pid(),
                peer.uid.as_raw(),
                ours.as_raw()
            ))
        );
        Ok(())
    }
    // ANCHOR_END: peer

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
        // What the other process sent is refused as its error (`Broken`), not ours: its fds close here.
        ensure!(
            !got.flags.contains(ReturnFlags::TRUNC),
            Broken(format!("a message longer than {MAX_MESSAGE} bytes"))
        );
        // CTRUNC (MSG_CTRUNC): fds that did not fit were closed by the kernel; refuse the rest.
        ensure!(
            !got.flags.contains(ReturnFlags::CTRUNC),
            Broken("a message with more fds than any carries".into())
        );
        let (message, fd) = decode(&bytes[..got.bytes], fds).map_err(|error| Broken(format!("{error:#}")))?;
        Ok(Received::Message(message, fd))
    }
    // ANCHOR_END: recv
}
