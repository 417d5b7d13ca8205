//! The team's belief: the pose the team's localisation held before the robot fell or was picked up.
//! A fall or a short carry leaves the robot near where it was, so the twin near the belief is the
//! right one; the belief's age widens its spread by how far a robot can walk and turn meanwhile.

use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, PoseSigma};
use crate::pipeline::Hypothesis;

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

    /// The likelihood of a hypothesis, up to a constant: the belief's Gaussian, its σ combined with the
    /// hypothesis' own σ and the drift since the belief.
    pub fn likelihood(&self, hypothesis: &Hypothesis) -> f64 {
        let age = self.age_s.max(0.0);
        let combine =
            |belief: f64, own: f64, drift: f64| (belief * belief + own * own + drift * drift).sqrt();
        let sx = combine(self.sigma.x, hypothesis.sigma.x, DRIFT_M_PER_S * age);
        let sy = combine(self.sigma.y, hypothesis.sigma.y, DRIFT_M_PER_S * age);
        let st = combine(self.sigma.theta, hypothesis.sigma.theta, TURN_RAD_PER_S * age);
        let dx = (hypothesis.pose.x() - self.pose.x()) / sx;
        let dy = (hypothesis.pose.y() - self.pose.y()) / sy;
        let dt = angle_distance(hypothesis.pose.heading(), self.pose.heading()) / st;
        (-0.5 * (dx * dx + dy * dy + dt * dt)).exp()
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
        assert!(fresh.likelihood(&near) > 0.5);
        assert!(fresh.likelihood(&twin) < 1e-20);
        let old = BeliefPrior { age_s: 10.0, ..fresh };
        assert!(
            old.likelihood(&twin) / old.likelihood(&near) > fresh.likelihood(&twin) / fresh.likelihood(&near)
        );
    }
}
