//! The daemon's configuration: a TOML file in which every key is optional and defaults to what a Nao
//! needs; `relocd run` flags override single keys. `deploy/relocd.toml` lists every key.

use std::fmt;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::Deserialize;
use thiserror::Error;
use tracing_subscriber::filter::{ParseError, Targets};

use crate::geometry::{CameraIntrinsics, CameraMounting, CameraPose, PoseError, Representation};
use crate::pipeline::GlobalSearch;
use crate::protocol::address::Address;
use crate::protocol::message::Encoding;
use crate::relocaliser::{Backend, LoadOptions};

/// A configuration that cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// TOML syntax, an unknown key, or a value of the wrong kind (the message names the key).
    #[error("config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The TOML decoder's message.
        message: String,
    },
    /// A value out of range.
    #[error("config key `{key}`: {reason}")]
    Invalid {
        /// The key, dotted.
        key: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// The `model` (and `--model`) that asks for no network at all: the field lines alone.
pub const NO_MODEL: &str = "none";

/// Everything `relocd run` needs.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Log level (error, warn, info, debug, trace), or targets and levels (see [`log_filter`]).
    pub log_level: String,
    /// Where frames come from.
    pub source: SourceSpec,
    /// ONNX model file; absent: the model built into the binary for `backend`; [`NO_MODEL`]: no
    /// network, the field lines alone (needs `refine`).
    pub model: Option<PathBuf>,
    /// Field description file (TOML or JSON, see `relocd field`) whose lines the frames are checked
    /// against, e.g. a lab's smaller field; absent: the model contract's field.
    pub field: Option<PathBuf>,
    /// Inference engine: tract (built in) or onnxruntime (the `onnxruntime` feature).
    pub backend: Backend,
    /// Decode the model's outputs in this representation instead of the one its contract names.
    pub representation: Option<Representation>,
    /// Our team number, as the GameController knows it; absent: the penalty trigger is off.
    pub team: Option<u8>,
    /// Our player number (1–20); absent: the penalty trigger is off.
    pub player: Option<u8>,
    /// GameController input.
    pub gamecontroller: GameControllerConfig,
    /// LoLA sensor input for fall and pick-up detection.
    pub sensors: SensorInput,
    /// The control socket: relocalise requests and status.
    pub control: Listen,
    /// Where hypotheses go.
    pub publish: PublishConfig,
    /// Burst size and timing.
    pub burst: BurstConfig,
    /// The camera: V4L2 settings and the head yaw assumed when nothing else gives one.
    pub camera: CameraConfig,
    /// The forwarded-frame socket (source `frames:unix:PATH`).
    pub frames: FramesConfig,
    /// The replay source (source `replay:DIR`).
    pub replay: ReplayConfig,
    /// The simulated source (source `sim`).
    pub sim: SimConfig,
    /// Scheduling.
    pub process: ProcessConfig,
    /// Longer GameController, sensor and control datagrams are dropped unread (and counted).
    pub max_datagram_bytes: usize,
    /// Verify and refine the hypotheses against the field lines in the burst's frames.
    pub refine: bool,
    /// With `refine` (ignored without): when the lines also look for places all over the field,
    /// beyond the network's hypotheses (`never`, `when_unsure`, `always`).
    pub global_search: GlobalSearch,
    /// With `refine`: the line fits also estimate a small correction of the camera's pitch and roll
    /// (a robot's calibration is never exact).
    pub camera_correction: bool,
    /// With `camera_correction`: the correction's lasting part (the robot's calibration error) is
    /// learnt over the bursts whose lines fix it, and later fits start from it and hold to it.
    pub learn_calibration: bool,
    /// The game and team context that tells the symmetric twins apart.
    pub priors: PriorsConfig,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            log_level: "info".into(),
            source: SourceSpec::V4l(PathBuf::from("/dev/video-top")),
            model: None,
            field: None,
            backend: Backend::default(),
            representation: None,
            team: None,
            player: None,
            gamecontroller: GameControllerConfig::default(),
            sensors: SensorInput::Forwarded(Listen::At(Address::Unix(PathBuf::from("/tmp/relocd-sensors")))),
            control: Listen::At(Address::Unix(PathBuf::from("/tmp/relocd-control"))),
            publish: PublishConfig::default(),
            burst: BurstConfig::default(),
            camera: CameraConfig::default(),
            frames: FramesConfig::default(),
            replay: ReplayConfig::default(),
            sim: SimConfig::default(),
            process: ProcessConfig::default(),
            max_datagram_bytes: 16_384,
            refine: true,
            global_search: GlobalSearch::default(),
            camera_correction: true,
            learn_calibration: true,
            priors: PriorsConfig::default(),
        }
    }
}

impl Config {
    /// Reads a config file: syntax, key names and value types. Ranges and combinations are checked
    /// by [`Config::validate`], once flags have overridden keys.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Whether `model` asks for no network: the field lines alone, searched all over the field after
    /// every burst (before a network exists for the hall or the field).
    pub fn lines_only(&self) -> bool {
        self.model.as_deref() == Some(Path::new(NO_MODEL))
    }

    /// How to load the model: the configured engine and representation.
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions { backend: self.backend, representation: self.representation }
    }

    /// Parses the text of a config file; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        toml::from_str(text)
            .map_err(|error| ConfigError::Parse { path: path.to_path_buf(), message: error.to_string() })
    }

    /// Checks what serde cannot: ranges and combinations.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let invalid = |key, reason: &str| Err(ConfigError::Invalid { key, reason: reason.into() });
        if self.player.is_some_and(|player| !(1..=20).contains(&player)) {
            return invalid("player", "player numbers run from 1 to 20");
        }
        if self.team.is_some() != self.player.is_some() {
            return invalid("team", "give both `team` and `player` for the penalty trigger, or neither");
        }
        if self.lines_only() && !self.refine {
            return invalid("model", "\"none\" (no network: the field lines alone) needs refine = true");
        }
        if !(1..=30).contains(&self.burst.frames) {
            return invalid("burst.frames", "a burst has 1 to 30 frames");
        }
        if self.burst.timeout_ms == 0 || self.burst.timeout_ms > 30_000 {
            return invalid("burst.timeout_ms", "must lie in 1..=30000");
        }
        if self.burst.spacing_ms > 10_000 {
            return invalid("burst.spacing_ms", "must lie in 0..=10000");
        }
        if self.burst.min_interval_ms > 600_000 {
            return invalid("burst.min_interval_ms", "must lie in 0..=600000");
        }
        if self.burst.settle_timeout_ms > 60_000 {
            return invalid("burst.settle_timeout_ms", "must lie in 0..=60000");
        }
        if self.publish.targets.is_empty() {
            return invalid("publish.targets", "give at least one target, e.g. \"udp:127.0.0.1:5454\"");
        }
        if self.publish.targets.len() > 8 {
            return invalid("publish.targets", "at most 8 targets");
        }
        if !(256..=65_507).contains(&self.max_datagram_bytes) {
            return invalid("max_datagram_bytes", "must lie in 256..=65507 (the largest UDP payload)");
        }
        if !(1..=1000).contains(&self.frames.queue) {
            return invalid("frames.queue", "must lie in 1..=1000");
        }
        let (width, height) = (self.camera.width, self.camera.height);
        if width == 0 || width % 2 != 0 || width > 1280 {
            return invalid("camera.width", "must be even and at most 1280");
        }
        if height == 0 || height > 960 {
            return invalid("camera.height", "must lie in 1..=960");
        }
        if !(1..=60).contains(&self.camera.fps) {
            return invalid("camera.fps", "must lie in 1..=60");
        }
        if !self.camera.head_yaw_deg.is_finite() || self.camera.head_yaw_deg.abs() > 120.0 {
            return invalid("camera.head_yaw_deg", "must lie within ±120° (the Nao's head yaw range)");
        }
        if let Err((axis, _)) = self.camera.intrinsics(CameraIntrinsics::nao_top()) {
            let key =
                if axis == "horizontal" { "camera.horizontal_fov_deg" } else { "camera.vertical_fov_deg" };
            return invalid(key, "must lie in (1, 170) degrees");
        }
        if let Err(error) = self.camera.mounting() {
            return invalid("camera.height_m/pitch_deg/roll_deg", &error.to_string());
        }
        if !(8..=1280).contains(&self.sim.width) {
            return invalid("sim.width", "must lie in 8..=1280");
        }
        if !(6..=960).contains(&self.sim.height) {
            return invalid("sim.height", "must lie in 6..=960");
        }
        let unix_paths: Vec<&Path> = [Some(&self.control), self.sensors.listen()]
            .into_iter()
            .flatten()
            .filter_map(|listen| match listen {
                Listen::At(Address::Unix(path)) => Some(path.as_path()),
                _ => None,
            })
            .chain(match &self.source {
                SourceSpec::Frames(path) => Some(path.as_path()),
                _ => None,
            })
            .collect();
        if unix_paths.iter().enumerate().any(|(index, path)| unix_paths[..index].contains(path)) {
            return invalid("control", "control, sensors and forwarded frames need different socket paths");
        }
        if !(-20..=19).contains(&self.process.nice) {
            return invalid("process.nice", "niceness lies in -20..=19");
        }
        if self.process.cpu.is_some_and(|cpu| cpu >= libc::CPU_SETSIZE as usize) {
            return invalid("process.cpu", "no such CPU");
        }
        let priors = &self.priors;
        if !(0.0..=0.5).contains(&priors.min_weight_share) {
            return invalid("priors.min_weight_share", "must lie in [0, 0.5]");
        }
        if !(priors.belief_max_age_s > 0.0 && priors.belief_max_age_s <= 60.0) {
            return invalid("priors.belief_max_age_s", "must lie in (0, 60] seconds");
        }
        if priors.goalkeeper > 20 {
            return invalid("priors.goalkeeper", "a player number 1 to 20, or 0 for none");
        }
        if !(0.0..=1.0).contains(&priors.ball_flip_probability) {
            return invalid("priors.ball_flip_probability", "a probability in [0, 1]");
        }
        if !(0.0..=60.0).contains(&self.gamecontroller.min_penalty_s) {
            return invalid("gamecontroller.min_penalty_s", "must lie in [0, 60] seconds");
        }
        if log_filter(&self.log_level).is_err() {
            return invalid(
                "log_level",
                "expected error, warn, info, debug, trace or targets such as warn,relocd=debug",
            );
        }
        Ok(())
    }
}

/// The log filter `spec` names: a level (`error`, `warn`, `info`, `debug`, `trace`, `off`), or
/// comma-separated `target=level` directives with an optional bare default level, as in
/// `warn,relocd=debug`.
pub fn log_filter(spec: &str) -> Result<Targets, ParseError> {
    spec.parse()
}

/// GameController input.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GameControllerConfig {
    /// Listen for GameController packets at all.
    pub enabled: bool,
    /// Address to bind. The GameController broadcasts on the robots' network, so the default listens
    /// on every interface; `127.0.0.1` only hears packets relayed on the robot.
    pub address: IpAddr,
    /// UDP port (the GameController's is 3838).
    pub port: u16,
    /// A penalty that ends sooner than this, seconds, was a mistake the referee revoked: the robot was
    /// not moved, so its end triggers nothing.
    pub min_penalty_s: f64,
}

impl Default for GameControllerConfig {
    fn default() -> Self {
        Self { enabled: true, address: IpAddr::V4(Ipv4Addr::UNSPECIFIED), port: 3838, min_penalty_s: 2.0 }
    }
}

/// The game and team context that tells the symmetric twins apart (see `crate::pipeline::priors`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PriorsConfig {
    /// After the priors, no hypothesis has less than min(its weight before them, this): a wrong prior
    /// cannot make the right twin vanish.
    pub min_weight_share: f64,
    /// The belief stream's last pose before a fall or pick-up (or a request's prior) older than this,
    /// seconds, is ignored.
    pub belief_max_age_s: f64,
    /// The goalkeeper's player number (0: none): as that player, every burst assumes the own half
    /// unless a request says `"own_half": false`.
    pub goalkeeper: u8,
    /// Chance that one teammate's ball is point-reflected (it is itself flipped); the team ball counts
    /// as flipped with this to the power of the teammates agreeing on it.
    pub ball_flip_probability: f64,
}

impl Default for PriorsConfig {
    fn default() -> Self {
        Self {
            min_weight_share: crate::pipeline::priors::DEFAULT_MIN_SHARE,
            belief_max_age_s: 5.0,
            goalkeeper: 1,
            ball_flip_probability: crate::pipeline::priors::simulate::DEFAULT_BALL_FLIP_PROBABILITY,
        }
    }
}

/// Where hypotheses go, and how they are encoded.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PublishConfig {
    /// Datagram targets.
    pub targets: Vec<Address>,
    /// Message encoding.
    pub encoding: Encoding,
}

impl Default for PublishConfig {
    fn default() -> Self {
        Self {
            targets: vec![Address::Udp(SocketAddr::from(([127, 0, 0, 1], 5454)))],
            encoding: Encoding::Json,
        }
    }
}

/// Burst size and timing.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BurstConfig {
    /// Frames per relocalisation (5: fusing 5 frames beat single frames in the measured test bursts).
    pub frames: usize,
    /// Least time between two frames of a burst, milliseconds.
    pub spacing_ms: u64,
    /// Give up capturing after this long and use the frames taken so far, milliseconds.
    pub timeout_ms: u64,
    /// Least time between the starts of two bursts; triggers in between join the next burst, ms.
    pub min_interval_ms: u64,
    /// After a trigger, wait at most this long for the sensors to report a steady robot, ms.
    pub settle_timeout_ms: u64,
}

impl Default for BurstConfig {
    fn default() -> Self {
        Self { frames: 5, spacing_ms: 100, timeout_ms: 3000, min_interval_ms: 1000, settle_timeout_ms: 2000 }
    }
}

/// The camera.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraConfig {
    /// V4L2 capture width, pixels.
    pub width: u32,
    /// V4L2 capture height, pixels.
    pub height: u32,
    /// V4L2 frame rate.
    pub fps: u32,
    /// Keep the V4L2 device streaming between bursts (faster bursts, but the camera stays taken).
    pub keep_streaming: bool,
    /// Head yaw assumed when neither the frame, the trigger nor the sensors give one, degrees
    /// (positive: left).
    pub head_yaw_deg: f64,
    /// Camera height above the ground when the frame does not carry its camera pose, metres (line
    /// refinement projects with it).
    pub height_m: f64,
    /// Camera pitch with the torso upright and the head at zero, degrees (positive looks down; the
    /// Nao's top camera is mounted 1.2° down); the sensed torso and head angles are added to it.
    pub pitch_deg: f64,
    /// Camera roll likewise, degrees.
    pub roll_deg: f64,
    /// The camera's horizontal field of view, degrees, where a robot's calibration differs from the
    /// model contract's camera (line points are projected with it).
    pub horizontal_fov_deg: Option<f64>,
    /// Its vertical field of view, degrees.
    pub vertical_fov_deg: Option<f64>,
}

impl CameraConfig {
    /// How the camera sits on the robot: the configured height, pitch and roll with the torso upright
    /// and the head at zero, and the configured head yaw.
    pub fn mounting(&self) -> Result<CameraMounting, PoseError> {
        let mounted =
            CameraPose::new(self.height_m, self.pitch_deg.to_radians(), self.roll_deg.to_radians(), 0.0)?;
        Ok(CameraMounting { mounted, head_yaw: self.head_yaw_deg.to_radians() })
    }

    /// `model`'s camera with the configured field of view, if one is configured; the error names the
    /// axis and degrees out of range (see [`CameraIntrinsics::with_field_of_view`]).
    pub fn intrinsics(
        &self,
        model: CameraIntrinsics,
    ) -> Result<Option<CameraIntrinsics>, (&'static str, f64)> {
        if self.horizontal_fov_deg.is_none() && self.vertical_fov_deg.is_none() {
            return Ok(None);
        }
        model.with_field_of_view(self.horizontal_fov_deg, self.vertical_fov_deg).map(Some)
    }
}

impl Default for CameraConfig {
    fn default() -> Self {
        let standing = CameraPose::STANDING;
        Self {
            width: 640,
            height: 480,
            fps: 30,
            keep_streaming: false,
            head_yaw_deg: 0.0,
            height_m: standing.height(),
            pitch_deg: standing.pitch().to_degrees(),
            roll_deg: standing.roll().to_degrees(),
            horizontal_fov_deg: None,
            vertical_fov_deg: None,
        }
    }
}

/// The forwarded-frame socket.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FramesConfig {
    /// Frames kept; when full, the oldest is dropped.
    pub queue: usize,
}

impl Default for FramesConfig {
    fn default() -> Self {
        Self { queue: 8 }
    }
}

/// The replay source.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReplayConfig {
    /// Start again at the end of the recording.
    #[serde(rename = "loop")]
    pub looping: bool,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self { looping: true }
    }
}

/// The simulated source: the renderer along a figure-eight walk over the field.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Rendered width, pixels.
    pub width: u32,
    /// Rendered height, pixels.
    pub height: u32,
    /// Seed of the randomised scenes.
    pub seed: u64,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self { width: 320, height: 240, seed: 1 }
    }
}

/// Scheduling: relocd must not take CPU from the team's process.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProcessConfig {
    /// Niceness of the whole process (higher is kinder to others).
    pub nice: i32,
    /// Pin every thread to this CPU; absent: any.
    pub cpu: Option<usize>,
}

impl Default for ProcessConfig {
    fn default() -> Self {
        Self { nice: 10, cpu: None }
    }
}

/// Where frames come from: `v4l:DEVICE`, `frames:unix:PATH`, `replay:DIR` or `sim`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(try_from = "String")]
pub enum SourceSpec {
    /// A V4L2 device (falls back to /dev/video0 when the default is missing).
    V4l(PathBuf),
    /// Frames forwarded by the team's process to this Unix stream socket.
    Frames(PathBuf),
    /// A recording directory, played at its timestamps.
    Replay(PathBuf),
    /// The renderer.
    Sim,
}

impl FromStr for SourceSpec {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let expected = "expected v4l:DEVICE, frames:unix:PATH, replay:DIR or sim";
        let path = |rest: &str| {
            if rest.is_empty() {
                Err(format!("{text:?} names no path: {expected}"))
            } else {
                Ok(PathBuf::from(rest))
            }
        };
        match text.split_once(':') {
            None if text == "sim" => Ok(Self::Sim),
            Some(("v4l", rest)) => path(rest).map(Self::V4l),
            Some(("frames", rest)) => match rest.strip_prefix("unix:") {
                Some(rest) => path(rest).map(Self::Frames),
                None => Err(format!("{text:?}: forwarded frames come over a Unix socket, frames:unix:PATH")),
            },
            Some(("replay", rest)) => path(rest).map(Self::Replay),
            _ => Err(format!("unknown frame source {text:?}: {expected}")),
        }
    }
}

impl TryFrom<String> for SourceSpec {
    type Error = String;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl fmt::Display for SourceSpec {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::V4l(path) => write!(formatter, "v4l:{}", path.display()),
            Self::Frames(path) => write!(formatter, "frames:unix:{}", path.display()),
            Self::Replay(path) => write!(formatter, "replay:{}", path.display()),
            Self::Sim => formatter.write_str("sim"),
        }
    }
}

/// A datagram socket relocd binds to listen: `udp:IP:PORT`, `unix:PATH`, or `off`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(try_from = "String")]
pub enum Listen {
    /// Not listening.
    Off,
    /// Listening at this address. relocd resolves no host names, so a UDP address is numeric; a Unix
    /// datagram socket is created with owner/group-only permissions.
    At(Address),
}

impl FromStr for Listen {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "off" => Ok(Self::Off),
            _ => text.parse().map(Self::At),
        }
    }
}

impl TryFrom<String> for Listen {
    type Error = String;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl fmt::Display for Listen {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Off => formatter.write_str("off"),
            Self::At(address) => address.fmt(formatter),
        }
    }
}

/// Sensor input: datagrams the team's process forwards (`udp:`/`unix:`, one LoLA state message
/// each), LoLA's own stream socket when relocd is its only client (`lola:/tmp/robocup`), or `off`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(try_from = "String")]
pub enum SensorInput {
    /// Forwarded datagrams.
    Forwarded(Listen),
    /// LoLA's Unix stream socket, read as a client.
    Lola(PathBuf),
}

impl SensorInput {
    /// The socket relocd binds, if any.
    fn listen(&self) -> Option<&Listen> {
        match self {
            Self::Forwarded(listen) => Some(listen),
            Self::Lola(_) => None,
        }
    }
}

impl FromStr for SensorInput {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.strip_prefix("lola:") {
            Some("") => Err("lola: needs LoLA's socket path, e.g. lola:/tmp/robocup".into()),
            Some(path) => Ok(Self::Lola(PathBuf::from(path))),
            None => text.parse().map(Self::Forwarded),
        }
    }
}

impl TryFrom<String> for SensorInput {
    type Error = String;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        text.parse()
    }
}

impl fmt::Display for SensorInput {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Forwarded(listen) => listen.fmt(formatter),
            Self::Lola(path) => write!(formatter, "lola:{}", path.display()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config, ConfigError> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("relocd.toml");
        std::fs::write(&path, text).unwrap();
        let config = Config::load(&path)?;
        config.validate()?;
        Ok(config)
    }

    #[test]
    fn the_shipped_config_parses_and_matches_the_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/relocd.toml");
        let shipped = Config::load(&path).unwrap();
        shipped.validate().unwrap();
        let defaults = Config { team: shipped.team, player: shipped.player, ..Config::default() };
        assert_eq!(shipped, defaults, "deploy/relocd.toml should show the defaults");
    }

    #[test]
    fn an_empty_file_is_the_defaults() {
        assert_eq!(parse("").unwrap(), Config::default());
    }

    #[test]
    fn keys_parse_into_typed_values() {
        let config = parse(
            r#"
            source = "replay:/data/hall"
            team = 5
            player = 2
            sensors = "lola:/tmp/robocup"
            control = "udp:127.0.0.1:5001"
            representation = "quarter"
            backend = "onnxruntime"
            [publish]
            targets = ["udp:127.0.0.1:5000", "unix:/tmp/loc"]
            encoding = "msgpack"
            [replay]
            loop = false
            "#,
        )
        .unwrap();
        assert_eq!(config.source, SourceSpec::Replay("/data/hall".into()));
        assert_eq!(config.sensors, SensorInput::Lola("/tmp/robocup".into()));
        assert_eq!(config.control, Listen::At(Address::Udp("127.0.0.1:5001".parse().unwrap())));
        assert_eq!(config.representation, Some(Representation::Quarter));
        assert_eq!(config.backend, Backend::Onnxruntime);
        assert_eq!(config.publish.encoding, Encoding::Msgpack);
        assert_eq!(config.publish.targets[1], Address::Unix("/tmp/loc".into()));
        assert!(!config.replay.looping);
    }

    #[test]
    fn bad_configs_name_the_key() {
        let message = |text: &str| parse(text).unwrap_err().to_string();
        assert!(message("sourse = \"sim\"").contains("sourse"), "{}", message("sourse = \"sim\""));
        assert!(message("[burst]\nframez = 3").contains("framez"));
        assert!(message("source = \"webcam\"").contains("unknown frame source"));
        assert!(message("[publish]\ntargets = [\"udp:robot.local:5000\"]").contains("numeric"));
        assert!(message("[burst]\nframes = 0").contains("burst.frames"));
        assert!(message("player = 3").contains("`team`"));
        assert!(message("team = 5\nplayer = 21").contains("`player`"));
        assert!(message("[camera]\nfps = \"fast\"").contains("fps"));
        assert!(message("source = ").contains("relocd.toml"));
        assert!(message("[camera]\nheight = 0").contains("camera.height"));
        assert!(message("backend = \"cuda\"").contains("tract"), "{}", message("backend = \"cuda\""));
        assert!(message("max_datagram_bytes = 10").contains("max_datagram_bytes"));
        let pitch = message("[camera]\npitch_deg = 120");
        assert!(pitch.contains("camera.height_m/pitch_deg/roll_deg") && pitch.contains("pitch"), "{pitch}");
        assert!(message("[camera]\nheight_m = -0.5").contains("height"));
        assert!(message("refine = \"yes\"").contains("refine"), "{}", message("refine = \"yes\""));
        assert!(message("global_search = \"often\"").contains("when_unsure"));
        assert!(message("[camera]\nhorizontal_fov_deg = 0.5").contains("camera.horizontal_fov_deg"));
        assert!(message("[camera]\nvertical_fov_deg = 200").contains("camera.vertical_fov_deg"));
        assert!(message("camera_correction = \"yes\"").contains("camera_correction"));
        assert!(message("learn_calibration = 1").contains("learn_calibration"));
        assert!(!parse("learn_calibration = false").unwrap().learn_calibration);
        assert_eq!(parse("global_search = \"always\"").unwrap().global_search, GlobalSearch::Always);
        assert!(parse("refine = false").is_ok(), "the default search needs no refine = true");
        let lab = parse("field = \"lab.toml\"\n[camera]\nhorizontal_fov_deg = 60").unwrap();
        assert_eq!(lab.field, Some(PathBuf::from("lab.toml")));
        let intrinsics = lab.camera.intrinsics(CameraIntrinsics::nao_top()).unwrap().unwrap();
        assert!((intrinsics.horizontal_fov.to_degrees() - 60.0).abs() < 1e-9);
        assert_eq!(intrinsics.vertical_fov, CameraIntrinsics::nao_top().vertical_fov);
        assert_eq!(Config::default().camera.intrinsics(CameraIntrinsics::nao_top()), Ok(None));
        assert!(message("control = \"unix:/tmp/x\"\nsensors = \"unix:/tmp/x\"").contains("different"));
    }

    #[test]
    fn model_none_runs_the_lines_alone_and_needs_refinement() {
        assert!(parse("model = \"none\"").unwrap().lines_only());
        assert!(!parse("model = \"lab.onnx\"").unwrap().lines_only());
        assert!(!Config::default().lines_only(), "the built-in model by default");
        let message = parse("model = \"none\"\nrefine = false").unwrap_err().to_string();
        assert!(message.contains("`model`") && message.contains("refine"), "{message}");
    }

    #[test]
    fn log_levels_and_targets_parse_and_a_bad_one_names_the_key() {
        for spec in ["info", "DEBUG", "off", "relocd=trace", "warn,relocd=debug,tract_core=error"] {
            assert!(log_filter(spec).is_ok(), "{spec}");
        }
        let filter = log_filter("warn,relocd=debug").unwrap();
        assert!(filter.would_enable("relocd::daemon", &tracing::Level::DEBUG));
        assert!(!filter.would_enable("tract_core::model", &tracing::Level::INFO));
        for spec in ["relocd=loud", "loud=[", "a=b=c"] {
            assert!(log_filter(spec).is_err(), "{spec}");
            let message = parse(&format!("log_level = {spec:?}")).unwrap_err().to_string();
            assert!(message.contains("log_level"), "{message}");
        }
    }

    #[test]
    fn specs_print_as_they_parse() {
        for text in ["v4l:/dev/video-top", "frames:unix:/tmp/f", "replay:rec", "sim"] {
            assert_eq!(text.parse::<SourceSpec>().unwrap().to_string(), text);
        }
        for text in ["off", "udp:127.0.0.1:5001", "unix:/tmp/c"] {
            assert_eq!(text.parse::<Listen>().unwrap().to_string(), text);
        }
        assert_eq!("lola:/tmp/robocup".parse::<SensorInput>().unwrap().to_string(), "lola:/tmp/robocup");
        assert!("frames:/tmp/f".parse::<SourceSpec>().is_err());
        assert!("unix:".parse::<Address>().is_err());
        assert!("lola:".parse::<SensorInput>().is_err());
    }
}
