//! Chapter 14's socket: one end of the connection between the renderer and the viewer, how it
//! is made (a socket pair for a viewer the renderer starts, a path for `--listen`/`--connect`),
//! and how a message and its fds go through it (`sendmsg`/`recvmsg` with `SCM_RIGHTS`).

use super::{MAX_MESSAGE, Message, decode, encode};
use anyhow::{Context as _, Result, bail, ensure};
use common::instruments::fail;
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
