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
use crate::geometry::angle::angle_distance;
use crate::geometry::{CameraIntrinsics, CameraPose, FieldModel, FieldPose, PoseSigma, Symmetry};
use crate::refine::{
    CameraCalibration, CameraMeasurement, FramePercepts, Guess, LineCheck, LineEvidence, LineFit,
    LineRefiner, LineVerdict, PoseCheck, distinct_places, same_place_or_twin,
};
use crate::relocaliser::contract::CameraRange;
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
    /// The camera's (pitch, roll) calibration the lines measured (the burst's calibration and the
    /// heaviest hypothesis's correction on top), where they refined that hypothesis at one place.
    pub camera: Option<CameraMeasurement>,
}

/// Why a burst gave no estimate.
#[derive(Debug, Error, PartialEq)]
pub enum BurstError {
    /// Every frame failed in the network; the first failure.
    #[error("no frame could be relocalised: {0}")]
    NoFrameRelocalised(String),
    /// Without a network, the lines are all there is, and they fit no place on the field.
    #[error("no network, and the {points} line points of the burst fit no place on the field")]
    NoPlace {
        /// Line points of the burst.
        points: usize,
    },
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

/// A network, and optionally a field whose lines check what it says; or the lines alone.
#[derive(Debug)]
pub struct Pipeline {
    relocaliser: Option<Relocaliser>,
    refiner: Option<LineRefiner>,
    search: GlobalSearch,
    intrinsics: CameraIntrinsics,
    /// Whether `intrinsics` are the robot's own (set by [`Pipeline::with_intrinsics`]) rather than
    /// the model contract's.
    calibrated: bool,
    /// The camera poses the network was trained for, where its contract says.
    camera_range: Option<CameraRange>,
}

impl Pipeline {
    /// The network alone. Line points are projected with the camera intrinsics the model's contract
    /// names (the camera its training frames emulate).
    pub fn new(model: Model) -> Self {
        let (intrinsics, camera_range) = (model.contract().camera, model.contract().camera_range());
        Self {
            relocaliser: Some(Relocaliser::new(model)),
            refiner: None,
            search: GlobalSearch::default(),
            intrinsics,
            calibrated: false,
            camera_range,
        }
    }

    /// No network: the lines of `field` alone, searched all over the field after every burst, with
    /// frames taken by a camera with `intrinsics`. For a hall with no network trained for it yet.
    pub fn lines_only(field: &FieldModel, intrinsics: CameraIntrinsics) -> Self {
        Self {
            relocaliser: None,
            refiner: Some(LineRefiner::new(field)),
            search: GlobalSearch::Always,
            intrinsics,
            calibrated: true,
            camera_range: None,
        }
    }

    /// Verifies and refines every burst against the lines of `field` (builds its distance map once).
    pub fn with_lines(mut self, field: &FieldModel) -> Self {
        self.refiner = Some(LineRefiner::new(field));
        self
    }

    /// Projects line points with the robot's own camera intrinsics (its field of view) instead of
    /// those the model's contract names; they stay when the model is replaced.
    pub fn with_intrinsics(mut self, intrinsics: CameraIntrinsics) -> Self {
        (self.intrinsics, self.calibrated) = (intrinsics, true);
        self
    }

    /// Whether the line fits also estimate a correction of the camera's pitch and roll (see
    /// [`LineRefiner::with_camera_correction`]; on by default). Call after [`Pipeline::with_lines`].
    pub fn with_camera_correction(mut self, on: bool) -> Self {
        self.refiner = self.refiner.map(|refiner| refiner.with_camera_correction(on));
        self
    }

    /// Sets when the lines look for places all over the field (see [`GlobalSearch`]).
    pub fn with_global_search(mut self, search: GlobalSearch) -> Self {
        self.search = search;
        self
    }

    /// The network, if there is one.
    pub fn relocaliser(&self) -> Option<&Relocaliser> {
        self.relocaliser.as_ref()
    }

    /// The field lines' refiner, if bursts are checked against them.
    pub fn refiner(&self) -> Option<&LineRefiner> {
        self.refiner.as_ref()
    }

    /// Whether bursts are checked against the field lines.
    pub fn checks_lines(&self) -> bool {
        self.refiner.is_some()
    }

    /// Runs `model`, and projects with its contract's camera unless the robot's own intrinsics were
    /// set, from the next burst on (the field whose lines are checked stays).
    pub fn replace_model(&mut self, model: Model) {
        if !self.calibrated {
            self.intrinsics = model.contract().camera;
        }
        self.camera_range = model.contract().camera_range();
        self.relocaliser = Some(Relocaliser::new(model));
    }

    /// Starts a burst: add its frames as they arrive, then finish it.
    pub fn burst(&self) -> Burst<'_> {
        self.calibrated_burst(CameraCalibration::default())
    }

    /// A burst whose camera poses take `calibration`'s correction, known to its σ (what a
    /// [`crate::refine::CalibrationTracker`] learnt from earlier bursts).
    pub fn calibrated_burst(&self, calibration: CameraCalibration) -> Burst<'_> {
        Burst {
            pipeline: self,
            calibration,
            frames: 0,
            predictions: Vec::new(),
            percepts: Vec::new(),
            percept_frames: Vec::new(),
            failures: Vec::new(),
            times: StageTimes::default(),
            camera_warned: false,
        }
    }
}

/// A burst in progress.
#[derive(Debug)]
pub struct Burst<'p> {
    pipeline: &'p Pipeline,
    calibration: CameraCalibration,
    frames: usize,
    predictions: Vec<Prediction>,
    percepts: Vec<FramePercepts>,
    /// Which frame of the burst (in the order added) each of `percepts` came from.
    percept_frames: Vec<usize>,
    failures: Vec<String>,
    times: StageTimes,
    /// Whether this burst has warned of a camera outside the network's training range.
    camera_warned: bool,
}

impl Burst<'_> {
    /// Relocalises one frame taken with the head turned by `head_yaw` radians (`None` without a
    /// network) and, when the pipeline checks lines and `camera` (the camera's pose on the robot) is
    /// known, finds its line points. A frame whose line points cannot be found still counts for the
    /// network (the log says why).
    pub fn add(
        &mut self,
        frame: &Frame,
        head_yaw: f64,
        camera: Option<&CameraPose>,
    ) -> Result<Option<Relocalisation>, RelocaliseError> {
        self.frames += 1;
        if let (Some(range), Some(camera), false) = (&self.pipeline.camera_range, camera, self.camera_warned)
            && let Some(outside) = range.outside(camera)
        {
            tracing::warn!(
                "the camera is outside what the network was trained for ({outside}): expect it to be off"
            );
            self.camera_warned = true;
        }
        if let (Some(refiner), Some(camera)) = (&self.pipeline.refiner, camera) {
            let started = Instant::now();
            let correction = self.calibration.correction;
            let found = camera
                .corrected(correction.x, correction.y)
                .map_err(|error| format!("the calibrated camera pose: {error}"))
                .and_then(|camera| {
                    refiner
                        .percepts(frame, &self.pipeline.intrinsics, &camera)
                        .map_err(|error| error.to_string())
                });
            match found {
                Ok(found) => {
                    self.percepts.push(found.with_camera_sigma(self.calibration.sigma));
                    self.percept_frames.push(self.frames - 1);
                }
                Err(error) => tracing::warn!("frame not used for line refinement: {error}"),
            }
            self.times.lines_ms += started.elapsed().as_secs_f64() * 1e3;
        }
        let Some(relocaliser) = &self.pipeline.relocaliser else { return Ok(None) };
        match relocaliser.relocalise(frame, head_yaw) {
            Ok(result) => {
                self.times.preprocess_ms += result.timings.preprocess_ms;
                self.times.inference_ms += result.timings.inference_ms;
                self.times.fusion_ms += result.timings.decode_ms;
                self.predictions.push(result.prediction.clone());
                Ok(Some(result))
            }
            Err(error) => {
                self.failures.push(error.to_string());
                Err(error)
            }
        }
    }

    /// What the line points of the frames so far say about `pose`, such as the robot's true pose (see
    /// [`PoseCheck`]; its frame indices count the frames in the order added); `None` without line
    /// checks or with too few line points.
    pub fn check_at(&self, pose: &FieldPose) -> Option<PoseCheck> {
        let mut check = self.pipeline.refiner.as_ref()?.check_at(&self.percepts, pose)?;
        for (frame, _) in check.off_lines.iter_mut().chain(check.unseen.iter_mut()) {
            *frame = self.percept_frames[*frame];
        }
        Some(check)
    }

    /// Why frames failed in the network so far, in order.
    pub fn failures(&self) -> &[String] {
        &self.failures
    }

    /// Fuses the frames, verifies the result against the lines and re-weights it with the burst's
    /// `priors`; returns the estimate and where the burst's time went.
    pub fn finish(mut self, priors: &Priors) -> (Result<Estimate, BurstError>, StageTimes) {
        if self.pipeline.relocaliser.is_none() {
            let started = Instant::now();
            let estimate = self.lines_alone(priors);
            self.times.lines_ms += started.elapsed().as_secs_f64() * 1e3;
            return (estimate, self.times);
        }
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
            let context = priors.guesses();
            let measured =
                verify(refiner, &self.percepts, &mut estimate.hypotheses, &context, self.pipeline.search);
            estimate.camera = measured.map(|measured| self.calibrated(measured));
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

    /// The estimate of a pipeline without a network: every place the lines fit, and its twin.
    fn lines_alone(&self, priors: &Priors) -> Result<Estimate, BurstError> {
        let mut hypotheses = Vec::new();
        let mut camera = None;
        if let Some(refiner) = &self.pipeline.refiner {
            let measured =
                verify(refiner, &self.percepts, &mut hypotheses, &priors.guesses(), GlobalSearch::Always);
            camera = measured.map(|measured| self.calibrated(measured));
        }
        if hypotheses.is_empty() {
            let points = self.percepts.iter().map(|frame| frame.points.len()).sum();
            return Err(BurstError::NoPlace { points });
        }
        let report = if priors.is_empty() { PriorReport::default() } else { priors.apply(&mut hypotheses) };
        Ok(Estimate {
            hypotheses,
            network: Vec::new(),
            frames: self.frames,
            agreeing: self.frames,
            priors: report,
            camera,
        })
    }

    /// A correction measured on top of this burst's camera poses, as a whole calibration.
    fn calibrated(&self, measured: CameraMeasurement) -> CameraMeasurement {
        CameraMeasurement { correction: self.calibration.correction + measured.correction, ..measured }
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
        camera: None,
    })
}

/// When the lines look for places all over the field, beyond the network's hypotheses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GlobalSearch {
    /// Never: the lines only check the network's hypotheses.
    Never,
    /// When the lines do not refine the network's heaviest hypothesis (contradicted or partial): the
    /// default, measured on held-out sets (BENCHMARKS.md, "Global search on fresh seeds").
    #[default]
    WhenUnsure,
    /// After every burst with enough line points (also catches a refinement that locked onto the
    /// wrong one of several places that look alike).
    Always,
}

impl std::str::FromStr for GlobalSearch {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            "never" => Ok(Self::Never),
            "when_unsure" => Ok(Self::WhenUnsure),
            "always" => Ok(Self::Always),
            _ => Err(format!("unknown global search {name:?}: expected never, when_unsure or always")),
        }
    }
}

/// Share of the weight a line-consistent place keeps however far the network's hypotheses are (the
/// network is a prior over the places the lines allow, not a gate).
const NETWORK_FLOOR: f64 = 0.05;
/// Least spread of a network hypothesis when it weighs places (metres, radians).
const MIN_NETWORK_SIGMA: (f64, f64) = (0.1, 0.05);
/// How far off a place's pose may be along what its lines leave open where no network hypothesis
/// explains it (metres, radians): a lone line runs metres across the field.
const UNINFORMED_SIGMA: (f64, f64) = (2.0, 0.5);

/// Verifies and refines `hypotheses` against the line points of a burst's frames: each takes the fitted
/// pose and σ where the lines support it, every one gets the lines' evidence, and the weights are
/// scaled by the fits' quality (contradicted ones cut), renormalised and sorted heaviest first.
/// The lines also check the `context` guesses (the poses the burst's priors name) and search near them
/// ([`LineRefiner::search_near`]), and where `search`
/// says so they look all over the field and near the heaviest hypothesis ([`search_places`]): if a
/// context guess or the search finds a place, the hypotheses become the places the lines fit and their
/// point-symmetric twins, weighted by the fit's quality and by how likely the network's hypotheses
/// make them (never below a floor), and marked `ambiguous` when there is more than one place. Every
/// σ keeps what the lines fix and, along what they leave open, the network's spread (or, for a place
/// the network does not explain, [`UNINFORMED_SIGMA`]): a fit along one line does not know where on
/// it the robot stands. Returns what the heaviest hypothesis's fit measured
/// of the camera's correction on top of the frames' poses, where it ends `refined`.
pub fn verify(
    refiner: &LineRefiner,
    percepts: &[FramePercepts],
    hypotheses: &mut Vec<Hypothesis>,
    context: &[Guess],
    search: GlobalSearch,
) -> Option<CameraMeasurement> {
    let network = hypotheses.iter().map(|h| Guess { pose: h.pose, sigma: h.sigma });
    let guesses: Vec<Guess> = network.chain(context.iter().copied()).collect();
    let mut fits = match refiner.check(percepts, &guesses) {
        LineVerdict::TooFewPoints(evidence) => {
            hypotheses.iter_mut().for_each(|hypothesis| hypothesis.lines = Some(evidence));
            return None;
        }
        LineVerdict::Checked(fits) => fits,
    };
    // Near a context guess the lines search even where they refine it: a place half a metre off may
    // fit as well (the penalty area's lines), and then the burst is ambiguous.
    let mut found: Vec<LineFit> = fits.split_off(hypotheses.len());
    found.retain(|fit| fit.evidence.check != LineCheck::Contradicted);
    found.extend(context.iter().flat_map(|guess| refiner.search_near(percepts, guess)));
    let heaviest = hypotheses
        .iter()
        .zip(&fits)
        .max_by(|(a, fa), (b, fb)| (a.weight * fa.factor).total_cmp(&(b.weight * fb.factor)))
        .map(|(_, fit)| fit.evidence.check);
    let look = match search {
        GlobalSearch::Never => false,
        GlobalSearch::WhenUnsure => heaviest != Some(LineCheck::Refined),
        GlobalSearch::Always => true,
    };
    if look {
        found.extend(search_places(
            refiner,
            percepts,
            hypotheses.iter().max_by(|a, b| a.weight.total_cmp(&b.weight)),
        ));
    }
    let places = if look || !found.is_empty() { places(&fits, found) } else { Vec::new() };
    // Each hypothesis's camera measurement, in the hypotheses' order.
    let mut cameras = Vec::new();
    if places.is_empty() {
        for (hypothesis, fit) in hypotheses.iter_mut().zip(fits) {
            *hypothesis = Hypothesis {
                pose: fit.pose,
                weight: hypothesis.weight * fit.factor,
                sigma: fit.spread_with(&floored(&hypothesis.sigma)),
                lines: Some(fit.evidence),
            };
            cameras.push(fit.camera);
        }
    } else {
        let network = std::mem::take(hypotheses);
        // Several fits are ambiguous even where they are one place (along one line): which pose on it
        // is right, the lines cannot say; `places` counts the places.
        let (fitted, count) = (places.len(), distinct_places(&places));
        for place in places {
            let evidence = LineEvidence {
                check: if fitted > 1 { LineCheck::Ambiguous } else { place.evidence.check },
                places: Some(count),
                ..place.evidence
            };
            for pose in [place.pose, Symmetry::PointReflection.apply(&place.pose)] {
                let weight = place.factor * (NETWORK_FLOOR + network_likelihood(&pose, &network));
                let sigma = place.spread_with(&prior_spread(&pose, &network));
                hypotheses.push(Hypothesis { pose, weight, sigma, lines: Some(evidence) });
                cameras.push(place.camera);
            }
        }
    }
    let total: f64 = hypotheses.iter().map(|hypothesis| hypothesis.weight).sum();
    hypotheses.iter_mut().for_each(|hypothesis| hypothesis.weight /= total);
    let heaviest =
        (0..hypotheses.len()).max_by(|&a, &b| hypotheses[a].weight.total_cmp(&hypotheses[b].weight));
    let camera = heaviest
        .filter(|&index| hypotheses[index].lines.is_some_and(|lines| lines.check == LineCheck::Refined))
        .and_then(|index| cameras[index]);
    hypotheses.sort_by(|a, b| b.weight.total_cmp(&a.weight));
    camera
}

/// The places the lines fit all over the field and, with a `heaviest` network hypothesis, near it
/// (within twice its σ, [`LineRefiner::search_near`]): the coarse grid's best candidates field-wide
/// can all lie along other lines than the one the network points to, and then the right place would
/// be missing from an ambiguous burst.
pub fn search_places(
    refiner: &LineRefiner,
    percepts: &[FramePercepts],
    heaviest: Option<&Hypothesis>,
) -> Vec<LineFit> {
    let mut found = refiner.search(percepts);
    if let Some(hypothesis) = heaviest {
        found
            .extend(refiner.search_near(percepts, &Guess { pose: hypothesis.pose, sigma: hypothesis.sigma }));
    }
    found
}

/// The places the lines fit: the network's hypotheses the lines supported (`fits`) and the places
/// `found` beyond them, one per point-symmetric pair.
fn places(fits: &[LineFit], found: Vec<LineFit>) -> Vec<LineFit> {
    let mut places: Vec<LineFit> = Vec::new();
    let supported = fits.iter().filter(|fit| fit.evidence.check != LineCheck::Contradicted).copied();
    for place in supported.chain(found) {
        if !places.iter().any(|known| same_place_or_twin(&known.pose, &place.pose)) {
            places.push(place);
        }
    }
    places
}

/// How likely the network's hypotheses (a mixture of Gaussians with their weights and spreads) make
/// `pose`, relative to the likelihood at a hypothesis' centre; 1 when there is no network.
fn network_likelihood(pose: &FieldPose, network: &[Hypothesis]) -> f64 {
    if network.is_empty() {
        return 1.0;
    }
    network.iter().map(|hypothesis| likelihood_under(pose, hypothesis)).sum()
}

/// The share of `pose`'s network likelihood that `hypothesis` gives: its weight times its Gaussian
/// (spread at least [`MIN_NETWORK_SIGMA`]) relative to the Gaussian's peak.
fn likelihood_under(pose: &FieldPose, hypothesis: &Hypothesis) -> f64 {
    let sigma = floored(&hypothesis.sigma);
    let dx = (pose.x() - hypothesis.pose.x()) / sigma.x;
    let dy = (pose.y() - hypothesis.pose.y()) / sigma.y;
    let dtheta = angle_distance(pose.heading(), hypothesis.pose.heading()) / sigma.theta;
    let exponent = -0.5 * (dx * dx + dy * dy + dtheta * dtheta);
    hypothesis.weight * if exponent.is_finite() { exponent.exp() } else { 0.0 }
}

/// A network hypothesis's spread, at least [`MIN_NETWORK_SIGMA`].
fn floored(sigma: &PoseSigma) -> PoseSigma {
    PoseSigma {
        x: sigma.x.max(MIN_NETWORK_SIGMA.0),
        y: sigma.y.max(MIN_NETWORK_SIGMA.0),
        theta: sigma.theta.max(MIN_NETWORK_SIGMA.1),
    }
}

/// What is known about a place's pose before its lines: the spread of the network hypothesis that
/// makes `pose` likeliest, where it explains the place better than the floor every place keeps;
/// otherwise (and with no network) [`UNINFORMED_SIGMA`].
fn prior_spread(pose: &FieldPose, network: &[Hypothesis]) -> PoseSigma {
    let likeliest = network
        .iter()
        .map(|hypothesis| (likelihood_under(pose, hypothesis), hypothesis))
        .max_by(|(a, _), (b, _)| a.total_cmp(b));
    match likeliest {
        Some((likelihood, hypothesis)) if likelihood >= NETWORK_FLOOR => floored(&hypothesis.sigma),
        _ => PoseSigma { x: UNINFORMED_SIGMA.0, y: UNINFORMED_SIGMA.0, theta: UNINFORMED_SIGMA.1 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn network_hypothesis(x: f64, y: f64, weight: f64, sigma: f64) -> Hypothesis {
        let pose = FieldPose::new(x, y, 0.0).unwrap();
        Hypothesis { pose, weight, sigma: PoseSigma { x: sigma, y: sigma, theta: 0.01 }, lines: None }
    }

    #[test]
    fn a_place_the_network_explains_takes_its_spread_and_any_other_is_uninformed() {
        let network = [network_hypothesis(1.0, 0.0, 0.9, 0.8), network_hypothesis(-1.0, 0.0, 0.1, 0.3)];
        let near = FieldPose::new(1.5, 0.3, 0.0).unwrap();
        // The likeliest hypothesis decides; its heading σ is raised to the floor.
        assert_eq!(prior_spread(&near, &network), PoseSigma { x: 0.8, y: 0.8, theta: MIN_NETWORK_SIGMA.1 });
        let uninformed =
            PoseSigma { x: UNINFORMED_SIGMA.0, y: UNINFORMED_SIGMA.0, theta: UNINFORMED_SIGMA.1 };
        // Three metres from both, the place stands on the floor alone.
        assert_eq!(prior_spread(&FieldPose::new(1.0, 3.0, 0.0).unwrap(), &network), uninformed);
        assert_eq!(prior_spread(&near, &[]), uninformed);
    }
}
