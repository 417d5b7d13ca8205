//! The replay source: a recording directory played at its timestamps from the moment the daemon
//! starts, optionally looping, as if a camera were filming it.

use std::time::{Duration, Instant};

use super::{CaptureRequest, CapturedFrame, FrameSource, SourceError, Taken, unix_now};
use crate::recording::{Recording, RecordingError};

/// Frame period assumed for a recording of a single frame.
const SINGLE_FRAME_PERIOD: f64 = 1.0 / 30.0;

/// A recording on a playback clock.
#[derive(Debug)]
pub struct ReplaySource {
    recording: Recording,
    looping: bool,
    started: Instant,
    /// Record indices in time order.
    order: Vec<usize>,
    /// Recording time of the first frame, seconds.
    first: f64,
    /// Length of one pass, seconds: first to last frame plus one frame period.
    period: f64,
}

impl ReplaySource {
    /// Opens a recording; its clock starts now.
    pub fn open(recording: Recording, looping: bool) -> Result<Self, RecordingError> {
        let records = recording.records();
        let mut order: Vec<usize> = (0..records.len()).collect();
        order.sort_by(|&a, &b| records[a].t.total_cmp(&records[b].t));
        let times: Vec<f64> = order.iter().map(|&index| records[index].t).collect();
        let (first, last) = match (times.first(), times.last()) {
            (Some(&first), Some(&last)) => (first, last),
            _ => {
                return Err(RecordingError::Empty { directory: recording.directory().to_path_buf() });
            }
        };
        let mut steps: Vec<f64> =
            times.windows(2).map(|pair| pair[1] - pair[0]).filter(|&s| s > 0.0).collect();
        steps.sort_by(f64::total_cmp);
        let frame_period = steps.get(steps.len() / 2).copied().unwrap_or(SINGLE_FRAME_PERIOD);
        let period = last - first + frame_period;
        Ok(Self { recording, looping, started: Instant::now(), order, first, period })
    }

    /// The first frame shown at or after `at`, and when it is shown.
    fn next_shown(&self, at: Instant) -> Result<(usize, Instant), SourceError> {
        let elapsed = (at.saturating_duration_since(self.started)).as_secs_f64();
        let mut pass = (elapsed / self.period).floor();
        if !self.looping && pass >= 1.0 {
            return Err(SourceError::Ended);
        }
        let offset = elapsed - pass * self.period;
        let records = self.recording.records();
        let position = self.order.iter().position(|&index| records[index].t - self.first >= offset - 1e-9);
        let index = match position.map(|position| self.order[position]) {
            Some(index) => index,
            None if self.looping => {
                pass += 1.0;
                self.order[0]
            }
            None => return Err(SourceError::Ended),
        };
        let shown = pass * self.period + records[index].t - self.first;
        Duration::try_from_secs_f64(shown.max(0.0))
            .ok()
            .and_then(|shown| self.started.checked_add(shown))
            .map(|shown| (index, shown))
            .ok_or(SourceError::Unplayable(self.period))
    }
}

impl FrameSource for ReplaySource {
    fn next_frame(
        &mut self,
        request: &CaptureRequest<'_>,
        earliest: Instant,
    ) -> Result<Option<Taken>, SourceError> {
        let (index, shown) = self.next_shown(earliest)?;
        if !request.sleep_until(shown) {
            return Ok(None);
        }
        let record = &self.recording.records()[index];
        let frame = CapturedFrame {
            frame: self.recording.load_frame(record)?,
            taken: unix_now(),
            camera: record.camera,
            truth: record.pose,
        };
        Ok(Some(Taken { frame, at: shown }))
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;
    use std::sync::atomic::AtomicBool;

    use super::*;
    use crate::daemon::source::capture_all;

    fn sample() -> Recording {
        Recording::open(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sample")).unwrap()
    }

    #[test]
    fn frames_come_in_order_and_spaced_as_asked() {
        let stop = AtomicBool::new(false);
        let mut source = ReplaySource::open(sample(), true).unwrap();
        let request = CaptureRequest {
            count: 3,
            spacing: Duration::from_millis(60),
            deadline: Instant::now() + Duration::from_secs(5),
            stop: &stop,
        };
        let frames = capture_all(&mut source, &request).unwrap();
        assert_eq!(frames.len(), 3);
        let truths: Vec<_> = frames.iter().map(|frame| frame.truth.unwrap()).collect();
        let records = source.recording.records();
        let index = |truth| records.iter().position(|record| record.pose == Some(truth)).unwrap();
        let (a, b, c) = (index(truths[0]), index(truths[1]), index(truths[2]));
        // 60 ms apart at 30 fps: every second frame (or the one after, if a frame is just missed).
        assert!(
            (2..=3).contains(&((b + 24 - a) % 24)) && (2..=3).contains(&((c + 24 - b) % 24)),
            "{a} {b} {c}"
        );
    }

    #[test]
    fn a_finished_recording_without_looping_says_so() {
        let stop = AtomicBool::new(false);
        let mut source = ReplaySource::open(sample(), false).unwrap();
        source.started -= Duration::from_secs(10);
        let request =
            CaptureRequest { count: 1, spacing: Duration::ZERO, deadline: Instant::now(), stop: &stop };
        assert!(matches!(capture_all(&mut source, &request), Err(SourceError::Ended)));
    }

    #[test]
    fn a_looping_recording_starts_again() {
        let stop = AtomicBool::new(false);
        let mut source = ReplaySource::open(sample(), true).unwrap();
        source.started -= Duration::from_secs_f64(source.period * 3.0 + 0.001);
        let request = CaptureRequest {
            count: 1,
            spacing: Duration::ZERO,
            deadline: Instant::now() + Duration::from_secs(1),
            stop: &stop,
        };
        let frame = capture_all(&mut source, &request).unwrap().remove(0);
        assert_eq!(frame.truth, source.recording.records()[1].pose, "the second frame of the fourth pass");
    }
}
