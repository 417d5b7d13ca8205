//! Fitting a robot pose to line points: a coarse search over the starting pose's uncertainty, then
//! Levenberg–Marquardt on point-to-line distances with a Cauchy loss and the starting pose as a
//! Gaussian prior. The covariance comes from the final normal equations.

use nalgebra::{Matrix3, Point2, Vector2, Vector3};

use super::line_map::LineMap;
use crate::geometry::FieldPose;
use crate::geometry::angle::normalize_angle;

/// Scale of the Cauchy loss, in standard deviations of a point.
const CAUCHY_SCALE: f64 = 2.0;
/// Coarse search: offsets per axis, in steps, each side of the start.
const SEARCH_STEPS: i32 = 2;
/// Coarse search: step as a share of the prior's standard deviation.
const SEARCH_STEP_SIGMAS: f64 = 0.75;
/// Coarse-search candidates refined by Levenberg–Marquardt.
const STARTS: usize = 3;
/// Levenberg–Marquardt iterations at most.
const MAX_ITERATIONS: usize = 30;

/// One line point as the optimiser sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Robot-frame ground position, metres.
    pub ground: Point2<f64>,
    /// Standard deviation of its position across the line, metres.
    pub sigma: f64,
}

/// A pose with its standard deviations: the prior the fit starts from and is held to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prior {
    /// The pose.
    pub pose: FieldPose,
    /// Standard deviations of (x, y, heading), metres and radians.
    pub sigma: Vector3<f64>,
}

/// The fitted pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    /// The pose.
    pub pose: FieldPose,
    /// Robust cost at the pose (lines and prior).
    pub cost: f64,
    /// Covariance of (x, y, heading) from lines and prior.
    pub covariance: Matrix3<f64>,
    /// Information about (x, y, heading) from the lines alone: degenerate where lines do not constrain.
    pub line_information: Matrix3<f64>,
}

fn to_field(pose: &Vector3<f64>, ground: &Point2<f64>) -> Point2<f64> {
    let (sin, cos) = pose.z.sin_cos();
    Point2::new(pose.x + cos * ground.x - sin * ground.y, pose.y + sin * ground.x + cos * ground.y)
}

fn cauchy(normalised: f64) -> f64 {
    0.5 * CAUCHY_SCALE * CAUCHY_SCALE * (normalised / CAUCHY_SCALE).powi(2).ln_1p()
}

fn prior_residual(pose: &Vector3<f64>, prior: &Prior) -> Vector3<f64> {
    Vector3::new(
        (pose.x - prior.pose.x()) / prior.sigma.x,
        (pose.y - prior.pose.y()) / prior.sigma.y,
        normalize_angle(pose.z - prior.pose.heading()) / prior.sigma.z,
    )
}

/// The cost using the map's cell distances: cheap, for the coarse search.
fn coarse_cost(map: &LineMap, observations: &[Observation], pose: &Vector3<f64>, prior: &Prior) -> f64 {
    let lines: f64 = observations
        .iter()
        .map(|observation| cauchy(map.distance(to_field(pose, &observation.ground)) / observation.sigma))
        .sum();
    lines + 0.5 * prior_residual(pose, prior).norm_squared()
}

/// Cost, Gauss–Newton normal equations (H, g) and the lines' share of H at `pose`.
struct Linearisation {
    cost: f64,
    hessian: Matrix3<f64>,
    gradient: Vector3<f64>,
    line_information: Matrix3<f64>,
}

fn linearise(
    map: &LineMap,
    observations: &[Observation],
    pose: &Vector3<f64>,
    prior: &Prior,
) -> Linearisation {
    let mut line_information = Matrix3::zeros();
    let mut gradient = Vector3::zeros();
    let mut cost = 0.0;
    let (sin, cos) = pose.z.sin_cos();
    for observation in observations {
        let field = to_field(pose, &observation.ground);
        let (distance, normal) = map.residual(field);
        let error = distance / observation.sigma;
        cost += cauchy(error);
        // IRLS weight of the Cauchy loss.
        let weight = 1.0 / (1.0 + (error / CAUCHY_SCALE).powi(2));
        let rotated = Vector2::new(
            cos * observation.ground.x - sin * observation.ground.y,
            sin * observation.ground.x + cos * observation.ground.y,
        );
        let jacobian = Vector3::new(normal.x, normal.y, normal.x * -rotated.y + normal.y * rotated.x)
            / observation.sigma;
        line_information += weight * jacobian * jacobian.transpose();
        gradient += weight * error * jacobian;
    }
    let residual = prior_residual(pose, prior);
    cost += 0.5 * residual.norm_squared();
    let prior_information = Matrix3::from_diagonal(&prior.sigma.map(|s| 1.0 / (s * s)));
    gradient += residual.component_div(&prior.sigma);
    Linearisation { cost, hessian: line_information + prior_information, gradient, line_information }
}

/// Levenberg–Marquardt from `start`.
fn levenberg_marquardt(
    map: &LineMap,
    observations: &[Observation],
    start: Vector3<f64>,
    prior: &Prior,
) -> (Vector3<f64>, Linearisation) {
    let mut pose = start;
    let mut state = linearise(map, observations, &pose, prior);
    let mut damping = 1e-3;
    for _ in 0..MAX_ITERATIONS {
        let mut improved = false;
        while damping < 1e8 {
            let damped = state.hessian + Matrix3::from_diagonal(&state.hessian.diagonal()) * damping;
            let Some(step) = damped.cholesky().map(|cholesky| -cholesky.solve(&state.gradient)) else {
                damping *= 10.0;
                continue;
            };
            let mut candidate = pose + step;
            candidate.z = normalize_angle(candidate.z);
            // Linearised at once: an accepted step needs it next, and a rejected one costs little more.
            let tried = linearise(map, observations, &candidate, prior);
            if tried.cost < state.cost {
                pose = candidate;
                state = tried;
                damping = (damping / 3.0).max(1e-9);
                improved = step.xy().norm() > 1e-5 || step.z.abs() > 1e-6;
                break;
            }
            damping *= 4.0;
        }
        if !improved {
            break;
        }
    }
    (pose, state)
}

/// Fits the pose that best explains `observations`, starting from and held to `prior`: a coarse
/// search over ±1.5 σ of the prior on the distance map, then Levenberg–Marquardt from the best few.
pub fn fit(map: &LineMap, observations: &[Observation], prior: &Prior) -> Fit {
    let centre = Vector3::new(prior.pose.x(), prior.pose.y(), prior.pose.heading());
    let step = prior.sigma * SEARCH_STEP_SIGMAS;
    let mut candidates: Vec<(f64, Vector3<f64>)> = Vec::new();
    for i in -SEARCH_STEPS..=SEARCH_STEPS {
        for j in -SEARCH_STEPS..=SEARCH_STEPS {
            for k in -SEARCH_STEPS..=SEARCH_STEPS {
                let pose = centre + Vector3::new(i as f64 * step.x, j as f64 * step.y, k as f64 * step.z);
                candidates.push((coarse_cost(map, observations, &pose, prior), pose));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let best = candidates
        .iter()
        .take(STARTS)
        .map(|(_, start)| levenberg_marquardt(map, observations, *start, prior))
        .min_by(|a, b| a.1.cost.total_cmp(&b.1.cost))
        .expect("at least one start");
    let (pose, state) = best;
    let covariance =
        state.hessian.try_inverse().unwrap_or_else(|| Matrix3::from_diagonal(&prior.sigma.map(|s| s * s)));
    Fit {
        // Finite points and a finite prior give a finite fit; should that ever fail, keep the prior.
        pose: FieldPose::new(pose.x, pose.y, pose.z).unwrap_or(prior.pose),
        cost: state.cost,
        covariance,
        line_information: state.line_information,
    }
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
        .map(|ground| Observation { ground, sigma: 0.02 })
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
    fn recovers_a_perturbed_pose_from_a_corner() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        let truth = FieldPose::new(-3.5, -1.5, -2.4).unwrap();
        let observations = observe(&field, &truth, 3.0);
        assert!(observations.len() > 20, "{}", observations.len());
        let prior = Prior {
            pose: FieldPose::new(-3.2, -1.8, -2.4 + 0.2).unwrap(),
            sigma: Vector3::new(0.4, 0.4, 0.2),
        };
        let fit = fit(&map, &observations, &prior);
        assert!(fit.pose.distance_to(&truth) < 0.01, "{:?}", fit.pose);
        assert_abs_diff_eq!(fit.pose.heading(), truth.heading(), epsilon = 0.005);
        assert!(fit.covariance[(0, 0)].sqrt() < 0.05);
    }

    #[test]
    fn one_line_leaves_its_direction_to_the_prior() {
        let field = FieldModel::default();
        let map = LineMap::new(&field);
        // Near the touchline, looking along it: only the touchline in view.
        let truth = FieldPose::new(1.2, 2.6, 0.0).unwrap();
        let observations: Vec<Observation> =
            observe(&field, &truth, 2.5).into_iter().filter(|o| (o.ground.y - 0.4).abs() < 0.01).collect();
        assert!(observations.len() > 10);
        let prior =
            Prior { pose: FieldPose::new(1.4, 2.5, 0.05).unwrap(), sigma: Vector3::new(0.3, 0.3, 0.1) };
        let fit = fit(&map, &observations, &prior);
        assert_abs_diff_eq!(fit.pose.y(), truth.y(), epsilon = 0.01);
        assert_abs_diff_eq!(fit.pose.x(), 1.4, epsilon = 0.05);
        // Along the line the lines say nothing: the information there is (almost) zero.
        assert!(fit.line_information[(0, 0)] < 1e-6 * fit.line_information[(1, 1)]);
    }
}
