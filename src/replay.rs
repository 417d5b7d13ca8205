//! Replaying a recording through the relocaliser: one JSON line per frame, optionally one per fused
//! burst of consecutive frames, and the thesis' metrics where the recording has true poses.

use std::io::Write;

use serde::Serialize;
use tracing::warn;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::eval::{
    BurstEvaluation, Evaluation, Metrics, RefinedEvaluation, RefinedMetrics, Sample, TruthEvaluation,
    TruthMetrics, TwinEvaluation, TwinMetrics,
};
use crate::geometry::{FieldPose, PoseSigma};
use crate::pipeline::priors::simulate::{PriorSpec, normal, priors_for};
use crate::pipeline::{BurstError, Estimate, Pipeline};
use crate::protocol::message::LineEvidence;
use crate::recording::{FrameRecord, Recording};
use crate::refine::{CalibrationTracker, PoseCheck};
use crate::relocaliser::{Relocalisation, Timings};

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

/// Where a point or an expected line sample lies: the frame's file and its pixel (u, v).
pub type WirePixel = (String, f64, f64);

/// What the lines say about a burst's true pose (`replay --check-truth`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthReport {
    /// Line points used.
    pub points: usize,
    /// Whether the true pose as recorded meets the verification's shares.
    pub passes: bool,
    /// Share of the points on a line at the true pose.
    pub inlier_share: f64,
    /// Share of the model-line samples expected at the true pose that no point lies near.
    pub unseen_share: Option<f64>,
    /// The points on no line there.
    pub off_lines: Vec<WirePixel>,
    /// The expected samples no point lies near.
    pub unseen: Vec<WirePixel>,
    /// The fit that starts from the true pose (weight 1, alone): where it ended and what the lines
    /// made of it.
    pub fit: WireFusedHypothesis,
}

impl TruthReport {
    /// The report of `check`, made on the frames of `files` (in the order the burst took them).
    fn new(files: &[&str], check: &PoseCheck) -> Self {
        let pixels = |list: &[(usize, nalgebra::Point2<f64>)]| {
            let round = |value: f64| (value * 10.0).round() / 10.0;
            list.iter()
                .map(|(frame, pixel)| (files[*frame].to_owned(), round(pixel.x), round(pixel.y)))
                .collect()
        };
        Self {
            points: check.points,
            passes: check.passes(),
            inlier_share: check.inlier_share,
            unseen_share: check.unseen_share,
            off_lines: pixels(&check.off_lines),
            unseen: pixels(&check.unseen),
            fit: WireFusedHypothesis {
                pose: WirePose::from(&check.fit.pose),
                weight: 1.0,
                sigma: check.fit.sigma,
                lines: Some(check.fit.evidence.into()),
            },
        }
    }
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
    /// The priors that re-weighted the hypotheses, as the message's `prior` names them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prior: Option<String>,
    /// The true pose of the burst's first frame, if recorded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<WirePose>,
    /// What the lines say about the true pose, with `--check-truth`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_truth: Option<TruthReport>,
    /// Why the burst could not be fused, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl BurstReport {
    fn new(
        records: &[FrameRecord],
        estimate: Result<&Estimate, &BurstError>,
        at_truth: Option<TruthReport>,
    ) -> Self {
        let prior = estimate.ok().and_then(|estimate| estimate.priors.names());
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
                            lines: h.lines.map(Into::into),
                        })
                        .collect(),
                ),
                Some(estimate.agreeing),
                None,
            ),
            Err(error) => (None, None, Some(error.to_string())),
        };
        Self {
            burst: records.iter().map(|record| record.file.clone()).collect(),
            hypotheses,
            agreeing,
            prior,
            truth: records[0].pose.as_ref().map(WirePose::from),
            at_truth,
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

    /// A frame without a network: the recorded truth only (its line points count in its burst).
    fn lines_only(record: &FrameRecord) -> Self {
        Self { error: None, ..Self::failure(record, String::new()) }
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
    /// Without a network: what the lines alone found, over bursts with a true pose.
    pub lines_alone: Option<RefinedMetrics>,
    /// The camera calibration learnt over the bursts, where any burst taught it.
    pub calibration: Option<CalibrationTracker>,
    /// Each frame with a true pose, evaluated (for plots).
    pub evaluations: Vec<Evaluation>,
}

/// How a replay treats consecutive frames.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// Frames per standing robot; above 1, every `burst` consecutive frames are fused.
    pub burst: usize,
    /// Priors applied to every fused burst (bursts of one frame when `burst` is 1), drawn around the
    /// burst's true pose where the spec says so.
    pub priors: Vec<PriorSpec>,
    /// Seed of the draws.
    pub prior_seed: u64,
    /// The priors' floor (see [`crate::pipeline::Priors::min_share`]).
    pub min_share: f64,
    /// Pitch and roll offsets added to every recorded camera pose, radians: a robot's extrinsic
    /// calibration, or a deliberate error to see what one costs.
    pub camera_offset: (f64, f64),
    /// Standard deviation of a further pitch and roll error drawn afresh for every burst, radians: how
    /// a robot's stance moves its camera from one burst to the next (0: none).
    pub camera_jitter: f64,
    /// Whether the camera's calibration error is learnt over the bursts (one robot's recording), as
    /// the daemon does; otherwise every burst starts from the recorded poses.
    pub learn_calibration: bool,
    /// Whether every burst with a true pose and line points also checks the lines at that pose (see
    /// [`PoseCheck`]): its line gets an `at_truth` block and the metrics an `at_truth` summary.
    pub check_truth: bool,
}

/// Relocalises every frame of `recording` with `pipeline`, writing one JSON line per frame to `out`;
/// with bursts, a prior or line checks, every burst of consecutive frames (a standing robot) also goes
/// through the rest of the pipeline and is written as one more line (frames need their camera pose in
/// the recording for the line checks). A frame that fails is reported and skipped; only a failing
/// `out` stops the replay.
pub fn replay(
    recording: &Recording,
    pipeline: &Pipeline,
    options: &ReplayOptions,
    out: &mut impl Write,
) -> std::io::Result<ReplaySummary> {
    let burst_size = options.burst.max(1);
    let mut evaluations = Vec::new();
    let mut burst_evaluations = Vec::new();
    let mut refined_evaluations = Vec::new();
    let mut twin_evaluations = Vec::new();
    let mut truth_evaluations = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(options.prior_seed);
    let with_priors = !options.priors.is_empty();
    let mut failed = 0;
    let mut calibration = CalibrationTracker::default();
    // Its own stream, so the priors' draws do not change with the jitter.
    let mut jitter_rng = ChaCha8Rng::seed_from_u64(options.prior_seed);
    jitter_rng.set_stream(1);
    for group in recording.records().chunks(burst_size) {
        let (pitch, roll) = match options.camera_jitter {
            0.0 => options.camera_offset,
            jitter => {
                let (pitch, roll) = options.camera_offset;
                (pitch + jitter * normal(&mut jitter_rng), roll + jitter * normal(&mut jitter_rng))
            }
        };
        // Without learning the tracker stays at the default calibration, the one `Pipeline::burst` takes.
        let mut burst = pipeline.calibrated_burst(calibration.calibration());
        // The frames the burst took, in order (a frame that cannot be loaded is not among them).
        let mut taken: Vec<&str> = Vec::with_capacity(group.len());
        for record in group {
            let _frame = tracing::warn_span!("frame", file = %record.file).entered();
            let head_yaw = record.camera.map_or(0.0, |camera| camera.head_yaw());
            if pipeline.checks_lines() && record.camera.is_none() {
                warn!("no camera pose recorded: frame not used for line refinement");
            }
            let result = (|| {
                let camera = record.camera.map(|camera| camera.corrected(pitch, roll)).transpose();
                let camera = camera.map_err(|error| format!("the corrected camera pose: {error}"))?;
                let frame = recording.load_frame(record).map_err(|error| error.to_string())?;
                taken.push(&record.file);
                burst.add(&frame, head_yaw, camera.as_ref()).map_err(|error| error.to_string())
            })();
            let report = match result {
                Ok(None) => FrameReport::lines_only(record),
                Ok(Some(result)) => {
                    if let Some(truth) = record.pose {
                        evaluations.push(
                            Sample { truth, head_yaw, prediction: result.prediction.clone() }.evaluate(),
                        );
                    }
                    FrameReport::success(record, &result)
                }
                Err(error) => {
                    warn!(%error, "frame skipped");
                    failed += 1;
                    FrameReport::failure(record, error)
                }
            };
            write_line(out, &report)?;
        }
        if burst_size > 1 || with_priors || pipeline.checks_lines() {
            let priors = priors_for(&options.priors, group[0].pose.as_ref(), options.min_share, &mut rng);
            let at_truth = group[0].pose.filter(|_| options.check_truth).and_then(|truth| {
                let check = burst.check_at(&truth)?;
                truth_evaluations.push(TruthEvaluation::new(&truth, &check));
                Some(TruthReport::new(&taken, &check))
            });
            let (estimate, _) = burst.finish(&priors);
            if let (true, Ok(Estimate { camera: Some(measured), .. })) =
                (options.learn_calibration, &estimate)
            {
                calibration.learn(measured);
            }
            match (&estimate, group[0].pose) {
                (Ok(estimate), Some(truth)) => {
                    if (burst_size > 1 || with_priors) && !estimate.network.is_empty() {
                        burst_evaluations.push(BurstEvaluation::new(&truth, &estimate.network));
                    }
                    if pipeline.checks_lines() {
                        refined_evaluations.push(RefinedEvaluation::new(&truth, &estimate.hypotheses));
                    }
                    if with_priors {
                        twin_evaluations.push(TwinEvaluation::new(
                            &truth,
                            &estimate.hypotheses,
                            &estimate.priors.before,
                        ));
                    }
                }
                (Err(BurstError::NoPlace { points }), Some(_)) => {
                    refined_evaluations.push(RefinedEvaluation::nothing(*points));
                }
                _ => {}
            }
            write_line(out, &BurstReport::new(group, estimate.as_ref(), at_truth))?;
        }
    }
    Ok(ReplaySummary {
        frames: recording.records().len(),
        failed,
        metrics: Metrics::summarise(&evaluations, &burst_evaluations, &refined_evaluations).map(
            |mut metrics| {
                metrics.twins = TwinMetrics::summarise(&twin_evaluations);
                if let Some(refined) = &mut metrics.refined {
                    refined.at_truth = TruthMetrics::summarise(&truth_evaluations);
                }
                metrics
            },
        ),
        lines_alone: pipeline
            .relocaliser()
            .is_none()
            .then(|| RefinedMetrics::summarise(&refined_evaluations))
            .flatten()
            .map(|lines| RefinedMetrics { at_truth: TruthMetrics::summarise(&truth_evaluations), ..lines }),
        calibration: (calibration.learnt() > 0).then_some(calibration),
        evaluations,
    })
}

fn write_line(out: &mut impl Write, value: &impl Serialize) -> std::io::Result<()> {
    serde_json::to_writer(&mut *out, value)?;
    writeln!(out)
}
