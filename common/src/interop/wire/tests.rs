//! Chapter 14's wire, tested: every kind round-trips, with its fd, through a real socket;
//! malformed messages are refused by name; the decoder survives fuzzing; no fd is left open.

use super::*;
use std::os::fd::{AsFd, BorrowedFd};
use std::time::Duration;

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
        semaphores: true,
    }
}

fn every_kind() -> Vec<Message> {
    vec![
        Message::Hello(hello()),
        Message::Welcome {
            device_uuid: [3; 16],
            driver_uuid: [4; 16],
            renderer: "llvmpipe".into(),
            semaphores: false,
        },
        Message::Refused { reason: "GL runs on another device".into() },
        Message::Slot { slot: 1, memory_size: 4096 },
        Message::Ready,
        Message::FrameReady { frame: u64::MAX, slot: 15 },
        Message::SlotFree { slot: 0, sent_ns: 123_456_789 },
        Message::SlotSemaphore { slot: 3 },
        Message::Ping { n: 7 },
        Message::Pong { n: 7 },
        Message::Bye,
        Message::Closed,
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
    crate::instruments::resources::open_fds().iter().filter(|fd| fd.contains(tag)).count()
}

#[test]
fn every_kind_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for message in every_kind() {
        let fds = match message {
            Message::Slot { .. } | Message::SlotSemaphore { .. } => {
                vec![tagged_fd(dir.path(), "round-trip", 4096)]
            }
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
        let carries = matches!(message, Message::Slot { .. } | Message::SlotSemaphore { .. });
        let fd = carries.then(|| tagged_fd(dir.path(), "socket-fd", 4096));
        let fds: Vec<BorrowedFd> = fd.iter().map(|f| f.as_fd()).collect();
        assert!(a.send(&message, &fds).unwrap());
        drop(fd); // ours: closed; the receiver has its own
        let Received::Message(got, fd) = b.recv().unwrap() else { panic!("no message") };
        assert_eq!(got, message);
        if let Some(fd) = fd {
            check_memory_fd(fd, 4096).unwrap(); // a file stands in for both kinds here
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
    assert!(with(&|b| b[4] = 1).contains("protocol version 1; this program speaks version 3"));
    assert!(with(&|b| b[6] = 99).contains("unknown kind 99"));
    assert!(with(&|b| b[6] = 14).contains("unknown kind 14"));
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
    // The semaphores flag, just before the device name's length and bytes.
    let mut flag = valid.clone();
    let at = flag.len() - 2 - hello().device.len() - 4;
    flag[at] = 2;
    assert!(decode(&flag, vec![]).unwrap_err().to_string().contains("semaphores is 2: 0 or 1"));
    let slot = |s: u32| encode(&Message::SlotFree { slot: s, sent_ns: 0 });
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
    let semaphore = encode(&Message::SlotSemaphore { slot: 0 });
    assert!(decode(&semaphore, vec![]).unwrap_err().to_string().contains("carries 1 fd(s), not 0"));
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
    let file = check_semaphore_fd(tagged_fd(dir.path(), "not-a-semaphore", 8)).unwrap_err();
    assert!(file.to_string().contains("not a semaphore"), "{file}");
    let (c, _d) = socketpair().unwrap();
    assert!(check_semaphore_fd(c.fd).unwrap_err().to_string().contains("not a semaphore"));
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
