//! `relocd record`: frames from the robot's camera (V4L2), the forwarded-frame socket or the
//! simulator into a recording (`crate::recording`), with capture times (Unix seconds) and the camera
//! pose where the source knows it, so that teams can build test sets in their own halls and replay
//! them with `relocd replay` or `relocd run --source replay:DIR`.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use tokio::sync::oneshot;
use tracing::{info, warn};

use super::config::{CameraConfig, SimConfig, SourceSpec};
use super::sockets;
use super::source::forwarded::{self, FrameQueue};
use super::source::{self as sources, CaptureRequest, SourceError, SourceSettings, sleep_unless_stopped};
use super::status::Status;
use crate::geometry::{FieldDimensions, FieldModel};
use crate::recording::{FrameFormat, FrameRecord, RecordingWriter};

/// How long one wait for frames may last before the recorder says that none come.
const PATIENCE: Duration = Duration::from_secs(2);

/// What to record.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// `v4l:DEVICE`, `frames:unix:PATH` or `sim`.
    pub source: SourceSpec,
    /// The recording directory to create.
    pub out: PathBuf,
    /// Stop after this many frames.
    pub count: u64,
    /// Stop after this long, if given.
    pub duration: Option<Duration>,
    /// Frames kept per second (the camera may deliver more).
    pub fps: f64,
    /// How frame files are stored.
    pub format: FrameFormat,
    /// V4L2 size and rate, and the simulator's size.
    pub camera: CameraConfig,
    /// Forwarded frames kept waiting, at most.
    pub queue: usize,
}

/// What was recorded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordSummary {
    /// Frames written.
    pub frames: u64,
    /// From the first frame to the last, seconds.
    pub seconds: f64,
    /// Forwarded frames refused (a bad header), if the source was the frame socket.
    pub rejected: u64,
}

/// Records until `options.count` frames, `options.duration` or a SIGINT/SIGTERM, whichever comes
/// first; `on_frame` is called after each frame is written.
pub fn record(options: &RecordOptions, mut on_frame: impl FnMut(u64)) -> anyhow::Result<RecordSummary> {
    if !(options.fps > 0.0 && options.fps <= 60.0) {
        bail!("--fps {}: expected frames per second in (0, 60]", options.fps);
    }
    if options.count == 0 {
        bail!("--count 0: nothing to record");
    }
    if let SourceSpec::Replay(_) = options.source {
        bail!("a recording is already recorded: copy its directory instead");
    }
    let status = Arc::new(Status::new(options.source.to_string(), String::new()));
    let background = Background::start(&options.source, options.queue, status.clone())?;
    // The simulator films at the camera's size here: a recording stands in for the camera.
    let camera = &options.camera;
    let settings = SourceSettings {
        camera: camera.clone(),
        sim: SimConfig { width: camera.width, height: camera.height, seed: 1 },
        field: FieldModel::new(FieldDimensions::spl_2025()),
        looping: false,
    };
    let mut source = sources::open(&options.source, &settings, background.queue.clone())?;
    let mut writer = RecordingWriter::create(&options.out)?;
    info!(source = %options.source, out = %options.out.display(), "recording");

    // One frame per capture, paced here: a source's first frame comes at once, so only this loop
    // can hold the rate across frames.
    let spacing = Duration::from_secs_f64(1.0 / options.fps);
    let started = Instant::now();
    let end = options.duration.map(|duration| started + duration);
    let (mut frames, mut first, mut last) = (0u64, None, 0.0);
    let mut next = started;
    while frames < options.count && end.is_none_or(|end| next < end) {
        if !sleep_unless_stopped(&background.stop, next) {
            break;
        }
        let deadline = Instant::now() + PATIENCE;
        let request = CaptureRequest {
            count: 1,
            spacing,
            deadline: end.map_or(deadline, |end| deadline.min(end)),
            stop: &background.stop,
        };
        let mut captured = Vec::with_capacity(1);
        match sources::capture(source.as_mut(), &request, &mut |frame| captured.push(frame)) {
            Ok(_) => {}
            Err(SourceError::Timeout(waited)) => {
                warn!("no frame from {} for {:.1} s", options.source, waited.as_secs_f64());
                next = Instant::now();
                continue;
            }
            Err(SourceError::Stopped) => break,
            Err(error) => return Err(error).context("recording stopped"),
        }
        next = Instant::now().max(next + spacing);
        for frame in captured {
            let (width, height) = frame.frame.dimensions();
            let record = FrameRecord {
                file: format!("{frames:06}.{}", options.format.extension()),
                t: frame.taken,
                pose: frame.truth,
                camera: frame.camera,
                width: Some(width),
                height: Some(height),
            };
            writer.write_frame(&record, &frame.frame)?;
            first.get_or_insert(frame.taken);
            last = frame.taken;
            frames += 1;
            on_frame(frames);
        }
    }
    Ok(RecordSummary {
        frames,
        seconds: first.map_or(0.0, |first| last - first),
        rejected: status.snapshot().rejected.frames,
    })
}

/// A thread with a small tokio runtime: turns SIGINT/SIGTERM into `stop`, and listens for forwarded
/// frames when the source is the frame socket. Stopped and joined when dropped.
struct Background {
    stop: Arc<AtomicBool>,
    queue: Option<Arc<FrameQueue>>,
    shutdown: Option<oneshot::Sender<()>>,
    thread: Option<JoinHandle<()>>,
}

impl Background {
    fn start(source: &SourceSpec, queue: usize, status: Arc<Status>) -> anyhow::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let frames = match source {
            SourceSpec::Frames(path) => Some((path.clone(), Arc::new(FrameQueue::new(queue)))),
            _ => None,
        };
        let queue = frames.as_ref().map(|(_, queue)| queue.clone());
        let (shutdown, shutdown_received) = oneshot::channel();
        let (ready, is_ready) = std::sync::mpsc::channel::<anyhow::Result<()>>();
        let flag = stop.clone();
        let thread = std::thread::Builder::new().name("record-io".into()).spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(runtime) => runtime,
                Err(error) => return drop(ready.send(Err(error.into()))),
            };
            runtime.block_on(async move {
                let signals = signals().context("cannot handle SIGINT/SIGTERM");
                let listener = match &frames {
                    Some((path, _)) => sockets::bind_stream(path)
                        .map(Some)
                        .with_context(|| format!("cannot listen for forwarded frames on {}", path.display())),
                    None => Ok(None),
                };
                let (mut terminate, mut interrupt, listener) = match (signals, listener) {
                    (Ok((terminate, interrupt)), Ok(listener)) => (terminate, interrupt, listener),
                    (Err(error), _) | (_, Err(error)) => return drop(ready.send(Err(error))),
                };
                let _ = ready.send(Ok(()));
                let listening = async {
                    match (listener, frames) {
                        (Some(listener), Some((_, queue))) => {
                            forwarded::listen(listener, queue, status).await
                        }
                        _ => std::future::pending().await,
                    }
                };
                tokio::select! {
                    _ = terminate.recv() => info!("SIGTERM: stopping"),
                    _ = interrupt.recv() => info!("SIGINT: stopping"),
                    _ = shutdown_received => {}
                    () = listening => {}
                }
                flag.store(true, Ordering::Relaxed);
            });
        })?;
        is_ready.recv().context("the recorder's I/O thread died")??;
        Ok(Self { stop, queue, shutdown: Some(shutdown), thread: Some(thread) })
    }
}

fn signals() -> std::io::Result<(tokio::signal::unix::Signal, tokio::signal::unix::Signal)> {
    use tokio::signal::unix::{SignalKind, signal};
    Ok((signal(SignalKind::terminate())?, signal(SignalKind::interrupt())?))
}

impl Drop for Background {
    fn drop(&mut self) {
        if let Some(shutdown) = self.shutdown.take() {
            let _ = shutdown.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
