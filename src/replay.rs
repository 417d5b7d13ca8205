//! Replaying a recording through the relocaliser: one JSON line per frame, optionally one per fused
//! burst of consecutive frames, and the thesis' metrics where the recording has true poses.

use std::io::Write;

use serde::Serialize;
use tracing::warn;

use crate::eval::{BurstEvaluation, Evaluation, Metrics, RefinedEvaluation, Sample};
use crate::frame::Frame;
use crate::geometry::{CameraIntrinsics, FieldPose};
use crate::recording::{FrameRecord, Recording};
use crate::refine::{FramePercepts, LineEvidence, LineRefiner};
use crate::relocaliser::{
    BurstEstimate, PlacementPrior, PoseSigma, Relocalisation, Relocaliser, Timings, fuse,
};

/// A pose on the wire: metres and radians.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WirePose {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// Heading, radians.
    pub theta: f64,
}

impl From<&FieldPose> for WirePose {
    fn from(pose: &FieldPose) -> Self {
        Self { x: pose.x(), y: pose.y(), theta: pose.heading() }
    }
}

/// One weighted hypothesis on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WireHypothesis {
    /// The pose.
    #[serde(flatten)]
    pub pose: WirePose,
    /// Its weight; a frame's weights sum to 1.
    pub weight: f64,
}

/// One fused hypothesis on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WireFusedHypothesis {
    /// The pose.
    #[serde(flatten)]
    pub pose: WirePose,
    /// Its weight; a burst's weights sum to 1.
    pub weight: f64,
    /// Its spread.
    pub sigma: PoseSigma,
    /// What the field lines said about it, when refinement is on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lines: Option<LineEvidence>,
}

/// The line written for a fused burst, after the lines of its frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BurstReport {
    /// The files of the frames in the burst.
    pub burst: Vec<String>,
    /// Fused full-field hypotheses, heaviest first.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hypotheses: Option<Vec<WireFusedHypothesis>>,
    /// Frames that agree with the fused pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub agreeing: Option<usize>,
    /// The true pose of the burst's first frame, if recorded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<WirePose>,
    /// Why the burst could not be fused, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl BurstReport {
    fn new(records: &[FrameRecord], estimate: Result<&BurstEstimate, String>) -> Self {
        let (hypotheses, agreeing, error) = match estimate {
            Ok(estimate) => (
                Some(
                    estimate
                        .hypotheses
                        .iter()
                        .map(|h| WireFusedHypothesis {
                            pose: WirePose::from(&h.pose),
                            weight: h.weight,
                            sigma: h.sigma,
                            lines: h.lines,
                        })
                        .collect(),
                ),
                Some(estimate.agreeing),
                None,
            ),
            Err(error) => (None, None, Some(error)),
        };
        Self {
            burst: records.iter().map(|record| record.file.clone()).collect(),
            hypotheses,
            agreeing,
            truth: records[0].pose.as_ref().map(WirePose::from),
            error,
        }
    }
}

/// The line written for one frame.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameReport {
    /// Frame file.
    pub file: String,
    /// Capture time, seconds.
    pub t: f64,
    /// The folded camera pose the network predicted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub folded: Option<WirePose>,
    /// Probability of each fold bit.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fold_probabilities: Option<Vec<f64>>,
    /// Predicted position standard deviation, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub position_sigma: Option<f64>,
    /// Predicted heading standard deviation, radians.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_sigma: Option<f64>,
    /// Full-field hypotheses, heaviest first.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hypotheses: Option<Vec<WireHypothesis>>,
    /// Stage timings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timings: Option<Timings>,
    /// The recorded true pose, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<WirePose>,
    /// Why this frame failed, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl FrameReport {
    fn success(record: &FrameRecord, result: &Relocalisation) -> Self {
        let folded = &result.prediction.folded;
        Self {
            file: record.file.clone(),
            t: record.t,
            folded: Some(WirePose { x: folded.x(), y: folded.y(), theta: folded.heading() }),
            fold_probabilities: Some(result.prediction.fold_probabilities.clone()),
            position_sigma: Some(result.prediction.position_sigma),
            heading_sigma: Some(result.prediction.heading_sigma),
            hypotheses: Some(
                result
                    .hypotheses
                    .iter()
                    .map(|h| WireHypothesis { pose: WirePose::from(&h.pose), weight: h.weight })
                    .collect(),
            ),
            timings: Some(result.timings),
            truth: record.pose.as_ref().map(WirePose::from),
            error: None,
        }
    }

    fn failure(record: &FrameRecord, error: String) -> Self {
        Self {
            file: record.file.clone(),
            t: record.t,
            folded: None,
            fold_probabilities: None,
            position_sigma: None,
            heading_sigma: None,
            hypotheses: None,
            timings: None,
            truth: record.pose.as_ref().map(WirePose::from),
            error: Some(error),
        }
    }
}

/// What a replay found.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplaySummary {
    /// Frames in the recording.
    pub frames: usize,
    /// Frames that could not be relocalised (each reported on its line and in the log).
    pub failed: usize,
    /// The metrics over frames with a true pose, if any.
    pub metrics: Option<Metrics>,
    /// Each frame with a true pose, evaluated (for plots).
    pub evaluations: Vec<Evaluation>,
}

/// How a replay treats consecutive frames.
#[derive(Clone, Debug, Default)]
pub struct ReplayOptions<'a> {
    /// Frames per standing robot; above 1, every `burst` consecutive frames are fused.
    pub burst: usize,
    /// A game-context prior applied to every fused burst (bursts of one frame when `burst` is 1).
    pub prior: Option<PlacementPrior>,
    /// Verify and refine every burst (bursts of one frame when `burst` is 1) against the field lines
    /// its frames show; frames need their camera pose in the recording.
    pub refiner: Option<&'a LineRefiner>,
}

/// Relocalises every frame of `recording`, writing one JSON line per frame to `out`; with bursts or a
/// prior, every burst of consecutive frames (a standing robot) is also fused, re-weighted by the prior,
/// and written as one more line. A frame that fails is reported and skipped; only a failing `out` stops
/// the replay.
pub fn replay(
    recording: &Recording,
    relocaliser: &Relocaliser,
    options: &ReplayOptions,
    out: &mut impl Write,
) -> std::io::Result<ReplaySummary> {
    let burst = options.burst.max(1);
    let mut evaluations = Vec::new();
    let mut burst_evaluations = Vec::new();
    let mut refined_evaluations = Vec::new();
    let mut failed = 0;
    for group in recording.records().chunks(burst) {
        let mut predictions = Vec::with_capacity(group.len());
        let mut percepts = Vec::new();
        for record in group {
            let head_yaw = record.camera.map_or(0.0, |camera| camera.head_yaw());
            let result = recording.load_frame(record).map_err(|error| error.to_string()).and_then(|frame| {
                if let Some(refiner) = options.refiner {
                    percepts.extend(frame_percepts(refiner, record, &frame));
                }
                relocaliser.relocalise(&frame, head_yaw).map_err(|error| error.to_string())
            });
            let report = match result {
                Ok(result) => {
                    if let Some(truth) = record.pose {
                        evaluations.push(
                            Sample { truth, head_yaw, prediction: result.prediction.clone() }.evaluate(),
                        );
                    }
                    let report = FrameReport::success(record, &result);
                    predictions.push(result.prediction);
                    report
                }
                Err(error) => {
                    warn!(file = %record.file, %error, "frame skipped");
                    failed += 1;
                    FrameReport::failure(record, error)
                }
            };
            write_line(out, &report)?;
        }
        if burst > 1 || options.prior.is_some() || options.refiner.is_some() {
            let mut estimate = fuse(&predictions);
            if let (Ok(estimate), Some(truth)) = (&estimate, group[0].pose) {
                if burst > 1 || options.prior.is_some() {
                    let mut unrefined = estimate.clone();
                    if let Some(prior) = &options.prior {
                        prior.apply(&mut unrefined.hypotheses);
                    }
                    burst_evaluations.push(BurstEvaluation::new(&truth, &unrefined));
                }
            }
            if let (Ok(estimate), Some(refiner)) = (&mut estimate, options.refiner) {
                refiner.refine(&percepts, estimate);
            }
            if let (Ok(estimate), Some(prior)) = (&mut estimate, &options.prior) {
                prior.apply(&mut estimate.hypotheses);
            }
            if let (Ok(estimate), Some(truth), Some(_)) = (&estimate, group[0].pose, options.refiner) {
                refined_evaluations.push(RefinedEvaluation::new(&truth, estimate));
            }
            write_line(out, &BurstReport::new(group, estimate.as_ref().map_err(ToString::to_string)))?;
        }
    }
    Ok(ReplaySummary {
        frames: recording.records().len(),
        failed,
        metrics: Metrics::summarise(&evaluations, &burst_evaluations, &refined_evaluations),
        evaluations,
    })
}

/// The line points of one frame, or none (with a warning) when its camera pose is not recorded or the
/// frame cannot be searched.
fn frame_percepts(refiner: &LineRefiner, record: &FrameRecord, frame: &Frame) -> Option<FramePercepts> {
    let Some(camera) = record.camera else {
        warn!(file = %record.file, "no camera pose recorded: frame not used for line refinement");
        return None;
    };
    refiner
        .percepts(frame, &CameraIntrinsics::nao_top(), &camera)
        .inspect_err(|error| warn!(file = %record.file, %error, "no line points"))
        .ok()
}

fn write_line(out: &mut impl Write, value: &impl Serialize) -> std::io::Result<()> {
    serde_json::to_writer(&mut *out, value)?;
    writeln!(out)
}
