//! Fitting a robot pose to line points: a coarse search over the starting pose's uncertainty, then
//! Levenberg–Marquardt on point-to-line distances with a Cauchy loss and the starting pose as a
//! prior (Gaussian near it, Cauchy far from it). The fit also estimates a small correction of the
//! camera's pitch and roll (a robot's calibration error, which bends every ground point the same way),
//! held to zero by a prior. Goal posts seen in the image add their bearings (the foot's column is
//! sharp where its row is not, and the camera correction turns them as it moves the points), each to
//! the field post nearest in bearing: they place the robot along the lines it sees. The covariance
//! comes from the final normal equations.

use std::ops::AddAssign;

use nalgebra::{Matrix2, Matrix3, Point2, SMatrix, SVector, Vector2, Vector3};

use super::calibration::CameraCalibration;
use super::line_map::LineMap;
use crate::geometry::FieldPose;
use crate::geometry::angle::normalize_angle;

/// Scale of the Cauchy loss, in standard deviations of a point.
const CAUCHY_SCALE: f64 = 2.0;
/// Scale of the Cauchy loss on the pose's distance from the prior, in the prior's standard
/// deviations: a guess half a σ or more off (a network is lost now and then) pulls the fit much less
/// than a Gaussian would, so what little the lines say along a line decides there; near the guess the
/// loss is the Gaussian's, and where the lines say nothing at all the fit stays at the guess. (On six
/// tuning sets 2 σ, 1 σ and a Gaussian found fewer poses; a quarter σ found a few more, but let one
/// stray goal-post bearing drag a fit metres along its line; BENCHMARKS.md, "A prior that yields" and
/// "A prior that yields sooner".)
const PRIOR_SCALE: f64 = 0.5;
/// Coarse search: offsets per axis, in steps, each side of the start.
const SEARCH_STEPS: i32 = 2;
/// Coarse search: step as a share of the prior's standard deviation.
const SEARCH_STEP_SIGMAS: f64 = 0.75;
/// Coarse-search candidates refined by Levenberg–Marquardt.
const STARTS: usize = 3;
/// Points the coarse search scores at most (evenly spread over them): enough to rank its 125 poses,
/// while Levenberg–Marquardt uses every point.
const COARSE_POINTS: usize = 100;
/// Levenberg–Marquardt iterations at most.
const MAX_ITERATIONS: usize = 20;
/// Iterations at most of the second pass with the camera correction free: it starts at the
/// camera-trusting fit, a few steps away.
const CALIBRATION_ITERATIONS: usize = 6;
/// Levenberg–Marquardt has converged when a step moves the position by at most this (metres) and the
/// heading and the camera correction by at most this (radians).
const NEGLIGIBLE_STEP: (f64, f64) = (1e-3, 1e-4);
/// Largest pitch or roll correction the fit may make, radians.
const MAX_CALIBRATION: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// The camera correction is estimated only where the camera-trusting fit already puts at least this
/// share of the points within [`CORRECTABLE_DISTANCE`] of a line: a wrong place stays wrong whatever
/// the camera, and the global search fits many.
const CORRECTABLE_SHARE: f64 = 0.5;
/// See [`CORRECTABLE_SHARE`], metres.
const CORRECTABLE_DISTANCE: f64 = 0.15;

/// Standard deviation of a goal post's bearing, radians: a pixel or two of its foot's column, the
/// camera's roll and the post's round face.
const POST_BEARING_SIGMA: f64 = 0.5 * std::f64::consts::PI / 180.0;
/// A field post nearer the robot than this (metres) is not matched to a bearing: its bearing swings
/// with every centimetre of position.
const MIN_POST_DISTANCE: f64 = 0.3;

/// (x, y, heading, pitch correction, roll correction).
type State = SVector<f64, 5>;
type Matrix5 = SMatrix<f64, 5, 5>;

/// One line point as the optimiser sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Robot-frame ground position, metres.
    pub ground: Point2<f64>,
    /// Standard deviation of its position across the line, metres.
    pub sigma: f64,
    /// How many of the burst's line points it stands for (1, or more where they were thinned): its
    /// loss and information count this many times.
    pub weight: f64,
    /// How `ground` moves per radian of camera pitch and of roll (zero: a correction does not move it).
    pub calibration_rates: [Vector2<f64>; 2],
}

impl Observation {
    /// The ground position with a camera correction of (pitch, roll) radians.
    pub fn corrected(&self, calibration: &Vector2<f64>) -> Point2<f64> {
        self.ground + self.calibration_rates[0] * calibration.x + self.calibration_rates[1] * calibration.y
    }
}

/// A goal post's bearing as the optimiser sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PostBearing {
    /// Robot-frame bearing of its foot, radians (counter-clockwise from straight ahead).
    pub bearing: f64,
    /// How the bearing moves per radian of camera pitch and of roll (a calibration error).
    pub calibration_rates: Vector2<f64>,
}

impl PostBearing {
    /// The bearing with a camera correction of (pitch, roll) radians.
    pub fn corrected(&self, calibration: &Vector2<f64>) -> f64 {
        self.bearing + self.calibration_rates.dot(calibration)
    }
}

/// Goal posts as the optimiser sees them: where they stand and where they were seen.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PostBearings<'a> {
    /// The field's posts, field frame, metres.
    pub field: &'a [Point2<f64>],
    /// The posts seen.
    pub seen: &'a [PostBearing],
}

impl PostBearings<'_> {
    /// Each seen post's residual from the field post nearest in bearing under `state`'s pose and
    /// camera correction, radians, and the residual's derivatives by the state.
    fn residuals(&self, state: &State) -> impl Iterator<Item = (f64, State)> + '_ {
        let (x, y, heading) = (state[0], state[1], state[2]);
        let calibration = state.fixed_rows::<2>(3).into_owned();
        self.seen.iter().filter_map(move |seen| {
            let bearing = seen.corrected(&calibration);
            let [pitch_rate, roll_rate] = [-seen.calibration_rates.x, -seen.calibration_rates.y];
            self.field
                .iter()
                .filter_map(|post| {
                    let (dx, dy) = (post.x - x, post.y - y);
                    let squared = dx * dx + dy * dy;
                    (squared >= MIN_POST_DISTANCE * MIN_POST_DISTANCE).then(|| {
                        let residual = normalize_angle(dy.atan2(dx) - heading - bearing);
                        (residual, State::new(dy / squared, -dx / squared, -1.0, pitch_rate, roll_rate))
                    })
                })
                .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
        })
    }

    /// The posts' robust cost at `state`.
    fn cost(&self, state: &State) -> f64 {
        self.residuals(state).map(|(residual, _)| cauchy(residual / POST_BEARING_SIGMA)).sum()
    }
}

/// A pose with its standard deviations: the prior the fit starts from and is held to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prior {
    /// The pose.
    pub pose: FieldPose,
    /// Standard deviations of (x, y, heading), metres and radians.
    pub sigma: Vector3<f64>,
    /// Standard deviations of the camera's (pitch, roll) correction, radians.
    pub camera_sigma: Vector2<f64>,
}

/// The fitted pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    /// The pose.
    pub pose: FieldPose,
    /// The camera's pitch and roll correction that goes with it, radians.
    pub calibration: Vector2<f64>,
    /// Robust cost at the pose (lines and prior).
    pub cost: f64,
    /// Covariance of (x, y, heading) from lines and prior.
    pub covariance: Matrix3<f64>,
    /// Information about (x, y, heading) from the lines alone, with the camera correction left free
    /// within the prior of a camera nothing was learnt about (a degree: a learnt calibration sharpens
    /// the fit, not what the fit claims): degenerate where lines do not constrain.
    pub line_information: Matrix3<f64>,
    /// Information about the camera correction from the lines alone, with the pose left free; `None`
    /// where the camera was trusted or the lines leave the pose free.
    pub camera_information: Option<Matrix2<f64>>,
}

/// The map from robot-frame ground points to field points under `pose` (its sine and cosine taken
/// once).
fn to_field(pose: Vector3<f64>) -> impl Fn(&Point2<f64>) -> Point2<f64> {
    let (sin, cos) = pose.z.sin_cos();
    let (x, y) = (pose.x, pose.y);
    move |ground| Point2::new(x + cos * ground.x - sin * ground.y, y + sin * ground.x + cos * ground.y)
}

/// A point's loss at `normalised` of its σ from the nearest line.
fn cauchy(normalised: f64) -> f64 {
    cauchy_loss((normalised / CAUCHY_SCALE).powi(2), CAUCHY_SCALE)
}

/// The Cauchy loss of `scale` at a residual whose square, in units of `scale`, is `ratio_squared`.
fn cauchy_loss(ratio_squared: f64, scale: f64) -> f64 {
    0.5 * scale * scale * ratio_squared.ln_1p()
}

/// The IRLS weight of [`cauchy_loss`] at `ratio_squared`.
fn cauchy_weight(ratio_squared: f64) -> f64 {
    1.0 / (1.0 + ratio_squared)
}

/// The prior's loss at a pose whose residual from it (in σ) has squared norm `squared`.
fn prior_loss(squared: f64) -> f64 {
    cauchy_loss(squared / (PRIOR_SCALE * PRIOR_SCALE), PRIOR_SCALE)
}

/// The IRLS weight of [`prior_loss`] at `squared`.
fn prior_weight(squared: f64) -> f64 {
    cauchy_weight(squared / (PRIOR_SCALE * PRIOR_SCALE))
}

fn prior_residual(pose: &Vector3<f64>, prior: &Prior) -> Vector3<f64> {
    Vector3::new(
        (pose.x - prior.pose.x()) / prior.sigma.x,
        (pose.y - prior.pose.y()) / prior.sigma.y,
        normalize_angle(pose.z - prior.pose.heading()) / prior.sigma.z,
    )
}

/// The prior's standard deviations of the whole state.
fn state_sigma(prior: &Prior) -> State {
    State::new(prior.sigma.x, prior.sigma.y, prior.sigma.z, prior.camera_sigma.x, prior.camera_sigma.y)
}

/// The cost using the map's cell distances: cheap, for the coarse search (no camera correction). Only
/// every `stride`-th point is scored, its loss counted `stride` times, so that the lines keep their
/// weight against the prior and the posts. `None` as soon as the cost is sure to exceed `limit`: every
/// point's loss is at least zero, so the cost only grows as points are added.
fn coarse_cost(
    map: &LineMap,
    observations: &[Observation],
    posts: &PostBearings,
    stride: usize,
    pose: &Vector3<f64>,
    prior: &Prior,
    limit: Option<f64>,
) -> Option<f64> {
    let place = to_field(*pose);
    let state = State::new(pose.x, pose.y, pose.z, 0.0, 0.0);
    let prior_cost = prior_loss(prior_residual(pose, prior).norm_squared()) + posts.cost(&state);
    let scale = stride as f64;
    let mut lines = 0.0;
    for observation in observations.iter().step_by(stride) {
        lines += observation.weight * cauchy(map.distance(place(&observation.ground)) / observation.sigma);
        if limit.is_some_and(|limit| (lines * scale + prior_cost).total_cmp(&limit).is_gt()) {
            return None;
        }
    }
    Some(lines * scale + prior_cost)
}

/// The coarse search's offsets in steps, [`SEARCH_STEPS`] each side along every axis, in grid order
/// (x, then y, then heading).
fn coarse_offsets() -> impl Iterator<Item = Vector3<f64>> {
    let steps = || (-SEARCH_STEPS..=SEARCH_STEPS).map(f64::from);
    steps().flat_map(move |i| steps().flat_map(move |j| steps().map(move |k| Vector3::new(i, j, k))))
}

/// The coarse search's [`STARTS`] best poses, best first: of the poses [`SEARCH_STEPS`] steps of
/// `step` each side of `centre` along every axis, those of least [`coarse_cost`] (ties in the order of
/// x, then y, then heading offsets). Poses are scored from the centre outwards, so that the best few
/// are known early and most others are left as soon as they are sure to cost more.
fn coarse_starts(
    map: &LineMap,
    observations: &[Observation],
    posts: &PostBearings,
    prior: &Prior,
    centre: &Vector3<f64>,
    step: &Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let stride = observations.len().div_ceil(COARSE_POINTS).max(1);
    let mut grid: Vec<(usize, Vector3<f64>)> = coarse_offsets().enumerate().collect();
    grid.sort_by_key(|(_, offset)| offset.abs().sum() as i32);
    // The best so far as (cost, grid order, pose), best first.
    let mut best: Vec<(f64, usize, Vector3<f64>)> = Vec::with_capacity(STARTS + 1);
    for (order, offset) in grid {
        let pose = centre + offset.component_mul(step);
        let limit = (best.len() == STARTS).then(|| best[STARTS - 1].0);
        let Some(cost) = coarse_cost(map, observations, posts, stride, &pose, prior, limit) else { continue };
        let rank = best.partition_point(|&(known, known_order, _)| {
            known.total_cmp(&cost).then(known_order.cmp(&order)).is_lt()
        });
        best.insert(rank, (cost, order, pose));
        best.truncate(STARTS);
    }
    best.into_iter().map(|(_, _, pose)| pose).collect()
}

/// Cost, Gauss–Newton normal equations (H, g) and the lines' share of H at a state (the posts' share
/// sharpens the pose but is not counted as the lines' evidence).
struct Linearisation {
    cost: f64,
    hessian: Matrix5,
    gradient: State,
    line_information: Matrix5,
}

/// Linearises at `state`; without `calibrate` the camera correction stays where it is (zero).
fn linearise(
    map: &LineMap,
    observations: &[Observation],
    posts: &PostBearings,
    state: &State,
    prior: &Prior,
    calibrate: bool,
) -> Linearisation {
    let pose = state.fixed_rows::<3>(0).into_owned();
    let calibration = state.fixed_rows::<2>(3).into_owned();
    let mut line_information = Matrix5::zeros();
    let mut gradient = State::zeros();
    // The pose's block of the two, summed apart while the camera is left as it is.
    let mut pose_information = Matrix3::zeros();
    let mut pose_gradient = Vector3::zeros();
    let mut cost = 0.0;
    let (sin, cos) = pose.z.sin_cos();
    let rotate = |v: &Vector2<f64>| Vector2::new(cos * v.x - sin * v.y, sin * v.x + cos * v.y);
    let place = to_field(pose);
    for observation in observations {
        let ground = observation.corrected(&calibration);
        let field = place(&ground);
        let (distance, normal) = map.residual(field);
        let error = distance / observation.sigma;
        let ratio_squared = (error / CAUCHY_SCALE).powi(2);
        cost += observation.weight * cauchy_loss(ratio_squared, CAUCHY_SCALE);
        let weight = observation.weight * cauchy_weight(ratio_squared);
        let rotated = rotate(&ground.coords);
        let turn = normal.x * -rotated.y + normal.y * rotated.x;
        if calibrate {
            let [pitch_rate, roll_rate] = observation.calibration_rates.each_ref().map(rotate);
            let jacobian =
                State::new(normal.x, normal.y, turn, normal.dot(&pitch_rate), normal.dot(&roll_rate))
                    / observation.sigma;
            line_information += weight * jacobian * jacobian.transpose();
            gradient += weight * error * jacobian;
        } else {
            // The camera's rows stay zero: only the pose's block is summed.
            let jacobian = Vector3::new(normal.x, normal.y, turn) / observation.sigma;
            pose_information += weight * jacobian * jacobian.transpose();
            pose_gradient += weight * error * jacobian;
        }
    }
    line_information.fixed_view_mut::<3, 3>(0, 0).add_assign(&pose_information);
    let mut hessian = line_information;
    for (residual, derivatives) in posts.residuals(state) {
        let error = residual / POST_BEARING_SIGMA;
        let ratio_squared = (error / CAUCHY_SCALE).powi(2);
        cost += cauchy_loss(ratio_squared, CAUCHY_SCALE);
        let mut jacobian = derivatives / POST_BEARING_SIGMA;
        if !calibrate {
            jacobian.fixed_rows_mut::<2>(3).fill(0.0);
        }
        hessian += cauchy_weight(ratio_squared) * jacobian * jacobian.transpose();
        gradient += cauchy_weight(ratio_squared) * error * jacobian;
    }
    gradient.fixed_rows_mut::<3>(0).add_assign(&pose_gradient);
    let sigma = state_sigma(prior);
    let pose_residual = prior_residual(&pose, prior);
    let pose_squared = pose_residual.norm_squared();
    let pose_weight = prior_weight(pose_squared);
    let camera_residual = calibration.component_div(&prior.camera_sigma);
    cost += prior_loss(pose_squared) + 0.5 * camera_residual.norm_squared();
    // The pose's prior weighted as its loss says (IRLS); the camera's stays Gaussian.
    let weights = State::new(pose_weight, pose_weight, pose_weight, 1.0, 1.0);
    let residual =
        State::new(pose_residual.x, pose_residual.y, pose_residual.z, camera_residual.x, camera_residual.y);
    let prior_information = Matrix5::from_diagonal(&sigma.zip_map(&weights, |s, weight| weight / (s * s)));
    gradient += residual.component_mul(&weights).component_div(&sigma);
    Linearisation { cost, hessian: hessian + prior_information, gradient, line_information }
}

/// Levenberg–Marquardt from `start`.
fn levenberg_marquardt(
    map: &LineMap,
    observations: &[Observation],
    posts: &PostBearings,
    start: State,
    prior: &Prior,
    calibrate: bool,
    iterations: usize,
) -> (State, Linearisation) {
    let mut state = start;
    let mut linearised = linearise(map, observations, posts, &state, prior, calibrate);
    let mut damping = 1e-3;
    for _ in 0..iterations {
        let mut improved = false;
        while damping < 1e8 {
            let damped =
                linearised.hessian + Matrix5::from_diagonal(&linearised.hessian.diagonal()) * damping;
            let Some(step) = damped.cholesky().map(|cholesky| -cholesky.solve(&linearised.gradient)) else {
                damping *= 10.0;
                continue;
            };
            // Converged, or damped so far that no step would change anything that matters: stop
            // before paying for a linearisation that cannot help.
            if negligible(&step) {
                break;
            }
            let mut candidate = state + step;
            candidate[2] = normalize_angle(candidate[2]);
            for correction in candidate.fixed_rows_mut::<2>(3).iter_mut() {
                *correction = correction.clamp(-MAX_CALIBRATION, MAX_CALIBRATION);
            }
            // Linearised at once: an accepted step needs it next, and a rejected one costs little more.
            let tried = linearise(map, observations, posts, &candidate, prior, calibrate);
            if tried.cost < linearised.cost {
                state = candidate;
                linearised = tried;
                damping = (damping / 3.0).max(1e-9);
                improved = true;
                break;
            }
            damping *= 4.0;
        }
        if !improved {
            break;
        }
    }
    (state, linearised)
}

/// Whether a step moves the pose by at most [`NEGLIGIBLE_STEP`]: a point's σ is a centimetre or more,
/// and a fit crawling along a shallow valley by less gains nothing that matters (with a 10 µm limit,
/// 16 of the 56 runs of a costly global search crawled for 15–30 iterations).
fn negligible(step: &State) -> bool {
    step.fixed_rows::<2>(0).norm() <= NEGLIGIBLE_STEP.0 && step.fixed_rows::<3>(2).amax() <= NEGLIGIBLE_STEP.1
}

/// Fits the pose that best explains `observations` and the `posts`' bearings, starting from and held
/// to `prior`: a coarse search over ±1.5 σ of the prior on the distance map (with at most
/// [`COARSE_POINTS`] of the points), then Levenberg–Marquardt from the best few with the camera as
/// given; with `calibrate`, from the best once more with the camera's pitch and roll free within
/// their prior.
pub fn fit(
    map: &LineMap,
    observations: &[Observation],
    posts: &PostBearings,
    prior: &Prior,
    calibrate: bool,
) -> Fit {
    let centre = Vector3::new(prior.pose.x(), prior.pose.y(), prior.pose.heading());
    let step = prior.sigma * SEARCH_STEP_SIGMAS;
    let (state, linearised) = coarse_starts(map, observations, posts, prior, &centre, &step)
        .into_iter()
        .map(|start| {
            let start = State::new(start.x, start.y, start.z, 0.0, 0.0);
            levenberg_marquardt(map, observations, posts, start, prior, false, MAX_ITERATIONS)
        })
        .min_by(|a, b| a.1.cost.total_cmp(&b.1.cost))
        .expect("at least one start");
    let calibrated = calibrate && explained_share(map, observations, &state) >= CORRECTABLE_SHARE;
    let (state, linearised) = if calibrated {
        levenberg_marquardt(map, observations, posts, state, prior, true, CALIBRATION_ITERATIONS)
    } else {
        (state, linearised)
    };
    let covariance = linearised
        .hessian
        .try_inverse()
        .map(|covariance| covariance.fixed_view::<3, 3>(0, 0).into_owned())
        .unwrap_or_else(|| Matrix3::from_diagonal(&prior.sigma.map(|s| s * s)));
    Fit {
        // Finite points and a finite prior give a finite fit; should that ever fail, keep the prior.
        pose: FieldPose::new(state[0], state[1], state[2]).unwrap_or(prior.pose),
        calibration: state.fixed_rows::<2>(3).into_owned(),
        cost: linearised.cost,
        covariance,
        line_information: pose_information(&linearised.line_information, &CameraCalibration::default().sigma),
        camera_information: calibrated.then(|| camera_information(&linearised.line_information)).flatten(),
    }
}

/// Share of the points within [`CORRECTABLE_DISTANCE`] of a line (or 3 σ, if more) at `state`.
fn explained_share(map: &LineMap, observations: &[Observation], state: &State) -> f64 {
    let place = to_field(state.fixed_rows::<3>(0).into_owned());
    let explained = observations
        .iter()
        .filter(|o| map.distance(place(&o.ground)) <= (3.0 * o.sigma).max(CORRECTABLE_DISTANCE))
        .count();
    explained as f64 / observations.len().max(1) as f64
}

/// The lines' information about the pose alone, the camera correction marginalised out within its
/// prior (Schur complement).
fn pose_information(lines: &Matrix5, camera_sigma: &Vector2<f64>) -> Matrix3<f64> {
    let pose = lines.fixed_view::<3, 3>(0, 0).into_owned();
    let cross = lines.fixed_view::<3, 2>(0, 3).into_owned();
    let calibration = lines.fixed_view::<2, 2>(3, 3).into_owned()
        + Matrix2::from_diagonal(&camera_sigma.map(|sigma| 1.0 / (sigma * sigma)));
    match calibration.try_inverse() {
        Some(inverse) => pose - cross * inverse * cross.transpose(),
        None => pose,
    }
}

/// The lines' information about the camera correction alone, the pose marginalised out with no prior
/// (Schur complement); `None` where the lines leave the pose free.
fn camera_information(lines: &Matrix5) -> Option<Matrix2<f64>> {
    let pose = lines.fixed_view::<3, 3>(0, 0).into_owned();
    let cross = lines.fixed_view::<3, 2>(0, 3).into_owned();
    let camera = lines.fixed_view::<2, 2>(3, 3).into_owned();
    Some(camera - cross.transpose() * pose.try_inverse()? * cross)
}

/// Test views: robot-frame points on the model's lines as seen from `truth`, every 10 cm, kept where
/// `visible` says (each with σ 2 cm).
#[cfg(test)]
pub(super) fn observe_lines(
    field: &crate::geometry::FieldModel,
    truth: &FieldPose,
    visible: impl Fn(Point2<f64>) -> bool,
) -> Vec<Observation> {
    LineMap::new(field)
        .primitives()
        .iter()
        .flat_map(|primitive| primitive.samples(0.1))
        .map(|point| truth.field_to_robot(point))
        .filter(|&ground| visible(ground))
        .map(|ground| Observation {
            ground,
            sigma: 0.02,
            weight: 1.0,
            calibration_rates: [Vector2::zeros(); 2],
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::FieldModel;
    use approx::assert_abs_diff_eq;

    /// Robot-frame points on the model's lines as seen from `truth`, within `range` metres ahead.
    fn observe(field: &FieldModel, truth: &FieldPose, range: f64) -> Vec<Observation> {
        observe_lines(field, truth, |ground| {
            ground.x > 0.2 && ground.coords.norm() < range && ground.y.abs() < ground.x
        })
    }

    #[test]
    fn the_coarse_starts_are_the_grid_s_least_costly_poses_in_grid_order() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        let truth = FieldPose::new(-3.5, -1.5, -2.4).unwrap();
        let observations = observe(&field, &truth, 3.0);
        let prior = Prior {
            pose: FieldPose::new(-3.2, -1.8, -2.2).unwrap(),
            sigma: Vector3::new(0.4, 0.4, 0.2),
            camera_sigma: Vector2::repeat(0.02),
        };
        let centre = Vector3::new(prior.pose.x(), prior.pose.y(), prior.pose.heading());
        let step = prior.sigma * SEARCH_STEP_SIGMAS;
        // Every grid pose scored in full, in grid order, sorted stably by cost.
        let mut all: Vec<(f64, Vector3<f64>)> = coarse_offsets()
            .map(|offset| {
                let pose = centre + offset.component_mul(&step);
                (
                    coarse_cost(&map, &observations, &PostBearings::default(), 1, &pose, &prior, None)
                        .unwrap(),
                    pose,
                )
            })
            .collect();
        assert_eq!(all.len(), 125);
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        let expected: Vec<Vector3<f64>> = all.iter().take(STARTS).map(|&(_, pose)| pose).collect();
        assert_eq!(
            coarse_starts(&map, &observations, &PostBearings::default(), &prior, &centre, &step),
            expected
        );
        // A pose's cost is left once it is sure to exceed the limit, and kept while it may not.
        let (best, _) = all[0];
        assert_eq!(
            coarse_cost(&map, &observations, &PostBearings::default(), 1, &expected[0], &prior, Some(best)),
            Some(best)
        );
        let (worst, pose) = all[all.len() - 1];
        assert_eq!(
            coarse_cost(&map, &observations, &PostBearings::default(), 1, &pose, &prior, Some(best)),
            None
        );
        assert!(worst > best);
    }

    #[test]
    fn recovers_a_perturbed_pose_from_a_corner() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        let truth = FieldPose::new(-3.5, -1.5, -2.4).unwrap();
        let observations = observe(&field, &truth, 3.0);
        assert!(observations.len() > 20, "{}", observations.len());
        let prior = Prior {
            pose: FieldPose::new(-3.2, -1.8, -2.4 + 0.2).unwrap(),
            sigma: Vector3::new(0.4, 0.4, 0.2),
            camera_sigma: Vector2::repeat(1.0_f64.to_radians()),
        };
        let fit = fit(&map, &observations, &PostBearings::default(), &prior, true);
        assert!(fit.pose.distance_to(&truth) < 0.01, "{:?}", fit.pose);
        assert_abs_diff_eq!(fit.pose.heading(), truth.heading(), epsilon = 0.005);
        assert!(fit.covariance[(0, 0)].sqrt() < 0.05);
    }

    /// Near the touchline, looking along it: only the touchline's points in view, the truth, and a
    /// guess 20 cm along it and 10 cm across.
    fn touchline_view(field: &FieldModel) -> (FieldPose, Vec<Observation>, Prior) {
        let truth = FieldPose::new(1.2, 2.6, 0.0).unwrap();
        let observations: Vec<Observation> =
            observe(field, &truth, 2.5).into_iter().filter(|o| (o.ground.y - 0.4).abs() < 0.01).collect();
        let prior = Prior {
            pose: FieldPose::new(1.4, 2.5, 0.05).unwrap(),
            sigma: Vector3::new(0.3, 0.3, 0.1),
            camera_sigma: Vector2::repeat(0.02),
        };
        (truth, observations, prior)
    }

    #[test]
    fn one_line_leaves_its_direction_to_the_prior() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        let (truth, observations, prior) = touchline_view(&field);
        assert!(observations.len() > 10);
        let fit = fit(&map, &observations, &PostBearings::default(), &prior, true);
        assert_abs_diff_eq!(fit.pose.y(), truth.y(), epsilon = 0.01);
        assert_abs_diff_eq!(fit.pose.x(), 1.4, epsilon = 0.05);
        // Along the line the lines say nothing: the information there is (almost) zero.
        assert!(fit.line_information[(0, 0)] < 1e-6 * fit.line_information[(1, 1)]);
    }

    #[test]
    fn a_goal_post_s_bearing_places_the_robot_along_the_one_line_it_sees() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        // Looking along the touchline towards a goal: the touchline and one post in view.
        let (truth, observations, prior) = touchline_view(&field);
        let seen = truth.field_to_robot(field.goals[1].posts[0]);
        let field_posts: Vec<Point2<f64>> = field.goal_posts().collect();
        let seen = [PostBearing { bearing: seen.y.atan2(seen.x), calibration_rates: Vector2::zeros() }];
        let posts = PostBearings { field: &field_posts, seen: &seen };
        let fit = fit(&map, &observations, &posts, &prior, true);
        assert!(fit.pose.distance_to(&truth) < 0.02, "{:?}", fit.pose);
        assert_abs_diff_eq!(fit.pose.heading(), truth.heading(), epsilon = 0.005);
        // Its bearing changes by 0.13 rad per metre along the line here: σ 0.5° is about 7 cm.
        assert!(fit.covariance[(0, 0)].sqrt() < 0.1, "{}", fit.covariance[(0, 0)].sqrt());
        // The post sharpens the pose, but it is not the lines' evidence.
        assert!(fit.line_information[(0, 0)] < 1e-6 * fit.line_information[(1, 1)]);
        // A bearing far from every post's is one loose observation: it may tug the fit along the line
        // (less than a third of the prior's 0.3 m), never drag it to a place where it would fit.
        let astray = [PostBearing { bearing: 1.2, calibration_rates: Vector2::zeros() }];
        let astray = PostBearings { field: &field_posts, seen: &astray };
        let fit = super::fit(&map, &observations, &astray, &prior, true);
        assert_abs_diff_eq!(fit.pose.x(), 1.4, epsilon = 0.1);
    }

    #[test]
    fn a_post_s_bearing_moves_with_the_camera_correction_and_its_derivatives_hold() {
        let field = FieldModel::default();
        let field_posts: Vec<Point2<f64>> = field.goal_posts().collect();
        let truth = FieldPose::new(1.2, 1.0, 0.3).unwrap();
        let seen = truth.field_to_robot(field.goals[1].posts[0]);
        // Seen through a camera 0.6° off in roll, which turns this bearing by rate × error.
        let (rates, error) = (Vector2::new(0.05, -0.4), Vector2::new(0.0, 0.6_f64.to_radians()));
        let post =
            PostBearing { bearing: seen.y.atan2(seen.x) - rates.dot(&error), calibration_rates: rates };
        let posts = PostBearings { field: &field_posts, seen: std::slice::from_ref(&post) };
        let at = |calibration: &Vector2<f64>| {
            State::new(truth.x(), truth.y(), truth.heading(), calibration.x, calibration.y)
        };
        let residual = |state: &State| posts.residuals(state).next().unwrap();
        assert_abs_diff_eq!(residual(&at(&error)).0, 0.0, epsilon = 1e-12);
        assert!(residual(&at(&Vector2::zeros())).0.abs() > 0.003, "uncorrected, the bearing is off");
        // Every derivative, the camera's too, against a central difference.
        let state = at(&Vector2::new(0.01, -0.02)) + State::new(0.3, -0.2, 0.1, 0.0, 0.0);
        let (_, derivatives) = residual(&state);
        for axis in 0..5 {
            let step = State::from_fn(|row, _| if row == axis { 1e-6 } else { 0.0 });
            let numeric = (residual(&(state + step)).0 - residual(&(state - step)).0) / 2e-6;
            assert_abs_diff_eq!(derivatives[axis], numeric, epsilon = 1e-6);
        }
    }

    #[test]
    fn a_guess_far_along_a_line_yields_to_what_little_the_lines_say_there() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        // Along the touchline towards the halfway line, of which only a loose stub of two points is
        // seen: the lines place the robot along the touchline to about 11 cm.
        let truth = FieldPose::new(-1.0, 2.6, 0.0).unwrap();
        let observations: Vec<Observation> = observe(&field, &truth, 2.5)
            .into_iter()
            .filter_map(|o| {
                let touchline = (o.ground.y - 0.4).abs() < 0.01;
                let stub = (o.ground.x - 1.0).abs() < 0.01 && (0.05..0.25).contains(&o.ground.y);
                (touchline || stub).then_some(Observation { sigma: if stub { 0.15 } else { o.sigma }, ..o })
            })
            .collect();
        assert_eq!(observations.iter().filter(|o| o.sigma == 0.15).count(), 2);
        // A guess 0.6 m (2.4 σ) off along the line, where the stub lies nearer the touchline than the
        // halfway line: held by a Gaussian prior (or a Cauchy loss at 2 σ) the fit stays at the guess.
        let prior = Prior {
            pose: FieldPose::new(-0.4, 2.6, 0.0).unwrap(),
            sigma: Vector3::new(0.25, 0.25, 0.05),
            camera_sigma: Vector2::repeat(0.02),
        };
        let fit = fit(&map, &observations, &PostBearings::default(), &prior, false);
        assert_abs_diff_eq!(fit.pose.y(), truth.y(), epsilon = 0.01);
        assert!((fit.pose.x() - truth.x()).abs() < 0.06, "{:?}", fit.pose);
    }

    #[test]
    fn a_camera_pitch_error_is_estimated_and_the_pose_stays_true() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        let truth = FieldPose::new(-3.5, -1.5, -2.4).unwrap();
        // A camera 0.5 m high pitched 0.8° more than the robot believes: every point seen too far
        // away, by d(distance)/d(pitch) = -(d² + h²) / h along its bearing.
        let (height, error) = (0.5, 0.8_f64.to_radians());
        let observations: Vec<Observation> = observe(&field, &truth, 3.0)
            .into_iter()
            .map(|observation| {
                let distance = observation.ground.coords.norm();
                let pitch_rate =
                    -(distance * distance + height * height) / height * observation.ground.coords / distance;
                Observation {
                    ground: observation.ground - pitch_rate * error,
                    calibration_rates: [pitch_rate, Vector2::zeros()],
                    ..observation
                }
            })
            .collect();
        let prior = Prior {
            pose: FieldPose::new(-3.3, -1.7, -2.3).unwrap(),
            sigma: Vector3::new(0.4, 0.4, 0.2),
            camera_sigma: Vector2::repeat(0.02),
        };
        let trusted = fit(&map, &observations, &PostBearings::default(), &prior, false);
        assert!(trusted.pose.distance_to(&truth) > 0.05, "the error moves the fit: {:?}", trusted.pose);
        let corrected = fit(&map, &observations, &PostBearings::default(), &prior, true);
        assert!(corrected.pose.distance_to(&truth) < 0.02, "{:?}", corrected.pose);
        assert_abs_diff_eq!(corrected.pose.heading(), truth.heading(), epsilon = 0.005);
        assert_abs_diff_eq!(corrected.calibration.x, error, epsilon = 0.15_f64.to_radians());
        assert!(corrected.cost < trusted.cost);
    }
}
