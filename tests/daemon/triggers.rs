//! Every trigger and input path of the daemon: GameController, LoLA sensors, control requests,
//! forwarded frames, bad input and bad config.

use std::io::Write;
use std::os::unix::net::{UnixDatagram, UnixStream};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use relocd::geometry::CameraPose;
use relocd::protocol::frame_header::FrameHeader;
use relocd::protocol::gamecontroller::{
    GameControlData, GamePhase, GameState, MAX_PLAYERS, Penalty, RobotInfo, SetPlay, TeamInfo,
};
use relocd::protocol::message::TriggerKind;
use relocd::recording::Recording;

use crate::harness::{Daemon, PLAYER, TEAM, sample, sample_yuyv, stream_frames};

/// How far the burst's best hypothesis may lie from the rendered robot (the model's median is
/// ~0.4 m per frame, 0.25 m for penalty-return bursts).
const ACCEPTED_ERROR_M: f64 = 1.0;

/// Renders a burst of five frames of a robot put back after a penalty; returns its true pose.
fn render_penalty_return(out: &Path) -> relocd::geometry::FieldPose {
    let status = Command::new(env!("CARGO_BIN_EXE_relocd"))
        .args(["render", "--out", out.to_str().unwrap(), "--count", "5", "--burst", "5"])
        .args(["--poses", "penalty-return", "--seed", "11", "--width", "320", "--height", "240"])
        .args(["--supersample", "1"])
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
    Recording::open(out).unwrap().records()[0].pose.unwrap()
}

/// A GameController packet in which our player has `penalty`.
pub fn packet(penalty: Penalty, packet_number: u8) -> [u8; 118] {
    let team = |number: u8| TeamInfo {
        team_number: number,
        field_player_colour: 0,
        goalkeeper_colour: 1,
        goalkeeper: 1,
        score: 0,
        penalty_shot: 0,
        single_shots: 0,
        message_budget: 1200,
        players: [RobotInfo { penalty: Penalty::None, secs_till_unpenalised: 0 }; MAX_PLAYERS],
    };
    let mut ours = team(TEAM);
    ours.players[usize::from(PLAYER) - 1].penalty = penalty;
    GameControlData {
        packet_number,
        players_per_team: 7,
        competition_phase: 0,
        competition_type: 0,
        game_phase: GamePhase::Normal,
        state: GameState::Playing,
        set_play: SetPlay::None,
        first_half: true,
        kicking_team: Some(TEAM),
        secs_remaining: 300,
        secondary_time: 0,
        teams: [ours, team(12)],
    }
    .to_bytes()
}

#[test]
fn a_penalty_return_is_answered_with_the_own_half_hypothesis() {
    let rendered = tempfile::tempdir().unwrap();
    let truth = render_penalty_return(&rendered.path().join("rec"));
    let daemon = Daemon::start(&format!("replay:{}", rendered.path().join("rec").display()), &[]);

    daemon.send_gamecontroller(&packet(Penalty::PlayerPushing, 1));
    // A repeated penalty changes nothing; its end is the kidnap.
    daemon.send_gamecontroller(&packet(Penalty::PlayerPushing, 2));
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(daemon.status()["game"]["penalty"], "player_pushing");
    daemon.send_gamecontroller(&packet(Penalty::None, 3));

    let message = daemon.message();
    assert_eq!(message.triggers.len(), 1);
    assert_eq!(message.triggers[0].kind, TriggerKind::PenaltyReturn);
    assert_eq!(message.triggers[0].reason.as_deref(), Some("player_pushing"));
    assert!(message.prior.as_deref().is_some_and(|prior| prior.starts_with("penalty_return")));
    assert_eq!((message.frames.requested, message.frames.used), (5, 5));
    assert!(message.failure.is_none());
    let best = message.hypotheses[0];
    assert!(best.x < 0.0, "the prior picks the own half: {best:?}");
    assert!(best.weight > 0.9 - 1e-9, "all the floor allows: {:?}", message.hypotheses);
    let error = (best.x - truth.x()).hypot(best.y - truth.y());
    assert!(error < ACCEPTED_ERROR_M, "best {best:?} is {error:.2} m from the truth {truth:?}");
    assert!(message.latency_ms.total >= message.latency_ms.capture);
    daemon.stop();
}

#[test]
fn a_fall_a_pick_up_and_a_request_are_each_answered() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "3"]);
    daemon.send_sensors(0.5, [0.0, 0.0], 1.3);
    daemon.send_sensors(0.5, [0.0, 1.5], 0.0);
    daemon.send_sensors(1.5, [0.0, 0.0], 1.3);
    let fall = daemon.message();
    assert_eq!(fall.triggers[0].kind, TriggerKind::Fall);
    assert_eq!(fall.prior, None, "only a penalty return has a placement prior");
    assert_eq!(fall.hypotheses.len(), 2, "half-point: a pose and its point-symmetric twin");

    daemon.send_sensors(1.0, [0.0, 0.1], 0.0);
    daemon.send_sensors(1.5, [0.0, 0.0], 1.3);
    let pick_up = daemon.message();
    assert_eq!(pick_up.triggers[0].kind, TriggerKind::PickUp);
    assert_eq!(pick_up.seq, fall.seq + 1);

    let answer = daemon.control(br#"{"relocalise": {"reason": "uncertain", "head_yaw": 0.3}}"#);
    let id = answer["accepted"]["trigger"].as_u64().expect("the request is accepted with an id");
    let request = daemon.message();
    assert_eq!(request.triggers[0].id, id);
    assert_eq!(request.triggers[0].reason.as_deref(), Some("uncertain"));
    assert_eq!(request.frames.used, 3);
    let status = daemon.status();
    assert_eq!(status["triggers"]["fall"], 1);
    assert_eq!(status["triggers"]["pick_up"], 1);
    assert_eq!(status["bursts"], 3);
    daemon.stop();
}

#[test]
fn lola_s_own_socket_is_read_as_a_stream() {
    let dir = tempfile::tempdir().unwrap();
    let lola = std::os::unix::net::UnixListener::bind(dir.path().join("robocup")).unwrap();
    let lola_path = dir.path().join("robocup");
    let daemon = Daemon::start(
        "replay:{sample}",
        &["--burst", "1", "--sensors", &format!("lola:{}", lola_path.display())],
    );
    lola.set_nonblocking(true).unwrap();
    let started = Instant::now();
    let mut stream = loop {
        match lola.accept() {
            Ok((stream, _)) => break stream,
            Err(_) if started.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(error) => panic!("relocd did not connect to LoLA: {error}"),
        }
    };
    stream.set_nonblocking(false).unwrap();
    let message = |angles: [f32; 2], fsr: f32| {
        let state = serde_json::json!({"Angles": angles, "Gyroscope": [0.0, 0.0, 0.0], "FSR": vec![fsr; 8]});
        rmp_serde::to_vec_named(&state).unwrap()
    };
    // LoLA's stream has no framing: messages back to back, split anywhere.
    let (standing, lying) = (message([0.0, 0.0], 1.3), message([0.0, 1.5], 0.0));
    for (state, cycles) in [(&standing, 40), (&lying, 80), (&standing, 150)] {
        for _ in 0..cycles {
            let (head, tail) = state.split_at(7);
            stream.write_all(head).unwrap();
            stream.write_all(tail).unwrap();
            std::thread::sleep(Duration::from_millis(12));
        }
    }
    assert_eq!(daemon.message().triggers[0].kind, TriggerKind::Fall);
    daemon.stop();
}

#[test]
fn bad_input_is_refused_and_the_daemon_keeps_answering() {
    let daemon = Daemon::start("replay:{sample}", &["--burst", "2", "--encoding", "msgpack"]);
    let good = packet(Penalty::None, 1);
    let mut wrong_header = good;
    wrong_header[..4].copy_from_slice(b"RGrt");
    let mut old_version = good;
    old_version[4] = 17;
    for bytes in [&good[..60], &wrong_header[..], &old_version[..], &[0u8; 500][..]] {
        daemon.send_gamecontroller(bytes);
    }
    let garbage = UnixDatagram::unbound().unwrap();
    for bytes in [&b"\xc1\xc1"[..], b"{}", &[0x80u8][..]] {
        garbage.send_to(bytes, daemon.socket("sensors")).unwrap();
    }
    for request in [&b"{\"relocalise\": 5}"[..], b"\xff\xfe", b"{\"status\": {}, \"relocalise\": {}}"] {
        assert!(daemon.control(request)["error"].is_string());
    }

    let answer = daemon.control(br#"{"relocalise": {}}"#);
    assert!(answer["accepted"]["trigger"].is_u64());
    let message = daemon.message();
    assert_eq!(message.triggers[0].kind, TriggerKind::Request);
    let status = daemon.status();
    assert_eq!(status["rejected"]["gamecontroller"], 4);
    assert_eq!(status["rejected"]["sensors"], 3);
    assert_eq!(status["rejected"]["control"], 3);
    daemon.stop();
}

#[test]
fn forwarded_frames_are_used_and_a_lying_header_is_dropped() {
    let daemon = Daemon::start("frames:unix:{dir}/frames", &["--burst", "2"]);
    let frames = daemon.socket("frames");

    // Nothing forwarded yet: the request is answered with a failure, not silence.
    daemon.control(br#"{"relocalise": {"reason": "no camera"}}"#);
    let failed = daemon.message();
    assert!(failed.hypotheses.is_empty());
    assert!(failed.failure.as_deref().unwrap().contains("no frame"), "{:?}", failed.failure);

    // A header whose size does not match its payload closes that connection.
    let mut liar = UnixStream::connect(&frames).unwrap();
    let mut header = FrameHeader { width: 640, height: 480, timestamp: 1.0, camera: None }.to_bytes();
    header[16..20].copy_from_slice(&1000u32.to_le_bytes());
    // relocd may close the connection after the header: the write's result does not matter.
    let _ = liar.write_all(&[&header[..], &[0u8; 1000]].concat());

    let image = sample_yuyv();
    let camera = Recording::open(&sample()).unwrap().records()[0].camera.unwrap_or(CameraPose::STANDING);
    let header =
        FrameHeader { width: image.width(), height: image.height(), timestamp: 2.0, camera: Some(camera) };
    let mut stream = UnixStream::connect(&frames).unwrap();
    // An impossible camera pitch drops that frame but keeps the connection in step.
    let mut tilted = header.to_bytes();
    tilted[36..40].copy_from_slice(&3.0f32.to_le_bytes());
    stream.write_all(&[&tilted[..], image.as_bytes()].concat()).unwrap();
    let frame = [&header.to_bytes()[..], image.as_bytes()].concat();
    let sender = stream_frames(stream, frame, 40, Duration::from_millis(50));
    std::thread::sleep(Duration::from_millis(200));
    daemon.control(br#"{"relocalise": {}}"#);
    let message = daemon.message();
    assert_eq!(message.frames.used, 2, "{:?}", message.failure);
    // The network's two twins, or every place the lines fit and its twin.
    let count = message.hypotheses.len();
    assert!(count >= 2 && count % 2 == 0, "{count} hypotheses");
    assert_eq!(daemon.status()["rejected"]["frames"], 2, "the lying header and the tilted frame");
    sender.join().unwrap();
    daemon.stop();
}

/// `--model none`: no network, the lines alone place the robot (and its point twin); the message and
/// `status` name no model, and SIGHUP has none to reload.
#[test]
fn with_no_network_the_lines_alone_place_the_robot() {
    let daemon = Daemon::start("frames:unix:{dir}/frames", &["--burst", "1", "--model", "none"]);
    assert_eq!(daemon.status()["model"], "none");
    let recording = Recording::open(&sample()).unwrap();
    let record = &recording.records()[0];
    let image = sample_yuyv();
    let camera = record.camera.unwrap_or(CameraPose::STANDING);
    let header =
        FrameHeader { width: image.width(), height: image.height(), timestamp: 1.0, camera: Some(camera) };
    let frame = [&header.to_bytes()[..], image.as_bytes()].concat();
    let stream = UnixStream::connect(daemon.socket("frames")).unwrap();
    let sender = stream_frames(stream, frame, 40, Duration::from_millis(50));
    std::thread::sleep(Duration::from_millis(200));
    daemon.hang_up();
    daemon.control(br#"{"relocalise": {"reason": "no network for this hall yet"}}"#);
    let message = daemon.message();
    assert!(message.failure.is_none(), "{:?}", message.failure);
    assert_eq!(message.model.id, "none");
    let count = message.hypotheses.len();
    assert!(count >= 2 && count % 2 == 0, "every place and its twin: {count} hypotheses");
    assert!(message.hypotheses.iter().all(|hypothesis| hypothesis.lines.is_some()));
    // The sample's first frame shows lines that fix the pose but for the point symmetry.
    let truth = record.pose.unwrap();
    let off = |x: f64, y: f64| (x - truth.x()).hypot(y - truth.y()).min((x + truth.x()).hypot(y + truth.y()));
    assert!(message.hypotheses.iter().any(|h| off(h.x, h.y) < 0.1), "{:?}", message.hypotheses);
    assert_eq!(daemon.status()["model"], "none", "SIGHUP loaded nothing");
    sender.join().unwrap();
    daemon.stop();
}

#[test]
fn the_head_yaw_the_sensors_report_turns_the_published_heading() {
    let daemon = Daemon::start("frames:unix:{dir}/frames", &["--burst", "1", "--no-refine"]);
    let image = sample_yuyv();
    // Frames without a camera pose: relocd takes it from the sensors, or else from the config.
    let header = FrameHeader { width: image.width(), height: image.height(), timestamp: 1.0, camera: None };
    let frame = [&header.to_bytes()[..], image.as_bytes()].concat();
    let stream = UnixStream::connect(daemon.socket("frames")).unwrap();
    let sender = stream_frames(stream, frame, 80, Duration::from_millis(50));
    std::thread::sleep(Duration::from_millis(200));
    daemon.control(br#"{"relocalise": {}}"#);
    let ahead = daemon.message();

    let head_yaw = 0.5;
    let turned = std::thread::scope(|scope| {
        scope.spawn(|| daemon.send_sensors_with_head(1.5, [head_yaw as f32, 0.1]));
        std::thread::sleep(Duration::from_millis(300));
        daemon.control(br#"{"relocalise": {}}"#);
        daemon.message()
    });
    assert!(ahead.failure.is_none() && turned.failure.is_none(), "{:?} {:?}", ahead.failure, turned.failure);
    assert_eq!(ahead.hypotheses.len(), turned.hypotheses.len());
    // The same image: the same camera heading, so the robot's heading is the head yaw less.
    for hypothesis in &turned.hypotheses {
        let twin = ahead
            .hypotheses
            .iter()
            .find(|other| (other.x - hypothesis.x).hypot(other.y - hypothesis.y) < 1e-3);
        let twin = twin.unwrap_or_else(|| panic!("{hypothesis:?} is not among {:?}", ahead.hypotheses));
        let turn = relocd::geometry::normalize_angle(twin.theta - hypothesis.theta);
        assert!((turn - head_yaw).abs() < 1e-3, "heading turned by {turn}, expected {head_yaw}");
    }
    sender.join().unwrap();
    daemon.stop();
}

#[test]
fn a_bad_config_is_refused_with_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("relocd.toml");
    std::fs::write(&config, "[burst]\nframes = 99\n").unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_relocd"))
        .args(["run", "--config", config.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("burst.frames"), "{stderr}");

    let output = Command::new(env!("CARGO_BIN_EXE_relocd"))
        .args(["run", "--source", "webcam", "--control", "off"])
        .output()
        .unwrap();
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("unknown frame source"));
}

#[cfg(feature = "v4l")]
#[test]
fn a_camera_that_cannot_be_opened_gives_a_failure_message() {
    let daemon = Daemon::start("v4l:{dir}/no-such-camera", &[]);
    daemon.control(br#"{"relocalise": {}}"#);
    let message = daemon.message();
    assert!(message.hypotheses.is_empty());
    let failure = message.failure.unwrap();
    assert!(failure.contains("no-such-camera") && failure.contains("cannot open"), "{failure}");
    // Still up: a status request is answered.
    assert_eq!(daemon.status()["failures"], 1);
    daemon.stop();
}

#[cfg(not(feature = "v4l"))]
#[test]
fn without_the_v4l_feature_a_camera_source_says_how_to_get_one() {
    let output = Command::new(env!("CARGO_BIN_EXE_relocd"))
        .args(["run", "--source", "v4l:/dev/video-top", "--control", "off", "--sensors", "off"])
        .output()
        .unwrap();
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("--features v4l"));
}

#[test]
fn the_simulated_camera_relocalises_without_any_files() {
    let daemon = Daemon::start("sim", &["--burst", "2"]);
    daemon.control(br#"{"relocalise": {"reason": "demo"}}"#);
    let message = daemon.message();
    assert_eq!(message.frames.used, 2, "{:?}", message.failure);
    // The half-field network's point-symmetric twins, or the places the lines found and theirs.
    let hypotheses = message.hypotheses.len();
    assert!(hypotheses >= 2 && hypotheses % 2 == 0, "{hypotheses} hypotheses");
    assert!(message.captured.is_some());
    daemon.stop();
}
