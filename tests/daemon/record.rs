//! `relocd record`: frames forwarded by a team's process, or simulated, become a recording that
//! `relocd replay` reads.

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use relocd::geometry::CameraPose;
use relocd::protocol::frame_header::FrameHeader;
use relocd::recording::Recording;

use crate::harness::sample_yuyv;

fn relocd(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_relocd"));
    command.args(args);
    command
}

fn replay(recording: &Path) -> Output {
    relocd(&["replay", recording.to_str().unwrap()]).output().unwrap()
}

#[test]
fn forwarded_frames_are_recorded_with_their_times_and_camera_poses() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("frames");
    let out = dir.path().join("recorded");
    let mut recorder = relocd(&["record", "--out", out.to_str().unwrap(), "--count", "4", "--fps", "4"])
        .args(["--seconds", "30"])
        .args(["--source", &format!("frames:unix:{}", socket.display())])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();

    let started = Instant::now();
    let mut stream = loop {
        match UnixStream::connect(&socket) {
            Ok(stream) => break stream,
            Err(_) if started.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(error) => panic!("relocd record does not listen on {}: {error}", socket.display()),
        }
    };
    let image = sample_yuyv();
    let camera = CameraPose::new(0.48, 0.3, 0.01, -0.2).unwrap();
    let header =
        FrameHeader { width: image.width(), height: image.height(), timestamp: 5.0, camera: Some(camera) };
    // Frames at ~30 Hz until the recorder has its four and goes away.
    while recorder.try_wait().unwrap().is_none() && started.elapsed() < Duration::from_secs(30) {
        if stream.write_all(&header.to_bytes()).and_then(|()| stream.write_all(image.as_bytes())).is_err() {
            break;
        }
        std::thread::sleep(Duration::from_millis(33));
    }
    let output = recorder.wait_with_output().unwrap();
    assert!(output.status.success());
    let summary: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(summary["frames"], 4);

    let recording = Recording::open(&out).unwrap();
    let records = recording.records();
    assert_eq!(records.len(), 4);
    for pair in records.windows(2) {
        let gap = pair[1].t - pair[0].t;
        assert!(gap >= 0.2, "frames kept at most 4 per second: {gap} s apart");
    }
    assert!(records[0].t > 1.0e9, "capture times are Unix seconds: {}", records[0].t);
    assert_eq!((records[0].width, records[0].height), (Some(640), Some(480)));
    assert!(records[0].file.ends_with(".yuyv"));
    let recorded_camera = records[0].camera.expect("the forwarded camera pose is kept");
    assert!((recorded_camera.head_yaw() - camera.head_yaw()).abs() < 1e-6);
    assert_eq!(recording.load_frame(&records[0]).unwrap().to_rgb(), image.to_rgb());

    let replayed = replay(&out);
    assert!(replayed.status.success(), "{}", String::from_utf8_lossy(&replayed.stderr));
    assert_eq!(String::from_utf8_lossy(&replayed.stdout).lines().count(), 4);
}

#[test]
fn simulated_frames_are_recorded_with_their_true_poses() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let output = relocd(&["record", "--source", "sim", "--out", out.to_str().unwrap(), "--count", "2"])
        .args(["--fps", "30", "--format", "png"])
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let recording = Recording::open(&out).unwrap();
    assert_eq!(recording.records().len(), 2);
    assert!(recording.records().iter().all(|record| record.pose.is_some() && record.file.ends_with(".png")));
    assert!(replay(&out).status.success());

    // The same directory again is refused, not overwritten.
    let again = relocd(&["record", "--source", "sim", "--out", out.to_str().unwrap(), "--count", "1"])
        .output()
        .unwrap();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("already holds a recording"));
    let nothing = relocd(&["record", "--source", "sim", "--out", "z", "--count", "0"]).output().unwrap();
    assert!(String::from_utf8_lossy(&nothing.stderr).contains("nothing to record"));
    let replay_source = relocd(&["record", "--source", "replay:x", "--out", "y"]).output().unwrap();
    assert!(String::from_utf8_lossy(&replay_source.stderr).contains("already recorded"));
}

#[test]
fn a_camera_that_cannot_be_opened_stops_the_recording_with_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let camera = dir.path().join("no-such-camera");
    let output = relocd(&["record", "--source", &format!("v4l:{}", camera.display()), "--count", "1"])
        .args(["--out", dir.path().join("rec").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    let expected = if cfg!(feature = "v4l") { "cannot open" } else { "--features v4l" };
    assert!(stderr.contains("no-such-camera") && stderr.contains(expected), "{stderr}");
}
