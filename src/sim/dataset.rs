//! Rendering a whole labelled recording: randomised frames written in the recording format.

use std::path::Path;

use rayon::prelude::*;

use super::randomise::Randomisation;
use super::render::render;
use crate::frame::{Frame, YuyvImage};
use crate::geometry::{Camera, CameraIntrinsics, FieldModel};
use crate::recording::{FrameFormat, FrameRecord, RecordingError, RecordingWriter, write_frame_file};

/// What to render.
#[derive(Clone, Debug)]
pub struct DatasetSpec {
    /// The field drawn.
    pub field: FieldModel,
    /// Camera intrinsics, at the output resolution.
    pub intrinsics: CameraIntrinsics,
    /// How frames are randomised.
    pub randomisation: Randomisation,
    /// Rays per pixel along each axis.
    pub supersample: u32,
    /// Frame file format.
    pub format: FrameFormat,
    /// Number of frames.
    pub count: u64,
    /// Seed: the same seed gives the same frames.
    pub seed: u64,
    /// Frames per standing pose (see [`Randomisation::sample_in_burst`]); 1 gives independent frames.
    pub burst: u64,
    /// Frame rate used for the `t` of each frame.
    pub frames_per_second: f64,
}

/// Renders `spec.count` frames into a new recording at `out`, calling `progress` once per frame.
/// Frames are rendered in parallel and written in order.
pub fn render_dataset(
    spec: &DatasetSpec,
    out: &Path,
    progress: impl Fn() + Sync,
) -> Result<(), RecordingError> {
    let mut writer = RecordingWriter::create(out)?;
    let digits = spec.count.saturating_sub(1).to_string().len().max(6);
    let batch = (rayon::current_num_threads() * 4) as u64;
    let burst = spec.burst.max(1);
    for start in (0..spec.count).step_by(batch as usize) {
        let end = (start + batch).min(spec.count);
        let records: Vec<FrameRecord> = (start..end)
            .into_par_iter()
            .map(|index| {
                let frame = spec.randomisation.sample_in_burst(
                    &spec.field,
                    spec.seed,
                    index / burst,
                    index % burst,
                    spec.supersample,
                );
                let camera = Camera::new(spec.intrinsics, &frame.pose, &frame.camera);
                let image = render(&frame.scene, &camera, &frame.settings);
                let record = FrameRecord {
                    file: format!("{index:0digits$}.{}", spec.format.extension()),
                    t: index as f64 / spec.frames_per_second,
                    pose: Some(frame.pose),
                    camera: Some(frame.camera),
                    width: Some(spec.intrinsics.width),
                    height: Some(spec.intrinsics.height),
                };
                let frame = match spec.format {
                    FrameFormat::Yuyv => Frame::Yuyv(YuyvImage::from_rgb(&image).map_err(|error| {
                        RecordingError::BadFrame { path: out.join(&record.file), reason: error.to_string() }
                    })?),
                    FrameFormat::Png | FrameFormat::Jpeg => Frame::Rgb(image),
                };
                write_frame_file(out, &record, &frame)?;
                progress();
                Ok(record)
            })
            .collect::<Result<_, RecordingError>>()?;
        for record in &records {
            writer.append(record)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::Recording;
    use std::sync::atomic::{AtomicUsize, Ordering};

    fn spec(count: u64, format: FrameFormat) -> DatasetSpec {
        DatasetSpec {
            field: FieldModel::default(),
            intrinsics: CameraIntrinsics::nao_top().with_resolution(32, 24),
            randomisation: Randomisation::default(),
            supersample: 1,
            format,
            count,
            seed: 5,
            burst: 1,
            frames_per_second: 30.0,
        }
    }

    #[test]
    fn writes_a_readable_labelled_recording() {
        let dir = tempfile::tempdir().unwrap();
        let calls = AtomicUsize::new(0);
        render_dataset(&spec(11, FrameFormat::Png), dir.path(), || {
            calls.fetch_add(1, Ordering::Relaxed);
        })
        .unwrap();
        assert_eq!(calls.into_inner(), 11);
        let recording = Recording::open(dir.path()).unwrap();
        assert_eq!(recording.records().len(), 11);
        let last = &recording.records()[10];
        assert_eq!(last.file, "000010.png");
        assert!((last.t - 10.0 / 30.0).abs() < 1e-12);
        assert!(last.pose.is_some() && last.camera.is_some());
        assert_eq!(recording.load_frame(last).unwrap().dimensions(), (32, 24));
    }

    #[test]
    fn bursts_share_a_pose() {
        let dir = tempfile::tempdir().unwrap();
        render_dataset(&DatasetSpec { burst: 3, ..spec(6, FrameFormat::Png) }, dir.path(), || {}).unwrap();
        let poses: Vec<_> = Recording::open(dir.path()).unwrap().records().iter().map(|r| r.pose).collect();
        assert_eq!((poses[0], poses[1]), (poses[2], poses[2]));
        assert_eq!((poses[3], poses[4]), (poses[5], poses[5]));
        assert_ne!(poses[0], poses[3]);
    }

    #[test]
    fn same_seed_same_frames_in_any_format() {
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        render_dataset(&spec(3, FrameFormat::Yuyv), a.path(), || {}).unwrap();
        render_dataset(&spec(3, FrameFormat::Yuyv), b.path(), || {}).unwrap();
        for name in ["frames.jsonl", "000000.yuyv", "000002.yuyv"] {
            assert_eq!(
                std::fs::read(a.path().join(name)).unwrap(),
                std::fs::read(b.path().join(name)).unwrap()
            );
        }
    }
}
