//! Faults the daemon survives: packets from the wrong GameController, publish targets that are missing,
//! refusing, or come and go, oversized datagrams, a model file replaced by a corrupt one, a trigger
//! storm, and frame senders that flood, break off or stop.

use std::io::Write;
use std::net::UdpSocket;
use std::os::unix::net::{UnixDatagram, UnixStream};
use std::time::Duration;

use relocd::protocol::frame_header::FrameHeader;
use relocd::protocol::gamecontroller::Penalty;
use relocd::protocol::message::{Message, TriggerKind};

use crate::harness::{Daemon, sample_yuyv, stream_frames};
use crate::triggers::packet;

/// Neither a second GameController, nor a duplicate, nor an old packet replayed can fake the end of a
/// penalty; the followed GameController's own return is still the trigger, and every ignored packet
/// is counted.
#[test]
fn a_second_gamecontroller_and_replayed_packets_cannot_fake_a_penalty_return() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1"]);
    let settle = || std::thread::sleep(Duration::from_millis(150));
    daemon.send_gamecontroller(&packet(Penalty::None, 20));
    settle();
    // A second GameController says we are picked up, then back: ignored while the first one talks.
    daemon.send_gamecontroller_from("127.0.0.2", &packet(Penalty::RequestForPickup, 21));
    settle();
    daemon.send_gamecontroller_from("127.0.0.2", &packet(Penalty::None, 22));
    // An old packet replayed from the followed address, and a duplicate: ignored too.
    daemon.send_gamecontroller(&packet(Penalty::RequestForPickup, 15));
    settle();
    daemon.send_gamecontroller(&packet(Penalty::RequestForPickup, 20));
    settle();
    daemon.send_gamecontroller(&packet(Penalty::None, 21));
    settle();
    assert_eq!(daemon.status()["triggers"]["penalty_return"], 0, "{}", daemon.status());
    assert_eq!(daemon.status()["rejected"]["gamecontroller"], 4);
    assert_eq!(daemon.status()["game"]["penalty"], "none");

    // The followed GameController's own penalty and return are the kidnap.
    daemon.send_gamecontroller(&packet(Penalty::RequestForPickup, 22));
    settle();
    daemon.send_gamecontroller(&packet(Penalty::None, 23));
    let message = daemon.message();
    assert_eq!(message.triggers[0].kind, TriggerKind::PenaltyReturn);
    assert_eq!(message.triggers[0].reason.as_deref(), Some("request_for_pickup"));
    daemon.stop();
}

/// A Unix publish target that does not exist yet, a UDP target nobody listens on, and a Unix target
/// that vanishes and comes back: each failed delivery is counted, the working targets get every
/// message, and a target that comes back gets the next one.
#[test]
fn publish_targets_that_are_missing_refusing_or_come_and_go_cost_only_their_own_messages() {
    let scratch = tempfile::tempdir().unwrap();
    let unix_target = scratch.path().join("localisation");
    let refusing = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
    let daemon = Daemon::start(
        "replay:{sample}",
        &[
            "--burst",
            "1",
            "--publish",
            &format!("unix:{}", unix_target.display()),
            "--publish",
            &format!("udp:{refusing}"),
        ],
    );
    let relocalise = || {
        let answer = daemon.control(br#"{"relocalise": {}}"#);
        answer["accepted"]["trigger"].as_u64().expect("accepted")
    };
    let answered = |message: &Message, trigger: u64| message.triggers.iter().any(|t| t.id == trigger);

    // The Unix target does not exist yet: the harness's UDP target still gets the message. (Its
    // failure is counted once the daemon has tried every target.)
    let first = relocalise();
    assert!(answered(&daemon.message(), first));
    daemon.status_when(|status| status["publish_errors"].as_u64() >= Some(1));

    // It appears: it gets the next message.
    let listener = UnixDatagram::bind(&unix_target).unwrap();
    listener.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    std::thread::sleep(Duration::from_millis(200)); // past the harness's 100 ms rate limit
    let second = relocalise();
    assert!(answered(&daemon.message(), second));
    let mut buffer = vec![0u8; 65536];
    let length = listener.recv(&mut buffer).unwrap();
    assert!(answered(&Message::decode(&buffer[..length]).unwrap(), second));

    // It vanishes again: nothing else changes.
    drop(listener);
    std::fs::remove_file(&unix_target).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let third = relocalise();
    assert!(answered(&daemon.message(), third));

    let status = daemon.status_when(|status| status["publish_errors"].as_u64() >= Some(2));
    assert_eq!(status["published"], 3, "{status}");
    // Missing twice; the refusing UDP target may fail up to three times (ICMP "port unreachable"
    // reaches an unconnected socket as an error on a later send, or not at all).
    let errors = status["publish_errors"].as_u64().unwrap();
    assert!((2..=5).contains(&errors), "{status}");
    daemon.stop();
}

/// Datagrams over `max_datagram_bytes` are dropped before parsing, even when they would parse, and
/// counted per input; a control request gets the reason back.
#[test]
fn oversized_datagrams_are_dropped_unread_and_counted() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1"]);
    let mut padded = br#"{"relocalise": {}}"#.to_vec();
    padded.resize(20_000, b' ');
    let answer = daemon.control(&padded);
    let error = answer["error"].as_str().unwrap_or_default();
    assert!(error.contains("max_datagram_bytes = 16384"), "{answer}");

    let sender = UnixDatagram::unbound().unwrap();
    sender.send_to(&vec![0x90u8; 20_000], daemon.socket("sensors")).unwrap();
    let mut packet = packet(Penalty::None, 1).to_vec();
    packet.resize(20_000, 0);
    daemon.send_gamecontroller(&packet);
    std::thread::sleep(Duration::from_millis(200));

    let status = daemon.status();
    assert_eq!(status["rejected"]["control"], 1, "{status}");
    assert_eq!(status["rejected"]["sensors"], 1, "{status}");
    assert_eq!(status["rejected"]["gamecontroller"], 1, "{status}");
    assert_eq!(status["triggers"]["request"], 0, "{status}");
    // Requests of a normal size are still answered.
    assert!(daemon.control(br#"{"relocalise": {}}"#)["accepted"]["trigger"].is_u64());
    daemon.message();
    daemon.stop();
}

/// SIGHUP reloads the model file: a corrupt replacement leaves the running model in place and
/// `status` says why; a valid one is used from the next burst.
#[test]
fn sighup_keeps_the_running_model_over_a_corrupt_file_and_loads_a_valid_one() {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let scratch = tempfile::tempdir().unwrap();
    let file = scratch.path().join("model.onnx");
    std::fs::copy(models.join("squeezenet-half-point.w8.onnx"), &file).unwrap();
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1", "--model", file.to_str().unwrap()]);
    assert_eq!(daemon.status()["model"], "squeezenet-half-point-w8-v3");

    std::fs::write(&file, b"not an ONNX file at all").unwrap();
    daemon.hang_up();
    let status = daemon.status_when(|status| status["model_error"].is_string());
    assert!(status["model_error"].as_str().unwrap().contains("is not an ONNX file"), "{status}");
    assert_eq!(status["model"], "squeezenet-half-point-w8-v3");
    assert!(daemon.control(br#"{"relocalise": {}}"#)["accepted"]["trigger"].is_u64());
    let message = daemon.message();
    assert_eq!(message.model.id, "squeezenet-half-point-w8-v3");
    assert!(message.failure.is_none());

    std::fs::copy(models.join("squeezenet-half-point.fp32.onnx"), &file).unwrap();
    daemon.hang_up();
    daemon.status_when(|status| {
        status["model"] == "squeezenet-half-point-fp32-v3" && status["model_error"].is_null()
    });
    std::thread::sleep(Duration::from_millis(200)); // past the harness's 100 ms rate limit
    assert!(daemon.control(br#"{"relocalise": {}}"#)["accepted"]["trigger"].is_u64());
    assert_eq!(daemon.message().model.id, "squeezenet-half-point-fp32-v3");
    daemon.stop();
}

/// A storm of requests and a flapping penalty at once: bursts stay rate-limited, and every trigger is
/// answered by a message, its own or (beyond the 64 that wait) that of the waiting trigger the control
/// answer names. Nothing is refused or lost: every trigger counted either started a burst or is
/// counted as coalesced into one.
#[test]
fn a_trigger_storm_is_answered_in_full_by_a_bounded_number_of_bursts() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "1"]);
    let mut awaited = std::collections::BTreeSet::new();
    let mut joined = 0;
    for request in 0..300u32 {
        if request % 6 == 0 {
            let penalty = if request % 12 == 0 { Penalty::RequestForPickup } else { Penalty::None };
            daemon.send_gamecontroller(&packet(penalty, (request / 6) as u8));
        }
        let accepted = &daemon.control(br#"{"relocalise": {"reason": "storm"}}"#)["accepted"];
        let trigger = accepted["trigger"].as_u64().expect("every request is accepted");
        if let Some(into) = accepted["coalesced_into"].as_u64() {
            assert!(into < trigger, "joins an earlier trigger");
            joined += 1;
            awaited.insert(into);
        } else {
            awaited.insert(trigger);
        }
    }
    assert!(joined > 0, "300 requests at once should overflow the queue of 64");

    let mut messages = 0;
    while !awaited.is_empty() {
        for trigger in &daemon.message().triggers {
            awaited.remove(&trigger.id);
        }
        messages += 1;
    }
    // The last penalty returns may still be waiting for a burst of their own.
    let status = daemon.status_when(|status| {
        let counted: u64 = ["request", "penalty_return", "fall", "pick_up"]
            .iter()
            .map(|kind| status["triggers"][kind].as_u64().unwrap())
            .sum();
        counted == status["bursts"].as_u64().unwrap() + status["coalesced"].as_u64().unwrap()
    });
    assert_eq!(status["triggers"]["request"], 300);
    assert_eq!(status["triggers"]["penalty_return"], 25, "{status}");
    assert!(messages < 30, "{messages} bursts for a storm: they should share");
    daemon.stop();
}

/// Forwarded frames: a sender that stops mid-frame costs that frame; a flood keeps the newest
/// `frames.queue` frames and counts the rest; a camera that stops mid-burst gives a burst of the frames
/// that came, the next trigger with no frames gets a failure message, and frames that come back are
/// used for the one after.
#[test]
fn a_frame_sender_that_floods_breaks_off_or_stops_costs_only_its_own_frames() {
    let daemon = Daemon::start("frames:unix:{dir}/frames", &["--burst", "3"]);
    let frames = daemon.socket("frames");
    let image = sample_yuyv();
    let header = FrameHeader { width: image.width(), height: image.height(), timestamp: 1.0, camera: None };
    let frame = [&header.to_bytes()[..], image.as_bytes()].concat();

    // Half a frame, then the connection closes.
    let mut broken = UnixStream::connect(&frames).unwrap();
    broken.write_all(&frame[..frame.len() / 2]).unwrap();
    drop(broken);
    // A flood: 40 frames as fast as the socket takes them, more than the queue of 8 holds.
    let mut flood = UnixStream::connect(&frames).unwrap();
    for _ in 0..40 {
        flood.write_all(&frame).unwrap();
    }
    drop(flood);
    let status = daemon.status_when(|status| status["frames_dropped"].as_u64() >= Some(32));
    assert_eq!(status["rejected"]["frames"], 1, "the broken frame: {status}");

    // The camera delivers one frame of the burst of 3 and stops: the burst uses what came.
    let sent = frame.clone();
    let path = frames.clone();
    let one_frame = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        UnixStream::connect(&path).unwrap().write_all(&sent).unwrap();
    });
    daemon.control(br#"{"relocalise": {}}"#);
    let partial = daemon.message();
    one_frame.join().unwrap();
    assert_eq!((partial.frames.requested, partial.frames.used), (3, 1), "{:?}", partial.failure);
    assert!(partial.failure.is_none());

    // No frames at all: a failure message for this trigger...
    daemon.control(br#"{"relocalise": {}}"#);
    let failed = daemon.message();
    assert!(failed.failure.as_deref().unwrap_or_default().contains("no frame"), "{:?}", failed.failure);

    // ...and frames that come back are used for the next one.
    let sender = stream_frames(UnixStream::connect(&frames).unwrap(), frame, 30, Duration::from_millis(40));
    std::thread::sleep(Duration::from_millis(100));
    daemon.control(br#"{"relocalise": {}}"#);
    let recovered = daemon.message();
    assert_eq!(recovered.frames.used, 3, "{:?}", recovered.failure);
    sender.join().unwrap();
    daemon.stop();
}
