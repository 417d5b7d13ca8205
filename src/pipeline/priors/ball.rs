//! The ball rule: the ball the robot sees, placed on the field from a hypothesis, should land where
//! the team sees it. From the wrong twin it lands on the point reflection of the team's ball. The
//! team's ball may itself come from flipped teammates: the more teammates agree on it, the less
//! likely that is.

use nalgebra::Point2;

use crate::pipeline::Hypothesis;

/// The robot's own ball observation's spread: this much plus [`OWN_SIGMA_PER_M`] per metre of distance.
pub const OWN_SIGMA_M: f64 = 0.1;
/// Spread of the robot's own ball observation per metre of distance.
pub const OWN_SIGMA_PER_M: f64 = 0.1;

/// The robot's own ball and the team's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BallPrior {
    /// Distance of the ball the robot sees, metres.
    pub own_distance: f64,
    /// Its bearing, radians, counter-clockwise from the robot's heading.
    pub own_bearing: f64,
    /// Where the team sees the ball on the field, metres.
    pub team: Point2<f64>,
    /// The team ball's standard deviation, metres.
    pub team_sigma: f64,
    /// How many teammates agree on the team ball (at least 1).
    pub teammates: u32,
    /// Chance that one teammate's ball is point-reflected (it is flipped itself); the team ball is
    /// flipped with this to the power of `teammates`.
    pub flip_probability: f64,
}

impl BallPrior {
    /// Where the robot's own ball lies on the field if the robot stands at `hypothesis`.
    pub fn own_ball_on_field(&self, hypothesis: &Hypothesis) -> Point2<f64> {
        let (sin, cos) = self.own_bearing.sin_cos();
        hypothesis.pose.robot_to_field(Point2::new(self.own_distance * cos, self.own_distance * sin))
    }

    /// The likelihood of a hypothesis, up to a constant: a mixture of the team ball being right and
    /// being flipped, each a Gaussian in the distance between the own ball placed from the hypothesis
    /// and the team ball (σ: the team's, the own observation's, and the hypothesis' position and
    /// heading σ carried out to the ball's distance).
    pub fn likelihood(&self, hypothesis: &Hypothesis) -> f64 {
        let own = OWN_SIGMA_M + OWN_SIGMA_PER_M * self.own_distance;
        let position = hypothesis.sigma.x.hypot(hypothesis.sigma.y);
        let heading = hypothesis.sigma.theta * self.own_distance;
        let variance = self.team_sigma.powi(2) + own.powi(2) + position.powi(2) + heading.powi(2);
        let ball = self.own_ball_on_field(hypothesis);
        let gaussian = |at: Point2<f64>| (-0.5 * (ball - at).norm_squared() / variance).exp();
        let flipped = self.flip_probability.clamp(0.0, 1.0).powi(self.teammates.max(1) as i32);
        (1.0 - flipped) * gaussian(self.team) + flipped * gaussian(Point2::from(-self.team.coords))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{FieldPose, PoseSigma, Symmetry};

    #[test]
    fn the_twin_that_puts_the_ball_where_the_team_sees_it_wins_by_the_teammates_confidence() {
        let sigma = PoseSigma { x: 0.05, y: 0.05, theta: 0.02 };
        let truth = FieldPose::new(-3.0, -1.5, 0.3).unwrap();
        let right = Hypothesis { pose: truth, weight: 0.5, sigma, lines: None };
        let twin = Hypothesis { pose: Symmetry::PointReflection.apply(&truth), ..right };
        let ball = truth.robot_to_field(Point2::new(2.0, 0.5));
        let prior = |teammates| BallPrior {
            own_distance: 2.0f64.hypot(0.5),
            own_bearing: 0.5f64.atan2(2.0),
            team: ball + nalgebra::Vector2::new(0.3, -0.2),
            team_sigma: 0.3,
            teammates,
            flip_probability: 0.2,
        };
        assert!((prior(1).own_ball_on_field(&right) - ball).norm() < 1e-9);
        let ratio = |teammates| prior(teammates).likelihood(&right) / prior(teammates).likelihood(&twin);
        assert!((ratio(1) - 4.0).abs() < 0.5, "{}", ratio(1));
        assert!(ratio(3) > 50.0, "{}", ratio(3));
    }
}
