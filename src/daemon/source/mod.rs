//! Frame sources: where a burst's frames come from. Each source is blocking and lives on the
//! relocalisation thread; nothing downstream knows which one it was. [`open`] makes the one a
//! [`SourceSpec`] names (for `relocd run` and `relocd record` alike), and [`capture`] runs a burst on
//! any of them: the pacing, the deadline and the "no frames" ending live there, once; a source only
//! says how to get its next frame.

pub mod forwarded;
pub mod replay;
pub mod sim;
#[cfg(feature = "v4l")]
pub mod v4l;
pub mod v4l_format;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::bail;
use thiserror::Error;
use tracing::debug;

use self::forwarded::{ForwardedSource, FrameQueue};
use super::config::{CameraConfig, SimConfig, SourceSpec};
use crate::frame::Frame;
use crate::geometry::{CameraPose, FieldModel, FieldPose};
use crate::recording::Recording;

/// Why a source delivered no frames.
#[derive(Debug, Error)]
pub enum SourceError {
    /// The camera could not be opened or failed while streaming.
    #[error("camera {device}: {reason}")]
    Camera {
        /// The device path.
        device: String,
        /// What went wrong.
        reason: String,
    },
    /// Not enough frames before the deadline.
    #[error("no frame arrived within {:.1} s", .0.as_secs_f64())]
    Timeout(Duration),
    /// A recorded frame could not be read.
    #[error(transparent)]
    Recording(#[from] crate::recording::RecordingError),
    /// A replay without looping has played its last frame.
    #[error("the recording has ended (set replay.loop = true to play it again)")]
    Ended,
    /// The recording's timestamps span more time than a clock can hold.
    #[error("the recording's timestamps span {0} s, too long to play")]
    Unplayable(f64),
    /// The daemon is shutting down.
    #[error("shutting down")]
    Stopped,
    /// This build cannot use the source.
    #[error("{0}")]
    Unsupported(String),
}

/// One frame of a burst.
#[derive(Clone, Debug)]
pub struct CapturedFrame {
    /// The image.
    pub frame: Frame,
    /// When it was taken, Unix seconds.
    pub taken: f64,
    /// The camera's pose on the robot, when the source knows it (its head yaw then wins over the
    /// trigger's and the config's).
    pub camera: Option<CameraPose>,
    /// The robot's true pose, when the source knows it (replay of a labelled recording, sim).
    pub truth: Option<FieldPose>,
}

/// What a burst needs.
#[derive(Debug)]
pub struct CaptureRequest<'a> {
    /// Frames wanted.
    pub count: usize,
    /// Least time between two frames.
    pub spacing: Duration,
    /// Return what was taken by then.
    pub deadline: Instant,
    /// Set when the daemon shuts down.
    pub stop: &'a AtomicBool,
}

impl CaptureRequest<'_> {
    /// Sleeps until `until`, noticing a shutdown; false (at once, or at the deadline) if stopped or
    /// `until` lies past the deadline.
    pub fn sleep_until(&self, until: Instant) -> bool {
        sleep_unless_stopped(self.stop, until.min(self.deadline)) && until <= self.deadline
    }

    /// Whether the daemon is shutting down.
    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
}

/// A frame and when the source took it.
#[derive(Clone, Debug)]
pub struct Taken {
    /// The frame.
    pub frame: CapturedFrame,
    /// When it was taken (or shown, for a replay): the next frame comes a spacing later.
    pub at: Instant,
}

/// A camera, or something that stands in for one. [`capture`] runs a burst on it.
pub trait FrameSource: Send {
    /// Gets ready for a burst (a camera opens its device); the default does nothing.
    fn start(&mut self, _request: &CaptureRequest<'_>) -> Result<(), SourceError> {
        Ok(())
    }

    /// The first frame taken at or after `earliest`, waiting for it until the request's deadline or
    /// a shutdown; `None` when none came by then.
    fn next_frame(
        &mut self,
        request: &CaptureRequest<'_>,
        earliest: Instant,
    ) -> Result<Option<Taken>, SourceError>;

    /// The burst is over, `failed` if the source said so (a camera that is not kept streaming
    /// closes); the default does nothing.
    fn finish(&mut self, _failed: bool) {}
}

/// Takes up to `request.count` frames from `source`, `request.spacing` apart, starting now, and hands
/// each to `deliver` as soon as it is taken, so the caller relocalises it while the next one is awaited
/// and no burst is held in memory. Returns how many were delivered, at least one, or an error saying
/// why there is none; fewer than asked when the deadline passed or the source failed mid-burst.
pub fn capture(
    source: &mut dyn FrameSource,
    request: &CaptureRequest<'_>,
    deliver: &mut dyn FnMut(CapturedFrame),
) -> Result<usize, SourceError> {
    let started = Instant::now();
    source.start(request)?;
    let (mut delivered, mut earliest, mut failure) = (0, started, None);
    while delivered < request.count && !request.stopped() {
        match source.next_frame(request, earliest) {
            Ok(Some(taken)) => {
                earliest = taken.at + request.spacing.max(Duration::from_micros(1));
                deliver(taken.frame);
                delivered += 1;
            }
            Ok(None) => break,
            Err(error) => {
                failure = Some(error);
                break;
            }
        }
    }
    source.finish(failure.is_some());
    match (delivered, failure) {
        (0, Some(error)) => Err(error),
        (0, None) if request.stopped() => Err(SourceError::Stopped),
        (0, None) => Err(SourceError::Timeout(started.elapsed())),
        (_, Some(error)) => {
            debug!("burst cut short after {delivered} frames: {error}");
            Ok(delivered)
        }
        (_, None) => Ok(delivered),
    }
}

/// What the sources take from the configuration.
#[derive(Clone, Debug)]
pub struct SourceSettings {
    /// V4L2 size, rate and streaming.
    pub camera: CameraConfig,
    /// The renderer's size and seed.
    pub sim: SimConfig,
    /// The field the renderer draws.
    pub field: FieldModel,
    /// Play a recording again once it has ended.
    pub looping: bool,
}

/// Opens the frame source `spec` names; `frames` is the queue the forwarded-frame listener fills,
/// needed for `frames:` (the caller binds the socket, since only it runs the listener).
pub fn open(
    spec: &SourceSpec,
    settings: &SourceSettings,
    frames: Option<Arc<FrameQueue>>,
) -> anyhow::Result<Box<dyn FrameSource>> {
    Ok(match spec {
        SourceSpec::Replay(directory) => {
            Box::new(replay::ReplaySource::open(Recording::open(directory)?, settings.looping)?)
        }
        SourceSpec::Sim => {
            let sim = &settings.sim;
            Box::new(sim::SimSource::new(settings.field.clone(), sim.width, sim.height, sim.seed))
        }
        SourceSpec::Frames(path) => match frames {
            Some(queue) => Box::new(ForwardedSource::new(queue)),
            None => bail!("frames:unix:{}: nobody listens for forwarded frames", path.display()),
        },
        SourceSpec::V4l(device) => v4l_source(device, &settings.camera)?,
    })
}

#[cfg(feature = "v4l")]
fn v4l_source(device: &std::path::Path, camera: &CameraConfig) -> anyhow::Result<Box<dyn FrameSource>> {
    Ok(Box::new(v4l::V4lSource::new(
        device.to_path_buf(),
        camera.width,
        camera.height,
        camera.fps,
        camera.keep_streaming,
    )))
}

#[cfg(not(feature = "v4l"))]
fn v4l_source(device: &std::path::Path, _: &CameraConfig) -> anyhow::Result<Box<dyn FrameSource>> {
    bail!(
        "source v4l:{} needs a relocd built with the `v4l` feature (cargo build --features v4l, \
         which needs libclang-dev; deploy/build-nao.sh does); use replay:DIR, frames:unix:PATH or sim otherwise",
        device.display()
    )
}

/// Captures a whole burst into memory (for tests of the sources).
#[cfg(test)]
pub fn capture_all(
    source: &mut dyn FrameSource,
    request: &CaptureRequest<'_>,
) -> Result<Vec<CapturedFrame>, SourceError> {
    let mut frames = Vec::new();
    capture(source, request, &mut |frame| frames.push(frame))?;
    Ok(frames)
}

/// Sleeps until `until` in steps of at most 50 ms, so that a shutdown is noticed; false if `stop`
/// was set.
pub fn sleep_unless_stopped(stop: &AtomicBool, until: Instant) -> bool {
    loop {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let now = Instant::now();
        if now >= until {
            return true;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(50)));
    }
}

/// Now, Unix seconds.
pub fn unix_now() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |elapsed| elapsed.as_secs_f64())
}
