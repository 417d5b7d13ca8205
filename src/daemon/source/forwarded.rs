//! Forwarded frames: the team's process streams the top camera and sends frames to relocd's Unix
//! stream socket (header + YUYV bytes, `crate::protocol::frame_header`). A listener task keeps the
//! newest few in a bounded queue; a burst takes the frames that arrive after it starts.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use tokio::io::AsyncReadExt;
use tokio::net::UnixStream;
use tracing::{debug, warn};

use super::{CaptureRequest, CapturedFrame, FrameSource, SourceError, Taken, unix_now};
use crate::daemon::sockets::StreamListener;
use crate::daemon::status::Status;
use crate::frame::{Frame, YuyvImage};
use crate::geometry::CameraPose;
use crate::protocol::frame_header::{FrameHeader, HEADER_SIZE};

/// A frame as it arrived.
#[derive(Clone, Debug)]
struct Arrived {
    image: YuyvImage,
    camera: Option<CameraPose>,
    at: Instant,
    taken: f64,
}

/// The newest forwarded frames; the oldest is dropped when full.
#[derive(Debug)]
pub struct FrameQueue {
    frames: Mutex<VecDeque<Arrived>>,
    arrived: Condvar,
    capacity: usize,
}

impl FrameQueue {
    /// An empty queue of at most `capacity` frames.
    pub fn new(capacity: usize) -> Self {
        Self { frames: Mutex::new(VecDeque::with_capacity(capacity)), arrived: Condvar::new(), capacity }
    }

    /// Adds a frame; true if the oldest had to go.
    fn push(&self, frame: Arrived) -> bool {
        let mut frames = self.frames.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let dropped = frames.len() >= self.capacity;
        if dropped {
            frames.pop_front();
        }
        frames.push_back(frame);
        self.arrived.notify_all();
        dropped
    }

    /// The first frame that arrived at or after `after`, waiting for it until `until`.
    fn first_after(&self, after: Instant, until: Instant) -> Option<Arrived> {
        let mut frames = self.frames.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        loop {
            if let Some(frame) = frames.iter().find(|frame| frame.at >= after) {
                return Some(frame.clone());
            }
            let now = Instant::now();
            if now >= until {
                return None;
            }
            frames = self
                .arrived
                .wait_timeout(frames, until - now)
                .unwrap_or_else(|poisoned| poisoned.into_inner())
                .0;
        }
    }
}

/// The source side: takes frames from the queue.
#[derive(Debug)]
pub struct ForwardedSource {
    queue: Arc<FrameQueue>,
}

impl ForwardedSource {
    /// Reads frames the listener puts into `queue`.
    pub fn new(queue: Arc<FrameQueue>) -> Self {
        Self { queue }
    }
}

impl FrameSource for ForwardedSource {
    fn next_frame(
        &mut self,
        request: &CaptureRequest<'_>,
        earliest: Instant,
    ) -> Result<Option<Taken>, SourceError> {
        while !request.stopped() {
            // Wake up now and then to notice a shutdown.
            let until = request.deadline.min(Instant::now() + Duration::from_millis(100));
            match self.queue.first_after(earliest, until) {
                Some(arrived) => {
                    let frame = CapturedFrame {
                        frame: Frame::Yuyv(arrived.image),
                        taken: arrived.taken,
                        camera: arrived.camera,
                        truth: None,
                    };
                    return Ok(Some(Taken { frame, at: arrived.at }));
                }
                None if Instant::now() >= request.deadline => break,
                None => {}
            }
        }
        Ok(None)
    }
}

/// Accepts senders until the task is dropped; each connection streams frames.
pub async fn listen(listener: StreamListener, queue: Arc<FrameQueue>, status: Arc<Status>) {
    loop {
        match listener.listener.accept().await {
            Ok((stream, _)) => {
                debug!("frame sender connected");
                tokio::spawn(serve(stream, queue.clone(), status.clone()));
            }
            Err(error) => {
                warn!("forwarded frames: accept failed: {error}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// Reads frames from one sender until it disconnects or sends something that breaks the stream.
async fn serve(mut stream: UnixStream, queue: Arc<FrameQueue>, status: Arc<Status>) {
    let mut header_bytes = [0u8; HEADER_SIZE];
    loop {
        match stream.read_exact(&mut header_bytes).await {
            Ok(_) => {}
            Err(error) if error.kind() == std::io::ErrorKind::UnexpectedEof => {
                debug!("frame sender disconnected");
                return;
            }
            Err(error) => {
                warn!("forwarded frames: read failed: {error}");
                return;
            }
        }
        let header = match FrameHeader::parse(&header_bytes) {
            Ok(header) => header,
            Err(error) => {
                status.update(|report| report.rejected.frames += 1);
                let Some(payload) = error.skippable_payload() else {
                    warn!("forwarded frame refused, closing the connection (out of step): {error}");
                    return;
                };
                warn!("forwarded frame dropped: {error}");
                let mut rest = (&mut stream).take(payload as u64);
                if tokio::io::copy(&mut rest, &mut tokio::io::sink()).await.ok() != Some(payload as u64) {
                    return;
                }
                continue;
            }
        };
        let mut payload = vec![0u8; header.payload_size()];
        if let Err(error) = stream.read_exact(&mut payload).await {
            warn!("forwarded frame dropped: the sender stopped mid-frame ({error})");
            status.update(|report| report.rejected.frames += 1);
            return;
        }
        let image = YuyvImage::new(header.width, header.height, payload)
            .expect("the header's checks fix the payload size");
        let arrived = Arrived { image, camera: header.camera, at: Instant::now(), taken: unix_now() };
        if queue.push(arrived) {
            status.update(|report| report.frames_dropped += 1);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;

    use super::*;
    use crate::daemon::source::capture_all;

    fn arrived(at: Instant, value: u8) -> Arrived {
        Arrived { image: YuyvImage::new(2, 1, vec![value; 4]).unwrap(), camera: None, at, taken: 0.0 }
    }

    #[test]
    fn the_queue_keeps_the_newest_frames() {
        let queue = FrameQueue::new(2);
        let now = Instant::now();
        assert!(!queue.push(arrived(now, 1)));
        assert!(!queue.push(arrived(now, 2)));
        assert!(queue.push(arrived(now, 3)), "the third frame pushes the first out");
        let first = queue.first_after(now, now).unwrap();
        assert_eq!(first.image.as_bytes()[0], 2);
    }

    #[test]
    fn a_burst_takes_only_frames_that_arrive_after_it_starts() {
        let queue = Arc::new(FrameQueue::new(8));
        queue.push(arrived(Instant::now(), 1));
        let sender = {
            let queue = queue.clone();
            std::thread::spawn(move || {
                for value in 2..6 {
                    std::thread::sleep(Duration::from_millis(20));
                    queue.push(arrived(Instant::now(), value));
                }
            })
        };
        let stop = AtomicBool::new(false);
        let request = CaptureRequest {
            count: 2,
            spacing: Duration::from_millis(30),
            deadline: Instant::now() + Duration::from_secs(5),
            stop: &stop,
        };
        let frames = capture_all(&mut ForwardedSource::new(queue), &request).unwrap();
        sender.join().unwrap();
        let values: Vec<u8> = frames
            .iter()
            .map(|frame| match &frame.frame {
                Frame::Yuyv(image) => image.as_bytes()[0],
                Frame::Rgb(_) => unreachable!(),
            })
            .collect();
        assert_eq!(values.len(), 2);
        assert!(values[0] >= 2 && values[1] >= values[0] + 2, "{values:?}: spaced by at least 30 ms");
    }

    #[test]
    fn no_frames_is_a_timeout() {
        let stop = AtomicBool::new(false);
        let request = CaptureRequest {
            count: 1,
            spacing: Duration::ZERO,
            deadline: Instant::now() + Duration::from_millis(20),
            stop: &stop,
        };
        let result = capture_all(&mut ForwardedSource::new(Arc::new(FrameQueue::new(2))), &request);
        assert!(matches!(result, Err(SourceError::Timeout(_))));
    }
}
