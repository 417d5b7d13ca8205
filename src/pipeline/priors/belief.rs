//! The team's belief: the pose the team's localisation held before the robot fell or was picked up.
//! A fall or a short carry leaves the robot near where it was, so the twin near the belief is the
//! right one; the belief's age widens its spread by how far a robot can walk and turn meanwhile.

use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, PoseSigma};
use crate::pipeline::Hypothesis;
use crate::refine::Guess;

/// How far a robot may have walked per second of the belief's age, metres.
pub const DRIFT_M_PER_S: f64 = 0.3;
/// How far it may have turned per second of the belief's age, radians.
pub const TURN_RAD_PER_S: f64 = 0.5;

/// A Gaussian around the team's last pose estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeliefPrior {
    /// The estimate.
    pub pose: FieldPose,
    /// Its standard deviations, as the team's localisation gives them.
    pub sigma: PoseSigma,
    /// How old the estimate was when the robot fell or was lifted, seconds.
    pub age_s: f64,
}

impl BeliefPrior {
    /// The belief `pose` with spread `sigma`, `age_s` seconds old at the event.
    pub fn new(pose: FieldPose, sigma: PoseSigma, age_s: f64) -> Self {
        Self { pose, sigma, age_s }
    }

    /// Where the robot may be now: the belief's σ widened by how far it may have walked and turned
    /// since the belief was held.
    pub fn spread(&self) -> PoseSigma {
        let age = self.age_s.max(0.0);
        let widen = |sigma: f64, drift: f64| sigma.hypot(drift * age);
        PoseSigma {
            x: widen(self.sigma.x, DRIFT_M_PER_S),
            y: widen(self.sigma.y, DRIFT_M_PER_S),
            theta: widen(self.sigma.theta, TURN_RAD_PER_S),
        }
    }

    /// The belief as a guess for the field lines to check, as they check the network's hypotheses.
    pub fn guess(&self) -> Guess {
        Guess { pose: self.pose, sigma: self.spread() }
    }

    /// The log-likelihood of a hypothesis, up to a constant: the belief's Gaussian, its
    /// [`spread`](Self::spread) combined with the hypothesis' own σ.
    pub fn log_likelihood(&self, hypothesis: &Hypothesis) -> f64 {
        let spread = self.spread();
        let sx = spread.x.hypot(hypothesis.sigma.x);
        let sy = spread.y.hypot(hypothesis.sigma.y);
        let st = spread.theta.hypot(hypothesis.sigma.theta);
        let dx = (hypothesis.pose.x() - self.pose.x()) / sx;
        let dy = (hypothesis.pose.y() - self.pose.y()) / sy;
        let dt = angle_distance(hypothesis.pose.heading(), self.pose.heading()) / st;
        -0.5 * (dx * dx + dy * dy + dt * dt)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, y: f64, theta: f64) -> Hypothesis {
        let sigma = PoseSigma { x: 0.1, y: 0.1, theta: 0.05 };
        Hypothesis { pose: FieldPose::new(x, y, theta).unwrap(), weight: 0.5, sigma, lines: None }
    }

    #[test]
    fn the_near_twin_is_far_likelier_and_age_softens_the_difference() {
        let sigma = PoseSigma { x: 0.4, y: 0.4, theta: 0.3 };
        let fresh = BeliefPrior::new(FieldPose::new(-2.0, 1.0, 0.5).unwrap(), sigma, 0.0);
        let (near, twin) = (at(-1.7, 1.2, 0.6), at(1.7, -1.2, 0.6 - std::f64::consts::PI));
        assert!(fresh.log_likelihood(&near) > 0.5f64.ln());
        assert!(fresh.log_likelihood(&twin) < 1e-20f64.ln());
        let old = BeliefPrior { age_s: 10.0, ..fresh };
        let log_ratio = |prior: &BeliefPrior| prior.log_likelihood(&twin) - prior.log_likelihood(&near);
        assert!(log_ratio(&old) > log_ratio(&fresh));
    }
}
