//! Chapter 14 against liars, through real sockets: a listening renderer refuses each client that
//! breaks the protocol or is not its user, and serves the honest viewer that comes next; a
//! `--reconnect` viewer refuses a lying renderer and waits for the next. (The wire's decoder
//! alone is fuzzed in the chapter's own unit tests.)

mod harness;

use std::io::{BufRead, BufReader, Read};
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const CH14: &str = env!("CARGO_BIN_EXE_14-two-processes");

/// A message as chapter 14's wire has it (protocol version 3): "VKGL", version, kind, body
/// length, body.
fn message(kind: u16, body: &[u8]) -> Vec<u8> {
    let mut bytes = b"VKGL".to_vec();
    bytes.extend_from_slice(&3u16.to_le_bytes());
    bytes.extend_from_slice(&kind.to_le_bytes());
    bytes.extend_from_slice(&(body.len() as u32).to_le_bytes());
    bytes.extend_from_slice(body);
    bytes
}

/// The kinds this test sends and reads.
const HELLO: u16 = 1;
const REFUSED: u16 = 3;
const SLOT: u16 = 4;
const READY: u16 = 5;
const FRAME_READY: u16 = 6;
const SLOT_FREE: u16 = 7;
const SUMMARY: u16 = 9;
const PING: u16 = 11;
const PONG: u16 = 12;

/// A Welcome: GL's device and driver UUIDs, whether it takes semaphores, its renderer string.
fn welcome(device: &[u8], driver: &[u8], semaphores: u32, renderer: &str) -> Vec<u8> {
    let mut body = [device, driver, &semaphores.to_le_bytes()].concat();
    body.extend_from_slice(&(renderer.len() as u16).to_le_bytes());
    body.extend_from_slice(renderer.as_bytes());
    message(2, &body)
}

/// An fd a liar may push along: one end of a socket pair, a kind the renderer's fd check counts
/// (as it counts the memfds of Mesa's exported memory), so that one left open fails it.
fn stray_fd() -> OwnedFd {
    use rustix::net::{AddressFamily, SocketFlags, SocketType};
    rustix::net::socketpair(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None).unwrap().0
}

/// One client of a listening renderer, played by this test. What the renderer sends it is read
/// with no room for fds: the kernel closes the ring's fds as they arrive.
struct Client(OwnedFd);

impl Client {
    fn connect(path: &Path) -> Client {
        use rustix::net::{AddressFamily, SocketAddrUnix, SocketFlags, SocketType};
        let socket =
            rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
                .unwrap();
        rustix::net::connect(&socket, &SocketAddrUnix::new(path).unwrap()).unwrap();
        let recv = rustix::net::sockopt::Timeout::Recv;
        rustix::net::sockopt::set_socket_timeout(&socket, recv, Some(Duration::from_secs(120))).unwrap();
        Client(socket)
    }

    /// The next message, (kind, body); None once the other end has hung up.
    fn recv(&self) -> Option<(u16, Vec<u8>)> {
        let mut bytes = vec![0u8; 64 * 1024];
        let n = rustix::net::recv(&self.0, &mut bytes, rustix::net::RecvFlags::empty()).ok()?.0;
        (n >= 12).then(|| (u16::from_le_bytes([bytes[6], bytes[7]]), bytes[12..n].to_vec()))
    }

    fn send(&self, bytes: &[u8]) {
        self.send_with_fds(bytes, &[]);
    }

    fn send_with_fds(&self, bytes: &[u8], fds: &[BorrowedFd<'_>]) {
        use rustix::net::{SendAncillaryBuffer, SendAncillaryMessage, SendFlags};
        let mut space = [std::mem::MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(8))];
        let mut control = SendAncillaryBuffer::new(&mut space);
        if !fds.is_empty() {
            assert!(control.push(SendAncillaryMessage::ScmRights(fds)));
        }
        let iov = [std::io::IoSlice::new(bytes)];
        let _ = rustix::net::sendmsg(&self.0, &iov, &mut control, SendFlags::NOSIGNAL);
    }

    /// The renderer's Hello: its device and driver UUIDs, its slot count, whether it offers
    /// semaphores.
    fn hello(&self) -> ([u8; 16], [u8; 16], u32, bool) {
        let (kind, body) = self.recv().expect("a Hello");
        assert_eq!(kind, HELLO, "the renderer begins with Hello");
        let uuid = |at: usize| -> [u8; 16] { body[at..at + 16].try_into().unwrap() };
        let word = |at: usize| u32::from_le_bytes(body[at..at + 4].try_into().unwrap());
        (uuid(0), uuid(16), word(52), word(56) == 1)
    }

    /// What an honest viewer says until it is Ready: a true Welcome (the host path), then
    /// every slot received.
    fn through_the_slots(&self) {
        let (device, driver, slots, _) = self.hello();
        self.send(&welcome(&device, &driver, 0, "a test playing a viewer"));
        for _ in 0..slots {
            assert_eq!(self.recv().map(|(kind, _)| kind), Some(SLOT));
        }
    }

    /// Ready, and each Ping answered: what an honest viewer does until the frames.
    fn through_the_pings(&self) {
        self.through_the_slots();
        self.send(&message(READY, &[]));
        loop {
            match self.recv() {
                Some((PING, n)) => self.send(&message(PONG, &n)),
                Some((FRAME_READY, _)) => return,
                other => panic!("Pings, then a frame: {other:?}"),
            }
        }
    }

    /// The renderer's last word to a client it refused, its reason; empty if it said none.
    fn refusal(&self) -> String {
        while let Some((kind, body)) = self.recv() {
            if kind == REFUSED {
                return String::from_utf8_lossy(&body[2..]).into_owned();
            }
        }
        String::new()
    }
}

/// A renderer listening at `path`, headless, its report on stdout and its stderr piped, with
/// `args`; once it says it listens.
fn listener(path: &Path, out: &Path, args: &[&str]) -> (Child, std::thread::JoinHandle<String>) {
    let mut command = Command::new(CH14);
    command.args(["--headless", "--json", "--size", "64x48", "--listen"]).arg(path).arg("--out").arg(out);
    command.args(args);
    harness::pin_software_stack(&mut command);
    command.stderr(Stdio::piped()).stdout(Stdio::piped());
    let mut renderer = command.spawn().unwrap();
    let mut says = BufReader::new(renderer.stderr.take().unwrap());
    let mut heard = String::new();
    // Not the path appearing: it appears at bind(), before listen().
    while !heard.contains("for a viewer (--connect)") {
        assert!(says.read_line(&mut heard).unwrap() > 0, "the renderer stopped early:\n{heard}");
    }
    let rest = std::thread::spawn(move || {
        says.read_to_string(&mut heard).unwrap();
        heard
    });
    (renderer, rest)
}

/// Chapter 14 as a viewer of the renderer at `path`, as user `uid` if given (root only): then
/// a copy of the program in `out`, which that user can reach wherever the checkout is.
fn viewer(path: &Path, out: &Path, args: &[&str], uid: Option<u32>) -> Command {
    let program = match uid {
        Some(_) => {
            let copy = out.join("14-two-processes");
            if !copy.exists() {
                std::fs::copy(CH14, &copy).unwrap();
            }
            copy
        }
        None => CH14.into(),
    };
    let mut command = Command::new(program);
    command.args(["--headless", "--connect"]).arg(path).arg("--out").arg(out).args(args);
    harness::pin_software_stack(&mut command);
    if let Some(uid) = uid {
        use std::os::unix::process::CommandExt as _;
        command.uid(uid).gid(uid);
    }
    command.stdout(Stdio::null()).stderr(Stdio::piped());
    command
}

/// How a liar breaks the protocol, on a connection of its own; whether it then stays to hear
/// the renderer's refusal (one that hangs up cannot).
type Lie = fn(&Client) -> bool;

/// The liars, each with what the renderer's reason must say (any of several, split by `|`: a
/// renderer that offers semaphores takes what this one is refused for).
fn liars() -> Vec<(&'static str, Lie, &'static str)> {
    vec![
        (
            "truncated",
            |c| {
                c.send(b"VKGL");
                true
            },
            "truncated: 4 bytes, a header alone is 12",
        ),
        (
            "oversized",
            |c| {
                c.send(&[7u8; 40_000]);
                true
            },
            "a message longer than 32782 bytes",
        ),
        (
            "wrong magic",
            |c| {
                c.send(&[b"GLVK".as_slice(), &[3, 0, 5, 0, 0, 0, 0, 0]].concat());
                true
            },
            "not a message of this program",
        ),
        (
            "wrong version",
            |c| {
                c.send(&[b"VKGL".as_slice(), &[99, 0, 5, 0, 0, 0, 0, 0]].concat());
                true
            },
            "protocol version 99; this program speaks version 3",
        ),
        (
            "unknown kind",
            |c| {
                c.send(&message(77, &[]));
                true
            },
            "unknown kind 77",
        ),
        (
            "a length that lies",
            |c| {
                c.send(&[message(READY, &[]), vec![1, 2, 3]].concat());
                true
            },
            "Ready: the header says 0 body bytes, 3 came",
        ),
        (
            "out of order",
            |c| {
                c.send(&message(READY, &[]));
                true
            },
            "the viewer answered Hello with Ready",
        ),
        (
            "a summary first",
            |c| {
                c.send(&message(SUMMARY, b"\x02\x00{}"));
                true
            },
            "the viewer answered Hello with Summary",
        ),
        (
            "UUIDs that lie",
            |c| {
                c.send(&welcome(&[0xAB; 16], &[0xCD; 16], 0, "a GPU that is not yours"));
                true
            },
            "is not our Vulkan (",
        ),
        (
            "an fd where none goes",
            |c| {
                let (device, driver, _, _) = c.hello();
                c.send_with_fds(&welcome(&device, &driver, 0, "with an fd"), &[stray_fd().as_fd()]);
                true
            },
            "Welcome carries 0 fd(s), not 1",
        ),
        (
            "eight fds",
            |c| {
                let fd = stray_fd();
                c.send_with_fds(&message(READY, &[]), &[fd.as_fd(); 8]);
                true
            },
            "a message with more fds than any carries",
        ),
        (
            "semaphores not offered",
            |c| {
                let (device, driver, _, offered) = c.hello();
                if !offered {
                    c.send(&welcome(&device, &driver, 1, "takes what was not offered"));
                }
                true
            },
            "semaphores that were not offered|fell silent during the handshake",
        ),
        ("silent", |_| true, "hung up or fell silent during the handshake"),
        ("hangs up at once", |_| false, "the viewer hung up"),
        (
            "the slots answered out of order",
            |c| {
                c.through_the_slots();
                c.send(&message(PONG, &0u64.to_le_bytes()));
                true
            },
            "the viewer answered the slots with Pong",
        ),
        (
            "silent after the slots",
            |c| {
                c.through_the_slots();
                true
            },
            "hung up or fell silent while importing the slots",
        ),
        (
            "a Pong that lies",
            |c| {
                c.through_the_slots();
                c.send(&message(READY, &[]));
                let _ = c.recv(); // Ping 0
                c.send(&message(PONG, &9u64.to_le_bytes()));
                true
            },
            "the viewer answered Ping 0 with Pong",
        ),
        (
            "the wrong slot freed",
            |c| {
                c.through_the_pings(); // frame 0 in slot 0 is out
                let _ = c.recv(); // frame 1, in slot 1
                c.send(&message(SLOT_FREE, &[1u32.to_le_bytes().as_slice(), &[0; 8]].concat()));
                true
            },
            "the viewer freed slot 1, not the oldest sent",
        ),
    ]
}

/// A process's open fds (what each points at, sorted) and resident memory (KiB), read from
/// outside, in `/proc`.
fn resources_of(pid: u32) -> (Vec<String>, u64) {
    let mut fds: Vec<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .flatten()
        .filter_map(|fd| std::fs::read_link(fd.path()).ok())
        .map(|target| target.display().to_string())
        .collect();
    fds.sort();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let rss = status.lines().find_map(|l| l.strip_prefix("VmRSS:")).unwrap();
    (fds, rss.trim().trim_end_matches(" kB").trim().parse().unwrap())
}

/// The renderer's fds once they are `baseline`'s again (it closes a refused client's socket
/// just after the client hears why), or what they are after 10 s; and its resident memory.
fn settled(pid: u32, baseline: &[String]) -> (Vec<String>, u64) {
    let started = std::time::Instant::now();
    loop {
        let now = resources_of(pid);
        if now.0 == baseline || started.elapsed() > Duration::from_secs(10) {
            return now;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Clients that lie to a listening renderer, each on its own connection, many at once, then
/// each class again one at a time, and one of another user: each is refused, told why where
/// its socket still takes a message, and counted. The honest viewer that comes next is served
/// every frame and every check passes. The renderer's fds, read from outside, are back where
/// they were before the first liar, and its memory where it was after the first batch. More
/// liars than `--restarts` allows deaths: no number stops it.
#[test]
fn ch14_a_listening_renderer_refuses_liars_and_serves_the_next_viewer() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("vkgl.sock");
    let args = ["--frames", "5", "--timeout", "5", "--pings", "2", "--restarts", "1"];
    let (mut renderer, stderr) = listener(&path, dir.path(), &args);
    let mode = std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(&path).unwrap().permissions());
    assert_eq!(mode & 0o777, 0o600, "the socket is its user's alone: {mode:o}");

    // What the renderer holds while it waits for its first client, read from outside.
    let (fds_before, _) = resources_of(renderer.id());

    // 1. Every liar at once, then every liar again one at a time.
    let mut heard = Vec::new();
    let lie_to = |path: &Path, lie: Lie| {
        let client = Client::connect(path);
        if lie(&client) { Some(client.refusal()) } else { None }
    };
    let at_once: Vec<_> = liars()
        .into_iter()
        .map(|(name, lie, why)| {
            let path = path.clone();
            std::thread::spawn(move || (name, why, lie_to(&path, lie)))
        })
        .collect();
    heard.extend(at_once.into_iter().map(|liar| liar.join().unwrap()));
    let (fds, warm_rss) = settled(renderer.id(), &fds_before);
    assert_eq!(fds, fds_before, "the renderer's fds after the liars at once");
    for (name, lie, why) in liars() {
        heard.push((name, why, lie_to(&path, lie)));
    }
    for (name, why, refusal) in &heard {
        if let Some(refusal) = refusal {
            assert!(why.split('|').any(|why| refusal.contains(why)), "{name}: told {refusal:?}, not {why:?}");
        }
    }
    let mut refused = heard.len();

    // 2. Another user: the socket's mode keeps it out; where that was loosened, its uid does.
    if rustix::process::getuid().is_root() {
        let nobody = Some(65534);
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
        let kept_out = viewer(&path, dir.path(), &[], nobody).output().unwrap();
        let said = String::from_utf8_lossy(&kept_out.stderr);
        assert_eq!(kept_out.status.code(), Some(2), "{said}");
        assert!(said.contains("no renderer listening at"), "{said}");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o666)).unwrap();
        let stranger = viewer(&path, dir.path(), &[], nobody).output().unwrap();
        let said = String::from_utf8_lossy(&stranger.stderr);
        assert_eq!(stranger.status.code(), Some(2), "{said}");
        // Each side asks the kernel who the other is: the viewer refuses a renderer of another
        // user too, and the renderer counts the stranger (its reason is checked below).
        assert!(said.contains(" runs as uid 0, not this program's uid 65534"), "{said}");
        heard.push(("another user", "runs as uid 65534, not this program's uid 0", None));
        refused += 1;
    } else {
        eprintln!("not root: no other user to connect as; the uid check is not tried");
    }

    // Every fd a liar sent, and every connection, is closed; memory has not grown with them.
    let (fds, rss) = settled(renderer.id(), &fds_before);
    assert_eq!(fds, fds_before, "the renderer's fds after every liar");
    assert!(rss <= warm_rss + 8 * 1024, "the renderer's resident memory grew from {warm_rss} to {rss} KiB");

    // 3. The honest viewer.
    let honest = viewer(&path, dir.path(), &["--timeout", "30"], None).output().unwrap();
    let said = String::from_utf8_lossy(&honest.stderr);
    assert_eq!(honest.status.code(), Some(0), "{said}");
    let mut report = String::new();
    renderer.stdout.take().unwrap().read_to_string(&mut report).unwrap();
    let status = renderer.wait().unwrap();
    let stderr = stderr.join().unwrap();
    assert_eq!(status.code(), Some(0), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&report).unwrap();
    for (name, ok) in report["checks"].as_object().unwrap() {
        assert_eq!(ok, true, "check {name}:\n{stderr}");
    }
    assert_eq!(report["checks"]["no_fd_leaked"], true, "every fd a liar sent was closed");
    assert_eq!(report["checks"]["viewer_every_frame_is_the_one_announced"], true);
    assert_eq!(report["validation"]["errors"], 0, "{stderr}");
    assert_eq!(report["viewers_refused"], refused, "{stderr}");
    assert_eq!(report["restarts"], 0, "a liar is refused, not a viewer lost");
    assert_eq!(report["frames"], 5);
    assert_eq!(report["frames_shown_by_the_last_viewer"], 5, "the frames a liar held are drawn again");
    assert_eq!(stderr.matches("renderer: refused a viewer: ").count(), refused, "{stderr}");
    for (name, why, _) in &heard {
        assert!(why.split('|').any(|why| stderr.contains(why)), "{name}: {why:?} not in\n{stderr}");
    }
    // The deeper page's table of liars quotes these reasons: each is what this run printed.
    let page =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/book/src/14-two-processes-deeper.md"));
    let page = page.unwrap();
    let table = page.split("## What was thrown at the socket").nth(1).unwrap().split("\n## ").next().unwrap();
    let rows: Vec<&str> =
        table.lines().filter(|l| l.starts_with("| ") && !l.starts_with("| the liar")).collect();
    assert_eq!(rows.len(), liars().len() + 1, "a row for each liar, and one for another user");
    for row in rows {
        let said = row.rsplit(" | ").next().unwrap();
        // Where a row gives two (the semaphores row: lavapipe's, then NVIDIA's), either.
        let quoted: Vec<&str> = said.split('`').skip(1).step_by(2).collect();
        let uid_row = quoted.iter().any(|q| q.contains("uid 65534"));
        // The other user's row is only seen when the test can be another user (root).
        if !uid_row || rustix::process::getuid().is_root() {
            assert!(
                quoted.iter().any(|q| stderr.contains(q)),
                "the page quotes {quoted:?}; the renderer said none"
            );
        }
    }
    eprintln!(
        "{refused} liars refused, then the viewer served on {} with sync {}",
        report["vulkan"]["device"], report["sync"]
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// A `--reconnect` viewer whose renderer lies (here, a test playing one: a truncated message,
/// then a Hello of another protocol version) refuses it, saying why, and waits for the next;
/// the real renderer that comes next is served, and the viewer exits 0.
#[test]
fn ch14_a_reconnecting_viewer_refuses_a_lying_renderer() {
    use rustix::net::{AddressFamily, SocketAddrUnix, SocketFlags, SocketType};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("vkgl.sock");
    let fake =
        rustix::net::socket_with(AddressFamily::UNIX, SocketType::SEQPACKET, SocketFlags::CLOEXEC, None)
            .unwrap();
    rustix::net::bind(&fake, &SocketAddrUnix::new(&path).unwrap()).unwrap();
    rustix::net::listen(&fake, 1).unwrap();
    let mut viewer = viewer(&path, dir.path(), &["--reconnect", "--timeout", "30"], None).spawn().unwrap();
    let lies = [b"VKGL".to_vec(), [b"VKGL".as_slice(), &[2, 0, 1, 0, 0, 0, 0, 0]].concat()];
    for lie in &lies {
        let accepted = rustix::net::accept_with(&fake, SocketFlags::CLOEXEC).unwrap();
        let client = Client(accepted);
        client.send(lie);
        assert_eq!(client.recv().map(|(kind, _)| kind), Some(REFUSED), "the viewer says why");
        assert_eq!(client.recv(), None, "and hangs up");
    }
    drop(fake);
    let (renderer, stderr) = listener(&path, dir.path(), &["--frames", "3", "--timeout", "30"]);
    let output = renderer.wait_with_output().unwrap();
    let renderer_said = stderr.join().unwrap();
    assert_eq!(output.status.code(), Some(0), "{renderer_said}");
    let mut said = String::new();
    viewer.stderr.take().unwrap().read_to_string(&mut said).unwrap();
    assert_eq!(viewer.wait().unwrap().code(), Some(0), "{said}");
    assert_eq!(said.matches("viewer: refused the renderer: ").count(), 2, "{said}");
    assert!(said.contains("truncated: 4 bytes, a header alone is 12"), "{said}");
    assert!(said.contains("protocol version 2; this program speaks version 3"), "{said}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["frames_shown_by_the_last_viewer"], 3, "{said}");
    assert_eq!(report["checks"]["viewer_no_fd_leaked"], true, "{said}");
}
