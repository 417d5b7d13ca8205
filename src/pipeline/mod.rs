//! The burst pipeline: where a burst of camera frames becomes the estimate relocd publishes.
//!
//! Frame by frame, as the frames arrive: the network ([`crate::relocaliser`]) and the frame's line
//! points ([`crate::refine::percepts`]). Once per burst: [`fuse`] the frames' predictions, [`verify`]
//! every hypothesis against the field lines (when the pipeline has a field to check against), then
//! the game-context priors re-weight the result. The daemon, `relocd replay` and `relocd bench` all run
//! this one path; none of them assembles the stages itself.

pub mod priors;
mod wire;

use std::time::Instant;

use thiserror::Error;

pub use priors::{PlacementPrior, PriorReport, Priors};

use crate::frame::Frame;
use crate::geometry::{CameraIntrinsics, CameraPose, FieldModel, FieldPose, PoseSigma};
use crate::refine::{FramePercepts, Guess, LineEvidence, LineRefiner, LineVerdict};
use crate::relocaliser::{
    FusionError, Model, Prediction, Relocalisation, RelocaliseError, Relocaliser, fuse as fuse_frames,
};

/// One weighted full-field hypothesis of a burst.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hypothesis {
    /// The robot's pose.
    pub pose: FieldPose,
    /// Its probability; a burst's weights sum to 1.
    pub weight: f64,
    /// Its spread: the network's (the burst's scatter and the frames' predicted σ) or, once the lines
    /// refined it, the line fit's.
    pub sigma: PoseSigma,
    /// What the field lines said about it, once checked.
    pub lines: Option<LineEvidence>,
}

/// What a burst yields.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// The hypotheses, heaviest first.
    pub hypotheses: Vec<Hypothesis>,
    /// The network's hypotheses before the lines checked them (priors applied), heaviest first: what
    /// the network alone would have said.
    pub network: Vec<Hypothesis>,
    /// Frames fused.
    pub frames: usize,
    /// Frames within a metre (heading counted as a metre per radian) of the fused pose.
    pub agreeing: usize,
    /// What the burst's priors did to `hypotheses`.
    pub priors: PriorReport,
}

/// Why a burst gave no estimate.
#[derive(Debug, Error, PartialEq)]
pub enum BurstError {
    /// Every frame failed in the network; the first failure.
    #[error("no frame could be relocalised: {0}")]
    NoFrameRelocalised(String),
    /// The predictions could not be fused.
    #[error(transparent)]
    Fusion(#[from] FusionError),
}

/// Time spent in each stage of a burst, milliseconds, summed over its frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Frames → input tensors.
    pub preprocess_ms: f64,
    /// The network.
    pub inference_ms: f64,
    /// Decoding and unfolding the outputs, fusion and the priors.
    pub fusion_ms: f64,
    /// Line points of the frames, and verifying the hypotheses against them.
    pub lines_ms: f64,
}

/// A network, and optionally a field whose lines check what it says.
#[derive(Debug)]
pub struct Pipeline {
    relocaliser: Relocaliser,
    refiner: Option<LineRefiner>,
    intrinsics: CameraIntrinsics,
}

impl Pipeline {
    /// The network alone. Line points are projected with the camera intrinsics the model's contract
    /// names (the camera its training frames emulate).
    pub fn new(model: Model) -> Self {
        let intrinsics = model.contract().camera;
        Self { relocaliser: Relocaliser::new(model), refiner: None, intrinsics }
    }

    /// Verifies and refines every burst against the lines of `field` (builds its distance map once).
    pub fn with_lines(mut self, field: &FieldModel) -> Self {
        self.refiner = Some(LineRefiner::new(field));
        self
    }

    /// The network.
    pub fn relocaliser(&self) -> &Relocaliser {
        &self.relocaliser
    }

    /// Whether bursts are checked against the field lines.
    pub fn checks_lines(&self) -> bool {
        self.refiner.is_some()
    }

    /// Runs `model`, and projects with its contract's camera, from the next burst on (the field whose
    /// lines are checked stays).
    pub fn replace_model(&mut self, model: Model) {
        self.intrinsics = model.contract().camera;
        self.relocaliser = Relocaliser::new(model);
    }

    /// Starts a burst: add its frames as they arrive, then finish it.
    pub fn burst(&self) -> Burst<'_> {
        Burst {
            pipeline: self,
            predictions: Vec::new(),
            percepts: Vec::new(),
            failures: Vec::new(),
            times: StageTimes::default(),
        }
    }
}

/// A burst in progress.
#[derive(Debug)]
pub struct Burst<'p> {
    pipeline: &'p Pipeline,
    predictions: Vec<Prediction>,
    percepts: Vec<FramePercepts>,
    failures: Vec<String>,
    times: StageTimes,
}

impl Burst<'_> {
    /// Relocalises one frame taken with the head turned by `head_yaw` radians and, when the pipeline
    /// checks lines and `camera` (the camera's pose on the robot) is known, finds its line points. A
    /// frame whose line points cannot be found still counts for the network (the log says why).
    pub fn add(
        &mut self,
        frame: &Frame,
        head_yaw: f64,
        camera: Option<&CameraPose>,
    ) -> Result<Relocalisation, RelocaliseError> {
        if let (Some(refiner), Some(camera)) = (&self.pipeline.refiner, camera) {
            let started = Instant::now();
            match refiner.percepts(frame, &self.pipeline.intrinsics, camera) {
                Ok(found) => self.percepts.push(found),
                Err(error) => tracing::warn!("frame not used for line refinement: {error}"),
            }
            self.times.lines_ms += started.elapsed().as_secs_f64() * 1e3;
        }
        match self.pipeline.relocaliser.relocalise(frame, head_yaw) {
            Ok(result) => {
                self.times.preprocess_ms += result.timings.preprocess_ms;
                self.times.inference_ms += result.timings.inference_ms;
                self.times.fusion_ms += result.timings.decode_ms;
                self.predictions.push(result.prediction.clone());
                Ok(result)
            }
            Err(error) => {
                self.failures.push(error.to_string());
                Err(error)
            }
        }
    }

    /// Why frames failed in the network so far, in order.
    pub fn failures(&self) -> &[String] {
        &self.failures
    }

    /// Fuses the frames, verifies the result against the lines and re-weights it with the burst's
    /// `priors`; returns the estimate and where the burst's time went.
    pub fn finish(mut self, priors: &Priors) -> (Result<Estimate, BurstError>, StageTimes) {
        let fusing = Instant::now();
        let fused = fuse(&self.predictions).map_err(|error| match self.failures.first() {
            Some(failure) => BurstError::NoFrameRelocalised(failure.clone()),
            None => BurstError::Fusion(error),
        });
        self.times.fusion_ms += fusing.elapsed().as_secs_f64() * 1e3;
        let mut estimate = match fused {
            Ok(estimate) => estimate,
            Err(error) => return (Err(error), self.times),
        };
        if let Some(refiner) = &self.pipeline.refiner {
            let verifying = Instant::now();
            verify(refiner, &self.percepts, &mut estimate.hypotheses);
            self.times.lines_ms += verifying.elapsed().as_secs_f64() * 1e3;
        }
        if !priors.is_empty() {
            let weighing = Instant::now();
            estimate.priors = priors.apply(&mut estimate.hypotheses);
            priors.apply(&mut estimate.network);
            self.times.fusion_ms += weighing.elapsed().as_secs_f64() * 1e3;
        }
        (Ok(estimate), self.times)
    }
}

/// Fuses the predictions of a burst of frames of one standing robot (see
/// [`crate::relocaliser::fusion`]); nothing is checked against the lines yet.
pub fn fuse(predictions: &[Prediction]) -> Result<Estimate, FusionError> {
    let fused = fuse_frames(predictions)?;
    let hypotheses: Vec<Hypothesis> = fused
        .hypotheses
        .iter()
        .map(|h| Hypothesis { pose: h.pose, weight: h.weight, sigma: h.sigma, lines: None })
        .collect();
    Ok(Estimate {
        network: hypotheses.clone(),
        hypotheses,
        frames: fused.frames,
        agreeing: fused.agreeing,
        priors: PriorReport::default(),
    })
}

/// Verifies and refines `hypotheses` against the line points of a burst's frames: each takes the fitted
/// pose and σ where the lines support it, every one gets the lines' evidence, and the weights are
/// scaled by the fits' quality (contradicted ones cut), renormalised and sorted heaviest first.
pub fn verify(refiner: &LineRefiner, percepts: &[FramePercepts], hypotheses: &mut [Hypothesis]) {
    let guesses: Vec<Guess> = hypotheses.iter().map(|h| Guess { pose: h.pose, sigma: h.sigma }).collect();
    match refiner.check(percepts, &guesses) {
        LineVerdict::TooFewPoints(evidence) => {
            hypotheses.iter_mut().for_each(|hypothesis| hypothesis.lines = Some(evidence));
        }
        LineVerdict::Checked(fits) => {
            for (hypothesis, fit) in hypotheses.iter_mut().zip(fits) {
                *hypothesis = Hypothesis {
                    pose: fit.pose,
                    weight: hypothesis.weight * fit.factor,
                    sigma: fit.sigma,
                    lines: Some(fit.evidence),
                };
            }
            let total: f64 = hypotheses.iter().map(|hypothesis| hypothesis.weight).sum();
            hypotheses.iter_mut().for_each(|hypothesis| hypothesis.weight /= total);
            hypotheses.sort_by(|a, b| b.weight.total_cmp(&a.weight));
        }
    }
}
