//! V4L2 capture from the Nao's top camera: YUYV, mmap streaming, opened only for a burst unless
//! `camera.keep_streaming` is set, so the team's process can have the camera the rest of the time.
//! A missing or failing device is retried with backoff until the burst's deadline, never fatal.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use tracing::{debug, info, warn};
use v4l::buffer::Type;
use v4l::io::traits::CaptureStream;
use v4l::prelude::{Device, MmapStream};
use v4l::video::Capture;
use v4l::video::capture::Parameters;
use v4l::{Format, FourCC};

use super::v4l_format::{Negotiated, YUYV, backoff, candidate_devices, check_format, frame_from_buffer};
use super::{CaptureRequest, CapturedFrame, FrameSource, SourceError, Taken, unix_now};
use crate::frame::Frame;

/// Driver buffers.
const BUFFERS: u32 = 4;
/// Frames thrown away after opening, while auto exposure settles and stale buffers drain.
const WARM_UP_FRAMES: usize = 5;
/// Longest wait for one frame.
const FRAME_TIMEOUT: Duration = Duration::from_secs(1);

/// An open, streaming camera.
struct Streaming {
    path: PathBuf,
    format: Negotiated,
    stream: MmapStream<'static>,
    // Dropped after the stream.
    _device: Device,
}

/// The camera settings and, between bursts when kept, the open stream.
pub struct V4lSource {
    devices: Vec<PathBuf>,
    width: u32,
    height: u32,
    fps: u32,
    keep_streaming: bool,
    streaming: Option<Streaming>,
}

impl std::fmt::Debug for V4lSource {
    fn fmt(&self, formatter: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        formatter.debug_struct("V4lSource").field("devices", &self.devices).finish_non_exhaustive()
    }
}

impl V4lSource {
    /// A camera at `device` (the top camera's link falls back to /dev/video0), not yet opened.
    pub fn new(device: PathBuf, width: u32, height: u32, fps: u32, keep_streaming: bool) -> Self {
        Self { devices: candidate_devices(&device), width, height, fps, keep_streaming, streaming: None }
    }

    fn open(&self, path: &PathBuf, request: &CaptureRequest<'_>) -> Result<Streaming, String> {
        let device = Device::with_path(path).map_err(|error| format!("cannot open: {error}"))?;
        let format = device
            .set_format(&Format::new(self.width, self.height, FourCC::new(&YUYV)))
            .map_err(|error| format!("cannot set the format: {error}"))?;
        let format = Negotiated {
            width: format.width,
            height: format.height,
            fourcc: format.fourcc.repr,
            stride: format.stride,
        };
        check_format(self.width, self.height, &format)?;
        if let Err(error) = device.set_params(&Parameters::with_fps(self.fps)) {
            warn!(
                "camera {}: cannot set {} fps, keeping the driver's rate: {error}",
                path.display(),
                self.fps
            );
        }
        let mut stream = MmapStream::with_buffers(&device, Type::VideoCapture, BUFFERS)
            .map_err(|error| format!("cannot start streaming: {error}"))?;
        stream.set_timeout(
            FRAME_TIMEOUT
                .min(request.deadline.saturating_duration_since(Instant::now()))
                .max(Duration::from_millis(1)),
        );
        let mut streaming = Streaming { path: path.clone(), format, stream, _device: device };
        for _ in 0..WARM_UP_FRAMES {
            if request.stopped() || Instant::now() >= request.deadline {
                return Err("no frames before the burst's deadline".into());
            }
            streaming.stream.next().map_err(|error| format!("no frames: {error}"))?;
        }
        info!("camera {} streaming {}×{} YUYV", path.display(), self.width, self.height);
        Ok(streaming)
    }

    /// Opens the first device that works, retrying with backoff until the deadline.
    fn open_with_retries(&self, request: &CaptureRequest<'_>) -> Result<Streaming, SourceError> {
        let mut failures = Vec::new();
        for attempt in 0.. {
            failures.clear();
            for path in &self.devices {
                match self.open(path, request) {
                    Ok(streaming) => return Ok(streaming),
                    Err(reason) => failures.push(format!("{}: {reason}", path.display())),
                }
            }
            debug!("camera not ready (attempt {attempt}): {}", failures.join("; "));
            if !request.sleep_until(Instant::now() + backoff(attempt)) {
                break;
            }
        }
        Err(SourceError::Camera {
            device: self.devices[0].display().to_string(),
            reason: failures.join("; "),
        })
    }
}

impl FrameSource for V4lSource {
    fn start(&mut self, request: &CaptureRequest<'_>) -> Result<(), SourceError> {
        match &mut self.streaming {
            Some(streaming) => {
                // Buffers filled while nobody looked are stale.
                for _ in 0..BUFFERS {
                    let _ = streaming.stream.next();
                }
            }
            None => self.streaming = Some(self.open_with_retries(request)?),
        }
        Ok(())
    }

    fn next_frame(
        &mut self,
        request: &CaptureRequest<'_>,
        earliest: Instant,
    ) -> Result<Option<Taken>, SourceError> {
        let device = self.devices[0].display().to_string();
        let streaming = self
            .streaming
            .as_mut()
            .ok_or_else(|| SourceError::Camera { device: device.clone(), reason: "not streaming".into() })?;
        while Instant::now() < request.deadline && !request.stopped() {
            let (buffer, metadata) = streaming.stream.next().map_err(|error| SourceError::Camera {
                device: device.clone(),
                reason: format!("streaming failed: {error}"),
            })?;
            let at = Instant::now();
            if at < earliest {
                continue;
            }
            match frame_from_buffer(buffer, metadata.bytesused as usize, &streaming.format) {
                Ok(image) => {
                    let frame = CapturedFrame {
                        frame: Frame::Yuyv(image),
                        taken: unix_now(),
                        camera: None,
                        truth: None,
                    };
                    return Ok(Some(Taken { frame, at }));
                }
                Err(reason) => warn!("camera {}: frame dropped: {reason}", streaming.path.display()),
            }
        }
        Ok(None)
    }

    fn finish(&mut self, failed: bool) {
        if failed || !self.keep_streaming {
            self.streaming = None;
        }
    }
}
