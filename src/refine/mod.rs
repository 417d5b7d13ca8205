//! Line refinement: the network proposes, the field lines verify and refine.
//!
//! Each frame gives line points on the ground in the robot frame ([`percepts`]). For every hypothesis of
//! a burst, the points are fitted to the field's lines ([`optimise`], on the [`line_map`]), starting
//! from and held to the hypothesis; the fit is then checked: the share of points that lie on a line, and
//! the share of the lines the camera should have seen under that pose that it did see. Hypotheses the
//! lines contradict lose weight; the rest take the fitted pose and its σ. A hypothesis and its twin by
//! the point symmetry see the same lines, so they always score the same: only the game prior (or the
//! surroundings, through the network) can tell them apart.

pub mod calibration;
pub mod line_map;
pub mod optimise;
pub mod percepts;
pub mod search;

use std::borrow::Cow;
use std::sync::OnceLock;

use nalgebra::{Matrix3, Point2, Point3, Vector2, Vector3};

pub use calibration::{CalibrationTracker, CameraCalibration, CameraMeasurement};
pub use line_map::LineMap;
use line_map::Primitive;
pub use percepts::{
    FramePercepts, ImagePercepts, LineCrossing, LinePoint, PerceptError, PostPoint, PostSighting, detect,
    detect_in_image,
};

use crate::frame::Frame;
use crate::geometry::angle::angle_distance;
use crate::geometry::{Camera, CameraIntrinsics, CameraPose, FieldModel, FieldPose, PoseSigma, Symmetry};
use optimise::{Observation, PostBearing, PostBearings, Prior, fit};
use search::{Region, SearchMap};

/// Fewest line points a burst needs for refinement.
pub const MIN_POINTS: usize = 12;
/// σ across its line of a point at the robot's feet, metres.
const POINT_SIGMA: f64 = 0.015;
/// Camera pitch uncertainty, radians: a point's σ grows by d²/h times this at distance d.
const PITCH_SIGMA: f64 = 0.005;
/// Farthest line point used, metres.
const MAX_POINT_DISTANCE: f64 = 5.0;
/// Most line points a burst's fits use, evenly spread over its frames and weighted to stand for the
/// rest: one frame's worth ([`percepts::MAX_POINTS`]), so that every fit costs what one frame's does
/// however many frames the burst has.
const MAX_BURST_POINTS: usize = percepts::MAX_POINTS;
/// Nearest and farthest model line the camera is expected to see, metres.
const EXPECTED_RANGE: (f64, f64) = (0.3, 3.0);
/// Spacing of the model-line samples checked for being seen, metres.
const EXPECTED_SPACING: f64 = 0.1;
/// Model-line samples closer than this, metres, are one (the shared end of two lines that meet).
const SAME_SAMPLE: f64 = 0.01;
/// Shortest painted segment whose absence counts against a pose, metres: a penalty mark's arms are
/// shorter and the percepts drop a mark as they drop a ball's patch (a blob that does not continue).
const MIN_EXPECTED_SEGMENT: f64 = 0.3;
/// Fewest expected samples for the unseen share to count.
const MIN_EXPECTED: usize = 8;
/// A point within this many σ of a line is an inlier (and always within 5 cm).
const INLIER_SIGMAS: f64 = 2.5;
/// Least share of the points on a line, and largest share of the expected lines unseen, for a fit to
/// stand: a true pose has (nearly) all points on lines and sees what it should, while a wrong fit that
/// found lines elsewhere leaves a few points off or misses a line (measured: BENCHMARKS.md; the
/// unseen limit was 5% until the percepts dropped crossings that do not line up, which thins a short
/// line's few crossings).
const MIN_INLIER_SHARE: f64 = 0.97;
const MAX_UNSEEN_SHARE: f64 = 0.1;
/// Lines whose directions' sines differ by less than this are parallel (10°).
const PARALLEL_SINE: f64 = 0.17;
/// Weight factor on top of the quality for a contradicted hypothesis.
const CONTRADICTED_FACTOR: f64 = 0.1;
/// Largest line-only σ (position, metres; heading, radians) for a fit to count as fully refined: about
/// the 5 cm / 1° a refined pose claims (at 10 cm / 2° fits 5–10 cm off were called refined). A
/// refined fit also needs [`MIN_POINTS`] of its points off the main line direction.
const REFINED_SIGMA: (f64, f64) = (0.06, 0.02);
/// Least prior σ (position, metres; heading, radians) the search starts from.
const MIN_PRIOR_SIGMA: (f64, f64) = (0.15, 0.09);
/// Largest prior σ the search covers.
const MAX_PRIOR_SIGMA: (f64, f64) = (0.6, 0.35);
/// Coarse-grid candidates the global search fits and checks, at most.
const SEARCH_CANDIDATES: usize = 10;
/// Candidates whose points lie farther than this from the lines on average (metres, on the coarse
/// grid) are not worth a fit.
const SEARCH_MAX_MEAN_DISTANCE: f64 = 0.12;
/// Line points one search's fits use in all (candidates times points per fit): where many candidates
/// pass, each is fitted to fewer points, evenly spread and weighted to stand for the rest, and still
/// checked against all of them, so a burst of five frames costs about what one frame does. With all
/// [`SEARCH_CANDIDATES`], 100 points each, as many as the fit's coarse search scores (on tuning
/// seeds as many poses were found as with every point; BENCHMARKS.md, "A budget for the search's
/// fits").
const SEARCH_FIT_POINTS: usize = 1000;
/// Widest reach of [`LineRefiner::search_near`] around its guess (metres, radians).
const NEAR_REACH: (f64, f64) = (2.0, 1.0);
/// Fits closer than this (metres, radians) are one place.
const SAME_PLACE: (f64, f64) = (0.1, 0.035);
/// Fits closer than this many of their combined σ in every component are one place too.
const PLACE_SIGMAS: f64 = 2.0;

/// `sigma` within `low..=high`; a spread that is not a number searches the widest region (`high`).
fn bounded(sigma: f64, low: f64, high: f64) -> f64 {
    if sigma.is_finite() { sigma.clamp(low, high) } else { high }
}

/// What the lines made of one hypothesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineCheck {
    /// The lines fix x, y and heading (to `REFINED_SIGMA`): the pose and σ are the fit's.
    Refined,
    /// The lines fit but fix less (one family of parallel lines, or σ wider than `REFINED_SIGMA`):
    /// fitted, with the network's pose holding the rest.
    Partial,
    /// Too few line points: the network's hypothesis as it was.
    Unrefined,
    /// The lines seen do not fit this pose cleanly (points off the lines, or lines it should show
    /// missing): kept at the network's pose with its weight cut.
    Contradicted,
    /// The lines fit this pose, and other places on the field just as well (a corner, two parallel
    /// lines): one of several line-consistent places, weighted by the network and the priors.
    Ambiguous,
}

/// The lines' evidence about one hypothesis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineEvidence {
    /// What was done with it.
    pub check: LineCheck,
    /// Line points used (all frames of the burst).
    pub points: usize,
    /// Share of the points that lie on a field line under the pose.
    pub inlier_share: f64,
    /// Share of the field lines the camera should have seen under the pose that it did not see;
    /// `None` when too few lines were expected to tell.
    pub unseen_share: Option<f64>,
    /// How many places on the field (a point-symmetric pair counted once) the lines fit, when the
    /// global search looked or a prior's guess found a place; `None` otherwise.
    pub places: Option<usize>,
}

/// A pose to verify, and the spread around it the fit may search.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guess {
    /// The robot's pose.
    pub pose: FieldPose,
    /// How far off it may be.
    pub sigma: PoseSigma,
}

/// What the lines made of one guess.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineFit {
    /// The fitted pose, or the guess's where the lines contradict it.
    pub pose: FieldPose,
    /// The fit's spread, or the guess's where the lines contradict it.
    pub sigma: PoseSigma,
    /// The lines' evidence.
    pub evidence: LineEvidence,
    /// Factor for the guess's weight: the fit's quality squared, cut further where contradicted.
    pub factor: f64,
    /// What a refined fit's lines say about the camera's (pitch, roll) correction on top of the
    /// frames' camera poses, where they fix it.
    pub camera: Option<CameraMeasurement>,
    /// What the lines alone say about the fitted pose (x, y, heading): the information matrix of the
    /// fit without its prior, degenerate along what they leave open; zero where contradicted.
    pub line_information: Matrix3<f64>,
}

impl LineFit {
    /// The same fit for the point-symmetric twin pose, which sees the same lines.
    fn point_reflected(&self) -> LineFit {
        // x and y change sign, the heading's rate does not.
        let flip = Matrix3::from_diagonal(&Vector3::new(-1.0, -1.0, 1.0));
        LineFit {
            pose: Symmetry::PointReflection.apply(&self.pose),
            line_information: flip * self.line_information * flip,
            ..*self
        }
    }

    /// The fitted pose's spread under the lines and an independent `prior` about it: what the lines
    /// fix keeps their spread, what they leave open (along a lone line) keeps the prior's. The same for
    /// the point-symmetric twin.
    pub fn spread_with(&self, prior: &PoseSigma) -> PoseSigma {
        let prior_information =
            Matrix3::from_diagonal(&Vector3::new(prior.x.powi(-2), prior.y.powi(-2), prior.theta.powi(-2)));
        (self.line_information + prior_information)
            .try_inverse()
            .map_or(*prior, |covariance| spread_of(&covariance))
    }
}

/// The standard deviations on the diagonal of a pose's `covariance` (x, y, heading).
fn spread_of(covariance: &Matrix3<f64>) -> PoseSigma {
    let sigma = covariance.diagonal().map(|variance| variance.max(0.0).sqrt());
    PoseSigma { x: sigma.x, y: sigma.y, theta: sigma.z }
}

/// The lines' answer for a burst's guesses.
#[derive(Clone, Debug, PartialEq)]
pub enum LineVerdict {
    /// Too few line points to check anything: every guess stands as it was.
    TooFewPoints(LineEvidence),
    /// One fit per guess, in the guesses' order.
    Checked(Vec<LineFit>),
}

/// What the lines say about one given pose, such as a recording's true pose: how the frames' line
/// points and the lines the camera should have seen agree with it as it is, where they do not, and the
/// fit that starts from it. A team with ground truth sees whether the percepts and the verification
/// accept the right answer in their hall.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseCheck {
    /// Line points used (all frames of the burst).
    pub points: usize,
    /// Share of the points on a line at the pose as given (the camera uncorrected).
    pub inlier_share: f64,
    /// Share of the model-line samples expected at the pose as given that no point lies near; `None`
    /// when too few were expected to tell.
    pub unseen_share: Option<f64>,
    /// The points on no line at the pose: (frame in the burst, pixel).
    pub off_lines: Vec<(usize, Point2<f64>)>,
    /// The expected model-line samples no point lies near: (frame in the burst, pixel).
    pub unseen: Vec<(usize, Point2<f64>)>,
    /// The fit from the pose as a guess: what a hypothesis exactly right gets.
    pub fit: LineFit,
}

impl PoseCheck {
    /// Whether the pose as given meets the verification's shares (the fit from it may still move).
    pub fn passes(&self) -> bool {
        self.inlier_share_passes() && self.unseen_share_passes()
    }

    /// Whether enough of the points lie on a line at the pose as given.
    pub fn inlier_share_passes(&self) -> bool {
        enough_inliers(self.inlier_share)
    }

    /// Whether few enough of the lines expected at the pose as given went unseen.
    pub fn unseen_share_passes(&self) -> bool {
        few_enough_unseen(self.unseen_share)
    }
}

/// Refines hypotheses against one field's lines.
#[derive(Clone, Debug)]
pub struct LineRefiner {
    field: FieldModel,
    map: LineMap,
    /// The global search's coarse map, built the first time a search runs.
    search: OnceLock<SearchMap>,
    /// Whether fits also estimate a correction of the camera's pitch and roll.
    correct_camera: bool,
    line_width: f64,
    /// Samples along every painted line, field frame.
    line_samples: Vec<Point2<f64>>,
    /// The goal posts' centres, field frame.
    posts: Vec<Point2<f64>>,
}

impl LineRefiner {
    /// Builds the distance map of `field` (once; about 0.6 MB). The global search's coarse map follows
    /// when the first search needs it.
    pub fn new(field: &FieldModel) -> Self {
        let map = LineMap::new(field);
        // Where lines meet (a corner, a T) their ends are one place on the field: sampled once.
        let mut line_samples: Vec<Point2<f64>> = Vec::new();
        for sample in map
            .primitives()
            .iter()
            .filter(|primitive| expected_to_be_seen(primitive))
            .flat_map(|primitive| primitive.samples(EXPECTED_SPACING))
        {
            if !line_samples.iter().any(|known| (known - sample).norm() < SAME_SAMPLE) {
                line_samples.push(sample);
            }
        }
        Self {
            field: field.clone(),
            map,
            search: OnceLock::new(),
            correct_camera: true,
            line_width: field.dimensions().line_width,
            line_samples,
            posts: field.goal_posts().collect(),
        }
    }

    /// Whether each fit also estimates a small correction of the camera's pitch and roll (on by
    /// default: a robot's camera pose is never exact, and half a degree moves a fit by tens of
    /// centimetres); off where the camera poses are exact, as in rendered recordings.
    pub fn with_camera_correction(mut self, on: bool) -> Self {
        self.correct_camera = on;
        self
    }

    /// The field's distance map.
    pub fn map(&self) -> &LineMap {
        &self.map
    }

    /// Finds the line points of one frame (see [`percepts::detect`]).
    pub fn percepts(
        &self,
        frame: &Frame,
        intrinsics: &CameraIntrinsics,
        camera: &CameraPose,
    ) -> Result<FramePercepts, PerceptError> {
        detect(frame, intrinsics, camera, self.field.dimensions())
    }

    /// Verifies and refines each guess against the line points of a burst's frames: the fitted pose
    /// and σ (or the guess as it was) with the lines' evidence and a weight factor, in the guesses'
    /// order. With too few line points nothing is checked.
    pub fn check(&self, frames: &[FramePercepts], guesses: &[Guess]) -> LineVerdict {
        let observations = observations(frames);
        if observations.len() < MIN_POINTS {
            return LineVerdict::TooFewPoints(LineEvidence {
                check: LineCheck::Unrefined,
                points: observations.len(),
                inlier_share: 0.0,
                unseen_share: None,
                places: None,
            });
        }
        let mut fits: Vec<LineFit> = Vec::with_capacity(guesses.len());
        for (index, guess) in guesses.iter().enumerate() {
            // A point-symmetric twin of one already refined sees the same lines: mirror its result.
            let twin = guesses[..index].iter().position(|earlier| {
                let image = Symmetry::PointReflection.apply(&earlier.pose);
                image.distance_to(&guess.pose) < 1e-6
                    && angle_distance(image.heading(), guess.pose.heading()) < 1e-6
            });
            fits.push(match twin {
                Some(twin) => fits[twin].point_reflected(),
                None => self.check_one(frames, &observations, &observations, guess),
            });
        }
        LineVerdict::Checked(fits)
    }

    /// Every place on the carpet whose pose the burst's line points fit (refined or partial), one per
    /// point-symmetric pair (the caller adds the twins), best fit first: the coarse grid's best
    /// candidates ([`search`]), each fitted and checked as a guess would be. Empty with too few points.
    pub fn search(&self, frames: &[FramePercepts]) -> Vec<LineFit> {
        self.search_within(frames, None)
    }

    /// The places the lines fit near `guess` (or its point-symmetric twin): [`LineRefiner::search`]
    /// over the poses within twice the guess's σ (at least a grid step, at most [`NEAR_REACH`]), so
    /// that a guess farther off than one fit can converge from still finds its place.
    pub fn search_near(&self, frames: &[FramePercepts], guess: &Guess) -> Vec<LineFit> {
        let (step, turn) = search::grid_spacing();
        let region = Region {
            centre: guess.pose,
            reach: bounded(2.0 * guess.sigma.x.max(guess.sigma.y), step, NEAR_REACH.0),
            turn: bounded(2.0 * guess.sigma.theta, turn, NEAR_REACH.1),
        };
        self.search_within(frames, Some(&region))
    }

    /// What the burst's lines say about `pose` (see [`PoseCheck`]); `None` with too few line points.
    pub fn check_at(&self, frames: &[FramePercepts], pose: &FieldPose) -> Option<PoseCheck> {
        let located = located_observations(frames);
        if located.len() < MIN_POINTS {
            return None;
        }
        let uncorrected = Vector2::zeros();
        let off_lines: Vec<(usize, Point2<f64>)> = located
            .iter()
            .filter(|(_, _, observation)| self.line_under(observation, pose, &uncorrected).is_none())
            .map(|&(frame, pixel, _)| (frame, pixel))
            .collect();
        let (mut expected, mut unseen) = (0usize, Vec::new());
        self.for_each_expected(frames, pose, &uncorrected, |frame, pixel, seen| {
            expected += 1;
            if !seen {
                unseen.push((frame, pixel));
            }
        });
        let observations: Vec<Observation> =
            located.into_iter().map(|(_, _, observation)| observation).collect();
        let sigma = PoseSigma { x: MIN_PRIOR_SIGMA.0, y: MIN_PRIOR_SIGMA.0, theta: MIN_PRIOR_SIGMA.1 };
        let fit = self.check_one(frames, &observations, &observations, &Guess { pose: *pose, sigma });
        Some(PoseCheck {
            points: observations.len(),
            inlier_share: 1.0 - off_lines.len() as f64 / observations.len() as f64,
            unseen_share: unseen_share_of(expected, unseen.len()),
            off_lines,
            unseen,
            fit,
        })
    }

    /// The places the lines fit among the coarse grid's best candidates (all over the field, or in
    /// `region`), best first, one per point-symmetric pair.
    fn search_within(&self, frames: &[FramePercepts], region: Option<&Region>) -> Vec<LineFit> {
        let observations = observations(frames);
        if observations.len() < MIN_POINTS {
            return Vec::new();
        }
        let (step, turn) = search::grid_spacing();
        let sigma = PoseSigma { x: step, y: step, theta: turn };
        let mut places: Vec<LineFit> = Vec::new();
        let search = self.search.get_or_init(|| SearchMap::new(&self.field, &self.map));
        let candidates =
            search.candidates(&observations, SEARCH_CANDIDATES, SEARCH_MAX_MEAN_DISTANCE, region);
        let fit_points = thinned(&observations, SEARCH_FIT_POINTS / candidates.len().max(1));
        for candidate in candidates {
            let guess = Guess { pose: candidate.pose, sigma };
            let fit = self.check_one(frames, &observations, &fit_points, &guess);
            if fit.evidence.check == LineCheck::Contradicted
                || places.iter().any(|place| same_place_or_twin(&place.pose, &fit.pose))
            {
                continue;
            }
            places.push(fit);
        }
        places.sort_by(|a, b| b.factor.total_cmp(&a.factor));
        places
    }

    /// Fits one guess to `fit_points` (the burst's `observations`, or an even share of them weighted
    /// to stand for the rest) and checks the fit against all `observations`.
    fn check_one(
        &self,
        frames: &[FramePercepts],
        observations: &[Observation],
        fit_points: &[Observation],
        guess: &Guess,
    ) -> LineFit {
        let camera = camera_calibration(frames);
        let prior = Prior {
            pose: guess.pose,
            sigma: Vector3::new(
                bounded(guess.sigma.x, MIN_PRIOR_SIGMA.0, MAX_PRIOR_SIGMA.0),
                bounded(guess.sigma.y, MIN_PRIOR_SIGMA.0, MAX_PRIOR_SIGMA.0),
                bounded(guess.sigma.theta, MIN_PRIOR_SIGMA.1, MAX_PRIOR_SIGMA.1),
            ),
            camera_sigma: camera.sigma,
        };
        let seen: Vec<PostBearing> = frames
            .iter()
            .flat_map(|frame| frame.posts.iter())
            .map(|post| PostBearing { bearing: post.bearing(), calibration_rates: post.bearing_rates() })
            .collect();
        let posts = PostBearings { field: &self.posts, seen: &seen };
        let fitted = fit(&self.map, fit_points, &posts, &prior, self.correct_camera);
        let inlier_share = self.inlier_share(observations, &fitted.pose, &fitted.calibration);
        let unseen_share = self.unseen_share(frames, &fitted.pose, &fitted.calibration);
        let quality = inlier_share * (1.0 - unseen_share.unwrap_or(0.0));
        let points = observations.len();
        if !(enough_inliers(inlier_share) && few_enough_unseen(unseen_share)) {
            return LineFit {
                pose: guess.pose,
                sigma: guess.sigma,
                evidence: LineEvidence {
                    check: LineCheck::Contradicted,
                    points,
                    inlier_share,
                    unseen_share,
                    places: None,
                },
                factor: quality.max(0.01).powi(2) * CONTRADICTED_FACTOR,
                camera: None,
                line_information: Matrix3::zeros(),
            };
        }
        let line_sigma = fitted
            .line_information
            .try_inverse()
            .map(|covariance| covariance.diagonal().map(f64::sqrt))
            .filter(|sigma| sigma.iter().all(|s| s.is_finite()));
        let fixed = line_sigma.is_some_and(|sigma| {
            sigma.x <= REFINED_SIGMA.0 && sigma.y <= REFINED_SIGMA.0 && sigma.z <= REFINED_SIGMA.1
        }) && self.off_the_main_direction(observations, &fitted.pose, &fitted.calibration)
            >= MIN_POINTS;
        let check = if fixed { LineCheck::Refined } else { LineCheck::Partial };
        let measured = fitted
            .camera_information
            .filter(|_| fixed)
            .and_then(|information| CameraMeasurement::from_fit(fitted.calibration, &information, &camera));
        LineFit {
            pose: fitted.pose,
            sigma: spread_of(&fitted.covariance),
            evidence: LineEvidence { check, points, inlier_share, unseen_share, places: None },
            factor: quality.powi(2),
            camera: measured,
            line_information: fitted.line_information,
        }
    }

    /// Share of the points within `INLIER_SIGMAS` σ (or 5 cm) of a line under `pose`, with the camera
    /// corrected by `calibration` (pitch, roll).
    fn inlier_share(
        &self,
        observations: &[Observation],
        pose: &FieldPose,
        calibration: &Vector2<f64>,
    ) -> f64 {
        let inliers = observations
            .iter()
            .filter(|observation| self.line_under(observation, pose, calibration).is_some())
            .count();
        inliers as f64 / observations.len() as f64
    }

    /// The model line a point lies on under `pose` (camera corrected by `calibration`): the nearest
    /// one, where the point is within `INLIER_SIGMAS` σ (or 5 cm) of it.
    fn line_under(
        &self,
        observation: &Observation,
        pose: &FieldPose,
        calibration: &Vector2<f64>,
    ) -> Option<&Primitive> {
        let field = pose.robot_to_field(observation.corrected(calibration));
        let primitive = self.map.nearest(field);
        (primitive.residual(field).0 <= (INLIER_SIGMAS * observation.sigma).max(0.05)).then_some(primitive)
    }

    /// How many of the points lie on a line under `pose` (camera corrected by `calibration`) but not
    /// on the lines of the direction most of them lie on: on a line across those, or on the circle.
    /// A pose is fixed along the main direction only by these points; a few of them (a short stub
    /// where a lone line meets another, a speck) can make a wrong place look fixed.
    fn off_the_main_direction(
        &self,
        observations: &[Observation],
        pose: &FieldPose,
        calibration: &Vector2<f64>,
    ) -> usize {
        // Points per direction of the segments they lie on (unit vectors, up to sign).
        let mut directions: Vec<(Vector2<f64>, usize)> = Vec::new();
        let mut on_lines = 0;
        for observation in observations {
            let Some(primitive) = self.line_under(observation, pose, calibration) else { continue };
            on_lines += 1;
            let Primitive::Segment { start, end } = primitive else { continue };
            let direction = (end - start).normalize();
            match directions.iter_mut().find(|(known, _)| known.perp(&direction).abs() < PARALLEL_SINE) {
                Some((_, count)) => *count += 1,
                None => directions.push((direction, 1)),
            }
        }
        on_lines - directions.iter().map(|&(_, count)| count).max().unwrap_or(0)
    }

    /// Share of the model-line samples some frame should have seen under `pose` (its camera corrected
    /// by `calibration`) that no line point of that frame lies near (in the image, within a scan
    /// spacing and a bit).
    fn unseen_share(
        &self,
        frames: &[FramePercepts],
        pose: &FieldPose,
        calibration: &Vector2<f64>,
    ) -> Option<f64> {
        let (mut expected, mut unseen) = (0usize, 0usize);
        self.for_each_expected(frames, pose, calibration, |_, _, seen| {
            expected += 1;
            unseen += usize::from(!seen);
        });
        unseen_share_of(expected, unseen)
    }

    /// Calls `visit(frame, pixel, seen)` for every model-line sample some frame of the burst should
    /// have seen under `pose` (its camera corrected by `calibration`): where it lies in that frame's
    /// image, and whether a line point of that frame lies near it (within a scan spacing and a bit).
    fn for_each_expected(
        &self,
        frames: &[FramePercepts],
        pose: &FieldPose,
        calibration: &Vector2<f64>,
        mut visit: impl FnMut(usize, Point2<f64>, bool),
    ) {
        for (index, frame) in frames.iter().enumerate() {
            let Some(camera) = frame.corrected_camera(calibration.x, calibration.y) else {
                continue;
            };
            let tolerance = 1.5 * frame.scan_spacing() as f64 + 1.0;
            for sample in &self.line_samples {
                let ground = pose.field_to_robot(*sample);
                let distance = ground.coords.norm();
                if !(EXPECTED_RANGE.0..=EXPECTED_RANGE.1).contains(&distance) {
                    continue;
                }
                let Some(pixel) = camera.project(&Point3::new(ground.x, ground.y, 0.0)) else {
                    continue;
                };
                if !frame.searched(&pixel, self.width_in_pixels(&camera, &ground, &pixel)) {
                    continue;
                }
                let seen = frame.points.iter().any(|point| (point.pixel - pixel).norm() <= tolerance);
                visit(index, pixel, seen);
            }
        }
    }

    /// How wide, in pixels, a painted line at `ground` (robot frame) looks at `pixel` under `camera`:
    /// the larger image step of a line width along either ground axis (at most √2 too wide).
    fn width_in_pixels(&self, camera: &Camera, ground: &Point2<f64>, pixel: &Point2<f64>) -> f64 {
        [Vector2::new(self.line_width, 0.0), Vector2::new(0.0, self.line_width)]
            .iter()
            .filter_map(|step| camera.project(&Point3::new(ground.x + step.x, ground.y + step.y, 0.0)))
            .map(|stepped| (stepped - pixel).norm())
            .fold(0.0, f64::max)
    }
}

/// Whether a fit's share of points on a line is enough for it to stand.
fn enough_inliers(inlier_share: f64) -> bool {
    inlier_share >= MIN_INLIER_SHARE
}

/// Whether a fit's share of expected lines unseen (`None`: too few expected to tell) lets it stand.
fn few_enough_unseen(unseen_share: Option<f64>) -> bool {
    unseen_share.is_none_or(|unseen| unseen <= MAX_UNSEEN_SHARE)
}

/// The share of `expected` model-line samples of which `unseen` were not seen; `None` when too few
/// were expected to tell.
fn unseen_share_of(expected: usize, unseen: usize) -> Option<f64> {
    (expected >= MIN_EXPECTED).then(|| unseen as f64 / expected as f64)
}

/// Whether a line must be seen where the camera looks: every line and circle, not a mark's arms.
fn expected_to_be_seen(primitive: &Primitive) -> bool {
    match primitive {
        Primitive::Segment { start, end } => (end - start).norm() >= MIN_EXPECTED_SEGMENT,
        Primitive::Circle { .. } => true,
    }
}

/// Whether two fits are one place, or point-symmetric twins of one: closer than [`SAME_PLACE`], or
/// within [`PLACE_SIGMAS`] of their combined σ in x, y and heading (a fit to one line is uncertain
/// along it, so fits a few tens of centimetres apart along that line are one place).
fn one_place(a: &LineFit, b: &LineFit) -> bool {
    let within =
        |difference: f64, sigma_a: f64, sigma_b: f64| difference <= PLACE_SIGMAS * sigma_a.hypot(sigma_b);
    let within_sigma = |pose: &FieldPose| {
        within((pose.x() - b.pose.x()).abs(), a.sigma.x, b.sigma.x)
            && within((pose.y() - b.pose.y()).abs(), a.sigma.y, b.sigma.y)
            && within(angle_distance(pose.heading(), b.pose.heading()), a.sigma.theta, b.sigma.theta)
    };
    same_place_or_twin(&a.pose, &b.pose)
        || within_sigma(&a.pose)
        || within_sigma(&Symmetry::PointReflection.apply(&a.pose))
}

/// How many distinct places `fits` show: fits that are [`one_place`] with an earlier one count once.
pub fn distinct_places(fits: &[LineFit]) -> usize {
    let mut representatives: Vec<&LineFit> = Vec::new();
    for fit in fits {
        if !representatives.iter().any(|known| one_place(known, fit)) {
            representatives.push(fit);
        }
    }
    representatives.len()
}

/// Whether two fitted poses are one place on the field, or point-symmetric twins of one, closer than
/// [`SAME_PLACE`] (the same fit found twice).
pub fn same_place_or_twin(a: &FieldPose, b: &FieldPose) -> bool {
    let same = |a: &FieldPose, b: &FieldPose| {
        a.distance_to(b) <= SAME_PLACE.0 && angle_distance(a.heading(), b.heading()) <= SAME_PLACE.1
    };
    same(a, b) || same(&Symmetry::PointReflection.apply(a), b)
}

/// The prior of a burst's camera correction: none on top of the frames' poses, within the loosest of
/// their spreads.
fn camera_calibration(frames: &[FramePercepts]) -> CameraCalibration {
    let sigma = frames.iter().map(FramePercepts::camera_sigma).reduce(|a, b| a.sup(&b));
    CameraCalibration {
        correction: Vector2::zeros(),
        sigma: sigma.unwrap_or(CameraCalibration::default().sigma),
    }
}

/// At most `at_most` of `observations` (at least one), evenly spread over them, each weighted to stand
/// for the ones left out; all of them where there are no more.
fn thinned(observations: &[Observation], at_most: usize) -> Cow<'_, [Observation]> {
    let at_most = at_most.max(1);
    if observations.len() <= at_most {
        return Cow::Borrowed(observations);
    }
    let stride = observations.len() as f64 / at_most as f64;
    let kept: Vec<Observation> = (0..at_most).map(|k| observations[(k as f64 * stride) as usize]).collect();
    let scale = observations.len() as f64 / at_most as f64;
    kept.into_iter()
        .map(|observation| Observation { weight: observation.weight * scale, ..observation })
        .collect()
}

/// The line points of all frames as observations with their σ (see [`located_observations`]).
fn observations(frames: &[FramePercepts]) -> Vec<Observation> {
    located_observations(frames).into_iter().map(|(_, _, observation)| observation).collect()
}

/// The line points of all frames within reach, each with its frame's index in the burst, its pixel and
/// its observation: at most [`MAX_BURST_POINTS`], each frame's share evenly spread over its points,
/// the frames' samples interleaved (a standing robot's frames see the same lines: the burst keeps
/// points from all over the view rather than the same ones from every frame), and each kept point
/// weighted to stand for the points left out.
fn located_observations(frames: &[FramePercepts]) -> Vec<(usize, Point2<f64>, Observation)> {
    let per_frame: Vec<Vec<(usize, Point2<f64>, Observation)>> = frames
        .iter()
        .enumerate()
        .map(|(index, frame)| {
            let height = frame.camera_height();
            let within = frame.points.iter().filter(|point| point.ground.coords.norm() <= MAX_POINT_DISTANCE);
            within
                .map(|point| {
                    let distance = point.ground.coords.norm();
                    let observation = Observation {
                        ground: point.ground,
                        sigma: POINT_SIGMA + distance * distance / height * PITCH_SIGMA,
                        weight: 1.0,
                        calibration_rates: point.calibration_rates,
                    };
                    (index, point.pixel, observation)
                })
                .collect()
        })
        .collect();
    let total: usize = per_frame.iter().map(Vec::len).sum();
    if total <= MAX_BURST_POINTS {
        return per_frame.into_iter().flatten().collect();
    }
    // Frame f keeps its points at (k + f / frames) strides, so identical frames keep different points.
    let stride = total as f64 / MAX_BURST_POINTS as f64;
    let phases = per_frame.len() as f64;
    let kept: Vec<(usize, Point2<f64>, Observation)> = per_frame
        .iter()
        .enumerate()
        .flat_map(|(index, points)| {
            (0..)
                .map(move |k| ((k as f64 + index as f64 / phases) * stride) as usize)
                .take_while(|&at| at < points.len())
                .map(|at| points[at])
        })
        .take(MAX_BURST_POINTS)
        .collect();
    let weight = total as f64 / kept.len() as f64;
    kept.into_iter()
        .map(|(index, pixel, observation)| (index, pixel, Observation { weight, ..observation }))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{Randomisation, render};

    #[test]
    fn a_burst_of_one_view_keeps_one_frame_s_worth_of_points_from_all_over_it_standing_for_all() {
        // The benchmark's frame: a penalty-area corner and the goal line.
        let field = FieldModel::default();
        let sampled = Randomisation::default().sample(&field, 4000, 0, 1);
        let intrinsics = CameraIntrinsics::nao_top();
        let camera = Camera::new(intrinsics, &sampled.pose, &sampled.camera);
        let frame = Frame::Rgb(render(&sampled.scene, &camera, &sampled.settings));
        let percepts = detect(&frame, &intrinsics, &sampled.camera, field.dimensions()).unwrap();
        let one = observations(std::slice::from_ref(&percepts));
        assert!(5 * one.len() > MAX_BURST_POINTS, "{}", one.len());
        let burst = observations(&vec![percepts; 5]);
        assert!(burst.len() <= MAX_BURST_POINTS, "{}", burst.len());
        assert!(burst.len() >= MAX_BURST_POINTS.min(5 * one.len()) - 5, "{}", burst.len());
        let distinct =
            one.iter().filter(|point| burst.iter().any(|kept| kept.ground == point.ground)).count();
        assert!(distinct as f64 >= 0.9 * one.len().min(burst.len()) as f64, "{distinct} of {}", one.len());
        // The kept points stand for all five frames' points.
        let weight: f64 = burst.iter().map(|observation| observation.weight).sum();
        assert!((weight - 5.0 * one.len() as f64).abs() < 1e-6, "{weight}");
    }

    fn fit(x: f64, y: f64, theta: f64, sigma: (f64, f64, f64)) -> LineFit {
        LineFit {
            pose: FieldPose::new(x, y, theta).unwrap(),
            sigma: PoseSigma { x: sigma.0, y: sigma.1, theta: sigma.2 },
            evidence: LineEvidence {
                check: LineCheck::Partial,
                points: 40,
                inlier_share: 1.0,
                unseen_share: None,
                places: None,
            },
            factor: 1.0,
            camera: None,
            line_information: Matrix3::zeros(),
        }
    }

    #[test]
    fn fits_along_one_line_within_their_sigma_are_one_place_and_sharp_fits_apart_are_two() {
        // Two fits to the halfway line, 26 cm apart along it, each uncertain along it.
        let along = (0.02, 0.3, 0.01);
        assert!(one_place(&fit(0.0, 1.0, 0.5, along), &fit(0.01, 1.26, 0.5, along)));
        // Their point-symmetric twins are the same place too.
        assert!(one_place(&fit(0.0, 1.0, 0.5, along), &fit(-0.01, -1.26, 0.5 - std::f64::consts::PI, along)));
        // Across the line the fit is sharp: 26 cm across it are two places.
        assert!(!one_place(&fit(0.0, 1.0, 0.5, along), &fit(0.26, 1.0, 0.5, along)));
        // Two refined fits 26 cm apart are two places; 5 cm apart, one.
        let sharp = (0.02, 0.02, 0.01);
        assert!(!one_place(&fit(0.0, 1.0, 0.5, sharp), &fit(0.0, 1.26, 0.5, sharp)));
        assert!(one_place(&fit(0.0, 1.0, 0.5, sharp), &fit(0.0, 1.05, 0.5, sharp)));
    }

    #[test]
    fn fits_along_one_line_count_as_one_place() {
        let fits = [
            fit(0.0, 1.0, 0.5, (0.02, 0.3, 0.01)),
            fit(0.0, 1.2, 0.5, (0.02, 0.02, 0.01)),
            fit(0.0, -1.3, 0.5 - std::f64::consts::PI, (0.02, 0.4, 0.01)),
            fit(2.0, 1.0, 0.5, (0.02, 0.02, 0.01)),
        ];
        assert_eq!(distinct_places(&fits), 2);
        assert_eq!(distinct_places(&fits[1..2]), 1);
        assert_eq!(distinct_places(&[]), 0);
    }

    /// Observations at field points, for a robot at the field's origin facing +x (robot frame = field
    /// frame).
    fn observed(points: impl IntoIterator<Item = (f64, f64)>) -> Vec<Observation> {
        points
            .into_iter()
            .map(|(x, y)| Observation {
                ground: Point2::new(x, y),
                sigma: POINT_SIGMA,
                weight: 1.0,
                calibration_rates: [Vector2::zeros(); 2],
            })
            .collect()
    }

    #[test]
    fn a_thinned_share_spans_the_points_and_stands_for_all_of_them() {
        let points = observed((0..400).map(|i| (f64::from(i) * 0.01, 0.0)));
        assert!(matches!(thinned(&points, 400), Cow::Borrowed(_)));
        let kept = thinned(&points, 150);
        assert_eq!(kept.len(), 150);
        assert_eq!(kept[0].ground, points[0].ground);
        assert!(kept.last().unwrap().ground.x > 3.9, "{}", kept.last().unwrap().ground.x);
        assert!(kept.windows(2).all(|pair| pair[1].ground.x > pair[0].ground.x));
        let weight: f64 = kept.iter().map(|observation| observation.weight).sum();
        assert!((weight - 400.0).abs() < 1e-9, "{weight}");
        assert_eq!(thinned(&points, 0).len(), 1);
    }

    #[test]
    fn points_off_the_main_line_direction_are_counted() {
        let refiner = LineRefiner::new(&FieldModel::default());
        let origin = FieldPose::new(0.0, 0.0, 0.0).unwrap();
        let none = Vector2::zeros();
        // Forty points along the sideline y = 3 (and so along the x axis), and a short stub of five on
        // the halfway line across it, one point off any line.
        let sideline = (0..40).map(|i| (-2.0 + 0.1 * i as f64, 3.0));
        let stub = (0..5).map(|i| (0.0, 2.5 + 0.1 * i as f64));
        let observations = observed(sideline.clone().chain(stub).chain([(1.3, 1.3)]));
        assert_eq!(refiner.off_the_main_direction(&observations, &origin, &none), 5);
        // The other sideline is parallel: still one direction. The centre circle is not.
        let far_side = (0..20).map(|i| (-1.0 + 0.1 * i as f64, -3.0));
        let circle = (0..15).map(|i| (0.75 * (0.2 * i as f64).cos(), 0.75 * (0.2 * i as f64).sin()));
        let observations = observed(sideline.chain(far_side).chain(circle));
        assert_eq!(refiner.off_the_main_direction(&observations, &origin, &none), 15);
    }

    #[test]
    fn where_lines_meet_the_field_is_sampled_once() {
        let refiner = LineRefiner::new(&FieldModel::default());
        let samples = &refiner.line_samples;
        for (index, sample) in samples.iter().enumerate() {
            assert!(
                samples[index + 1..].iter().all(|other| (other - sample).norm() >= SAME_SAMPLE),
                "{sample:?} sampled twice"
            );
        }
        // A corner of the field and the T where the halfway line meets a sideline are among them.
        let dimensions = FieldModel::default().dimensions().clone();
        let (half_length, half_width) = (dimensions.field_length / 2.0, dimensions.field_width / 2.0);
        for point in [Point2::new(half_length, half_width), Point2::new(0.0, -half_width)] {
            assert!(samples.iter().any(|sample| (sample - point).norm() < 1e-9), "{point:?}");
        }
    }

    #[test]
    fn the_lines_fix_what_they_see_and_the_prior_keeps_the_rest_for_either_twin() {
        // Points along a line parallel to x: y and the heading are fixed, x is left open.
        let mut along_x = fit(1.0, 3.0, 0.3, (0.6, 0.01, 0.01));
        along_x.line_information = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1e4, 2e3, 0.0, 2e3, 1e4);
        let prior = PoseSigma { x: 1.5, y: 1.5, theta: 0.2 };
        let spread = along_x.spread_with(&prior);
        assert!((spread.x - 1.5).abs() < 1e-9, "{spread:?}");
        assert!(spread.y < 0.011 && spread.theta < 0.011, "{spread:?}");
        let twin = along_x.point_reflected();
        assert_eq!(twin.pose, Symmetry::PointReflection.apply(&along_x.pose));
        assert_eq!(twin.line_information[(1, 2)], -2e3);
        let twin_spread = twin.spread_with(&prior);
        for (a, b) in
            [(spread.x, twin_spread.x), (spread.y, twin_spread.y), (spread.theta, twin_spread.theta)]
        {
            assert!((a - b).abs() < 1e-12);
        }
        // Where the lines say nothing (contradicted) the prior is all there is.
        assert_eq!(fit(0.0, 0.0, 0.0, (0.1, 0.1, 0.1)).spread_with(&prior), prior);
    }
}
