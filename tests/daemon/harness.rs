//! The daemon under test: `relocd run` on loopback and Unix sockets in a temporary directory.

use std::io::Write;
use std::net::UdpSocket;
use std::os::unix::net::{UnixDatagram, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use relocd::frame::YuyvImage;
use relocd::protocol::message::Message;
use relocd::recording::Recording;

/// Our team number in the daemon's config.
pub const TEAM: u8 = 5;
/// Our player number in the daemon's config.
pub const PLAYER: u8 = 2;

/// A running daemon and the sockets a test talks to it through.
pub struct Daemon {
    child: Child,
    dir: tempfile::TempDir,
    published: UdpSocket,
    gamecontroller_port: u16,
    client: UnixDatagram,
}

impl Daemon {
    /// Starts `relocd run` with `source` and loopback/Unix sockets in a fresh directory. Penalties of
    /// any length count (`gamecontroller.min_penalty_s = 0`), so tests need not wait them out.
    pub fn start(source: &str, extra: &[&str]) -> Self {
        Self::start_with(source, extra, 0.0)
    }

    /// [`Daemon::start`], with `gamecontroller.min_penalty_s` set.
    pub fn start_with(source: &str, extra: &[&str], min_penalty_s: f64) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let published = UdpSocket::bind("127.0.0.1:0").unwrap();
        published.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let gamecontroller_port = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let config = dir.path().join("relocd.toml");
        let settings = "[burst]\nspacing_ms = 40\nmin_interval_ms = 100\nsettle_timeout_ms = 500\n\
                        [gamecontroller]\naddress = \"127.0.0.1\"\n";
        std::fs::write(&config, format!("{settings}min_penalty_s = {min_penalty_s:?}\n")).unwrap();
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

    pub fn socket(&self, name: &str) -> PathBuf {
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

    /// Sends a control datagram that gets no answer (a belief).
    pub fn send_control(&self, datagram: &[u8]) {
        self.client.send_to(datagram, self.socket("control")).unwrap();
    }

    /// Sends a control datagram and returns the answer.
    pub fn control(&self, request: &[u8]) -> serde_json::Value {
        self.client.send_to(request, self.socket("control")).unwrap();
        let mut buffer = vec![0u8; 65536];
        let length = self.client.recv(&mut buffer).expect("the control socket answers");
        serde_json::from_slice(&buffer[..length]).unwrap()
    }

    pub fn status(&self) -> serde_json::Value {
        self.control(br#"{"status": {}}"#)["status"].clone()
    }

    pub fn send_gamecontroller(&self, bytes: &[u8]) {
        self.send_gamecontroller_from("127.0.0.1", bytes);
    }

    /// Sends a GameController packet from another loopback address (a second GameController).
    pub fn send_gamecontroller_from(&self, source: &str, bytes: &[u8]) {
        let socket = UdpSocket::bind((source, 0)).unwrap();
        socket.send_to(bytes, ("127.0.0.1", self.gamecontroller_port)).unwrap();
    }

    /// Sends LoLA state messages at 100 Hz for `seconds`.
    pub fn send_sensors(&self, seconds: f64, angles: [f32; 2], fsr: f32) {
        self.send_state(seconds, &sensor_state(angles, fsr));
    }

    /// Sends LoLA state messages of a robot standing still with its head at `head` (HeadYaw,
    /// HeadPitch; radians) at 100 Hz for `seconds`.
    pub fn send_sensors_with_head(&self, seconds: f64, head: [f32; 2]) {
        let mut state = sensor_state([0.0, 0.0], 1.3);
        let mut joints = [0.0f32; 25];
        joints[..2].copy_from_slice(&head);
        state["Position"] = serde_json::json!(joints);
        self.send_state(seconds, &state);
    }

    fn send_state(&self, seconds: f64, state: &serde_json::Value) {
        let socket = UnixDatagram::unbound().unwrap();
        let bytes = rmp_serde::to_vec_named(state).unwrap();
        for _ in 0..(seconds * 100.0) as usize {
            socket.send_to(&bytes, self.socket("sensors")).unwrap();
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The next published message within `timeout`, if any.
    pub fn message_within(&self, timeout: Duration) -> Option<Message> {
        self.published.set_read_timeout(Some(timeout)).unwrap();
        let mut buffer = vec![0u8; 65536];
        let received = self.published.recv(&mut buffer);
        self.published.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        received.ok().map(|length| Message::decode(&buffer[..length]).expect("a valid message"))
    }

    /// The next published message.
    pub fn message(&self) -> Message {
        let mut buffer = vec![0u8; 65536];
        let length = self.published.recv(&mut buffer).expect("relocd publishes a message");
        Message::decode(&buffer[..length]).expect("a valid message")
    }

    /// Sends SIGHUP (reload the model file).
    pub fn hang_up(&self) {
        // SAFETY: kill only sends a signal to our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGHUP) };
    }

    /// Polls `status` until `done` holds for it (at most 10 s) and returns it.
    pub fn status_when(&self, done: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
        let started = Instant::now();
        loop {
            let status = self.status();
            if done(&status) {
                return status;
            }
            assert!(started.elapsed() < Duration::from_secs(10), "status never got there: {status}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn stop(mut self) {
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

/// A YUYV frame of the sample recording, as a team's process would forward it.
pub fn sample_yuyv() -> YuyvImage {
    let recording = Recording::open(&sample()).unwrap();
    let frame = recording.load_frame(&recording.records()[0]).unwrap();
    YuyvImage::from_rgb(&frame.to_rgb()).unwrap()
}

pub fn sample() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sample")
}

/// Writes `frame` (forwarded-frame header and payload) to `stream` `count` times, `gap` apart, on a
/// thread, like a camera forwarding at its rate; stops early when relocd closes the connection.
pub fn stream_frames(mut stream: UnixStream, frame: Vec<u8>, count: usize, gap: Duration) -> JoinHandle<()> {
    std::thread::spawn(move || {
        for _ in 0..count {
            if stream.write_all(&frame).is_err() {
                break;
            }
            std::thread::sleep(gap);
        }
    })
}

/// A LoLA state message (the keys relocd reads, and one it does not).
fn sensor_state(angles: [f32; 2], fsr: f32) -> serde_json::Value {
    serde_json::json!({
        "Angles": angles, "Gyroscope": [0.0, 0.0, 0.0], "FSR": vec![fsr; 8], "Battery": [1.0, 0.0, 0.0, 0.0],
    })
}
