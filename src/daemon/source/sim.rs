//! The simulated source: the built-in renderer filming a robot that walks a figure eight over the
//! field, for demos without a robot. Each frame's true pose travels with it, so the log can show the
//! error.

use std::f64::consts::TAU;
use std::time::Instant;

use super::{CaptureRequest, CapturedFrame, FrameSource, SourceError, Taken, unix_now};
use crate::frame::Frame;
use crate::geometry::{Camera, CameraIntrinsics, FieldModel, FieldPose};
use crate::sim::{Randomisation, render};

/// Seconds for one loop of the figure eight.
const LOOP_SECONDS: f64 = 120.0;

/// The renderer on a scripted walk.
#[derive(Debug)]
pub struct SimSource {
    field: FieldModel,
    randomisation: Randomisation,
    intrinsics: CameraIntrinsics,
    seed: u64,
    started: Instant,
    frames_taken: u64,
}

impl SimSource {
    /// A simulated Nao top camera of `width`×`height` pixels; scenes (light, carpet, other robots)
    /// are drawn from `seed`.
    pub fn new(field: FieldModel, width: u32, height: u32, seed: u64) -> Self {
        Self {
            field,
            randomisation: Randomisation::default(),
            intrinsics: CameraIntrinsics::nao_top().with_resolution(width, height),
            seed,
            started: Instant::now(),
            frames_taken: 0,
        }
    }
}

/// The walk: a figure eight through both halves, 6 m long and 3.6 m wide, facing where it goes.
pub fn walk(seconds: f64) -> FieldPose {
    let phase = TAU * seconds / LOOP_SECONDS;
    let (x, y) = (3.0 * phase.sin(), 1.8 * (2.0 * phase).sin());
    let (dx, dy) = (3.0 * phase.cos(), 3.6 * (2.0 * phase).cos());
    FieldPose::new(x, y, dy.atan2(dx)).expect("the walk stays finite")
}

impl FrameSource for SimSource {
    fn next_frame(
        &mut self,
        request: &CaptureRequest<'_>,
        earliest: Instant,
    ) -> Result<Option<Taken>, SourceError> {
        if !request.sleep_until(earliest) {
            return Ok(None);
        }
        let at = Instant::now();
        let sample = self.randomisation.sample(&self.field, self.seed, self.frames_taken, 1);
        self.frames_taken += 1;
        let pose = walk(self.started.elapsed().as_secs_f64());
        let taken = unix_now();
        let camera = Camera::new(self.intrinsics, &pose, &sample.camera);
        let image = render(&sample.scene, &camera, &sample.settings);
        let frame =
            CapturedFrame { frame: Frame::Rgb(image), taken, camera: Some(sample.camera), truth: Some(pose) };
        Ok(Some(Taken { frame, at }))
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;
    use std::time::Duration;

    use super::*;
    use crate::daemon::source::capture_all;

    #[test]
    fn the_walk_stays_on_the_carpet_and_faces_where_it_goes() {
        let half = FieldModel::default().dimensions().carpet_half_length();
        for step in 0..240 {
            let (a, b) = (walk(step as f64 * 0.5), walk(step as f64 * 0.5 + 0.01));
            assert!(a.x().abs() < half && a.y().abs() < 2.5);
            let moved = (b.y() - a.y()).atan2(b.x() - a.x());
            let turn = (moved - a.heading()).sin().abs();
            assert!(turn < 0.05, "step {step}: heading {} but moving {moved}", a.heading());
        }
    }

    #[test]
    fn frames_carry_their_true_pose() {
        let stop = AtomicBool::new(false);
        let mut source = SimSource::new(FieldModel::default(), 40, 30, 3);
        let request = CaptureRequest {
            count: 2,
            spacing: Duration::ZERO,
            deadline: Instant::now() + Duration::from_secs(10),
            stop: &stop,
        };
        let frames = capture_all(&mut source, &request).unwrap();
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[0].frame.dimensions(), (40, 30));
        assert!(frames[0].truth.unwrap().distance_to(&walk(0.0)) < 0.1);
    }
}
