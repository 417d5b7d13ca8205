//! `relocd run` end to end: a real daemon on loopback sockets, real GameController packets, LoLA
//! sensor messages, control requests and forwarded frames; the published messages are decoded with
//! the library's reference decoder.

use std::io::Write;
use std::net::UdpSocket;
use std::os::unix::net::{UnixDatagram, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use relocd::frame::YuyvImage;
use relocd::geometry::CameraPose;
use relocd::protocol::frame_header::FrameHeader;
use relocd::protocol::gamecontroller::{
    GameControlData, GamePhase, GameState, MAX_PLAYERS, Penalty, RobotInfo, SetPlay, TeamInfo,
};
use relocd::protocol::message::{Message, TriggerKind};
use relocd::recording::Recording;

const TEAM: u8 = 5;
const PLAYER: u8 = 2;
/// How far the burst's best hypothesis may lie from the rendered robot (the model's median is
/// ~0.4 m per frame, 0.2 m for penalty-return bursts).
const ACCEPTED_ERROR_M: f64 = 1.0;

/// A running daemon and the sockets a test talks to it through.
struct Daemon {
    child: Child,
    dir: tempfile::TempDir,
    published: UdpSocket,
    gamecontroller_port: u16,
    client: UnixDatagram,
}

impl Daemon {
    /// Starts `relocd run` with `source` and loopback/Unix sockets in a fresh directory.
    fn start(source: &str, extra: &[&str]) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let published = UdpSocket::bind("127.0.0.1:0").unwrap();
        published.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let gamecontroller_port = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let config = dir.path().join("relocd.toml");
        let settings = "[burst]\nspacing_ms = 40\nmin_interval_ms = 100\nsettle_timeout_ms = 500\n\
                        [gamecontroller]\naddress = \"127.0.0.1\"\n";
        std::fs::write(&config, settings).unwrap();
        let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
        let mut args = vec![
            "run".to_string(),
            "--config".into(),
            path("relocd.toml"),
            "--source".into(),
            source
                .replace("{dir}", dir.path().to_str().unwrap())
                .replace("{sample}", sample().to_str().unwrap()),
            "--publish".into(),
            format!("udp:{}", published.local_addr().unwrap()),
            "--gc-port".into(),
            gamecontroller_port.to_string(),
            "--team".into(),
            TEAM.to_string(),
            "--player".into(),
            PLAYER.to_string(),
            "--control".into(),
            format!("unix:{}", path("control")),
        ];
        if !extra.contains(&"--sensors") {
            args.extend(["--sensors".into(), format!("unix:{}", path("sensors"))]);
        }
        args.extend(extra.iter().map(|arg| arg.to_string()));
        let child = Command::new(env!("CARGO_BIN_EXE_relocd"))
            .args(&args)
            .env("RELOCD_LOG", "relocd=debug")
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("relocd starts");
        let client = UnixDatagram::bind(dir.path().join("client")).unwrap();
        client.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut daemon = Self { child, dir, published, gamecontroller_port, client };
        daemon.wait_until_ready();
        daemon
    }

    fn socket(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn wait_until_ready(&mut self) {
        let started = Instant::now();
        while !self.socket("control").exists() {
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!("relocd exited before it was ready: {status}");
            }
            assert!(started.elapsed() < Duration::from_secs(30), "relocd did not open its control socket");
            std::thread::sleep(Duration::from_millis(20));
        }
        self.status();
    }

    /// Sends a control datagram and returns the answer.
    fn control(&self, request: &[u8]) -> serde_json::Value {
        self.client.send_to(request, self.socket("control")).unwrap();
        let mut buffer = vec![0u8; 65536];
        let length = self.client.recv(&mut buffer).expect("the control socket answers");
        serde_json::from_slice(&buffer[..length]).unwrap()
    }

    fn status(&self) -> serde_json::Value {
        self.control(br#"{"status": {}}"#)["status"].clone()
    }

    fn send_gamecontroller(&self, bytes: &[u8]) {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket.send_to(bytes, ("127.0.0.1", self.gamecontroller_port)).unwrap();
    }

    /// Sends LoLA state messages at 100 Hz for `seconds`.
    fn send_sensors(&self, seconds: f64, angles: [f32; 2], fsr: f32) {
        let socket = UnixDatagram::unbound().unwrap();
        let state = serde_json::json!({
            "Angles": angles, "Gyroscope": [0.0, 0.0, 0.0], "FSR": vec![fsr; 8], "Battery": [1.0, 0.0, 0.0, 0.0],
        });
        let bytes = rmp_serde::to_vec_named(&state).unwrap();
        for _ in 0..(seconds * 100.0) as usize {
            socket.send_to(&bytes, self.socket("sensors")).unwrap();
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The next published message.
    fn message(&self) -> Message {
        let mut buffer = vec![0u8; 65536];
        let length = self.published.recv(&mut buffer).expect("relocd publishes a message");
        Message::decode(&buffer[..length]).expect("a valid message")
    }

    fn stop(mut self) {
        // SAFETY: kill only sends a signal to our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let status = self.child.wait().unwrap();
        assert!(status.success(), "relocd exits cleanly on SIGTERM: {status}");
        assert!(!self.socket("control").exists(), "the control socket file is removed");
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

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

fn packet(penalty: Penalty, packet_number: u8) -> [u8; 118] {
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
    assert_eq!(message.prior.as_deref(), Some("penalty_return"));
    assert_eq!((message.frames.requested, message.frames.used), (5, 5));
    assert!(message.failure.is_none());
    let best = message.hypotheses[0];
    assert!(best.x < 0.0, "the prior picks the own half: {best:?}");
    assert!(best.weight > 0.9, "{:?}", message.hypotheses);
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

/// A YUYV frame of the sample recording, as a team's process would forward it.
fn sample_yuyv() -> YuyvImage {
    let recording = Recording::open(&sample()).unwrap();
    let frame = recording.load_frame(&recording.records()[0]).unwrap();
    YuyvImage::from_rgb(&frame.to_rgb()).unwrap()
}

fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sample")
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
    let sender = std::thread::spawn(move || {
        let mut stream = UnixStream::connect(&frames).unwrap();
        let header = FrameHeader {
            width: image.width(),
            height: image.height(),
            timestamp: 2.0,
            camera: Some(camera),
        };
        // An impossible camera pitch drops that frame but keeps the connection in step.
        let mut tilted = header.to_bytes();
        tilted[36..40].copy_from_slice(&3.0f32.to_le_bytes());
        stream.write_all(&tilted).unwrap();
        stream.write_all(image.as_bytes()).unwrap();
        for _ in 0..40 {
            if stream.write_all(&header.to_bytes()).and_then(|()| stream.write_all(image.as_bytes())).is_err()
            {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    });
    std::thread::sleep(Duration::from_millis(200));
    daemon.control(br#"{"relocalise": {}}"#);
    let message = daemon.message();
    assert_eq!(message.frames.used, 2, "{:?}", message.failure);
    assert_eq!(message.hypotheses.len(), 2);
    assert_eq!(daemon.status()["rejected"]["frames"], 2, "the lying header and the tilted frame");
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
    assert_eq!(message.hypotheses.len(), 2);
    assert!(message.captured.is_some());
    daemon.stop();
}
