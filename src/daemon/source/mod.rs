//! Frame sources: where a burst's frames come from. Each source is blocking and lives on the
//! relocalisation thread; nothing downstream knows which one it was.

pub mod forwarded;
pub mod replay;
pub mod sim;
#[cfg(feature = "v4l")]
pub mod v4l;
pub mod v4l_format;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use thiserror::Error;

use crate::frame::Frame;
use crate::geometry::{CameraPose, FieldPose};

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

/// A camera, or something that stands in for one.
pub trait FrameSource: Send {
    /// Takes up to `request.count` frames, `request.spacing` apart, starting now, and hands each to
    /// `deliver` as soon as it is taken, so the caller relocalises it while the next one is awaited
    /// and no burst is held in memory. Returns how many were delivered, at least one, or an error
    /// saying why there is none; fewer than asked when the deadline passed.
    fn capture(
        &mut self,
        request: &CaptureRequest<'_>,
        deliver: &mut dyn FnMut(CapturedFrame),
    ) -> Result<usize, SourceError>;
}

/// Captures a whole burst into memory (for tests of the sources).
#[cfg(test)]
pub fn capture_all(
    source: &mut dyn FrameSource,
    request: &CaptureRequest<'_>,
) -> Result<Vec<CapturedFrame>, SourceError> {
    let mut frames = Vec::new();
    source.capture(request, &mut |frame| frames.push(frame))?;
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
