//! The game-context prior: where the rules put a robot back after a penalty, used to re-weight the
//! symmetric hypotheses the camera supports. It never moves a pose and only tells the symmetric twins
//! apart, which the image alone cannot do on a symmetric field; its placements are also guesses for
//! the field lines, which add a hypothesis only where the lines support one.

use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, PoseSigma};
use crate::refine::Guess;

/// Where the rules place returning robots, and how far from it they may stand.
#[derive(Clone, Debug, PartialEq)]
pub struct PlacementPrior {
    /// Placement poses.
    pub placements: Vec<FieldPose>,
    /// Standard deviation along x, metres.
    pub sigma_x: f64,
    /// Standard deviation along y, metres.
    pub sigma_y: f64,
    /// Standard deviation of the heading, radians.
    pub sigma_theta: f64,
    /// Likelihood left to a hypothesis far from every placement, so that the camera still decides
    /// when no hypothesis fits the rule (e.g. the robot was put back elsewhere).
    pub floor: f64,
}

impl PlacementPrior {
    /// A robot returning from a penalty (SPL rules): beside either touchline in its own half, near the
    /// penalty mark's projection, facing the field: (−3.2 m, ±3.5 m, ∓90°). The spreads follow what
    /// B-Human uses (0.7 m along the touchline, 0.2 m across it, 17°), widened across the line and in
    /// heading for the network's error.
    pub fn penalty_return() -> Self {
        let placement = |y: f64, heading_deg: f64| {
            FieldPose::new(-3.2, y, heading_deg.to_radians()).expect("finite placement")
        };
        Self {
            placements: vec![placement(3.5, -90.0), placement(-3.5, 90.0)],
            sigma_x: 0.7,
            sigma_y: 0.5,
            sigma_theta: 30f64.to_radians(),
            floor: 1e-3,
        }
    }

    /// Each placement as a guess for the field lines to check.
    pub fn guesses(&self) -> impl Iterator<Item = Guess> + '_ {
        let sigma = PoseSigma { x: self.sigma_x, y: self.sigma_y, theta: self.sigma_theta };
        self.placements.iter().map(move |&pose| Guess { pose, sigma })
    }

    /// The prior's likelihood of a pose, up to a constant: the nearest placement's Gaussian, at least
    /// the floor.
    pub fn likelihood(&self, pose: &FieldPose) -> f64 {
        self.placements
            .iter()
            .map(|placement| {
                let dx = (pose.x() - placement.x()) / self.sigma_x;
                let dy = (pose.y() - placement.y()) / self.sigma_y;
                let dtheta = angle_distance(pose.heading(), placement.heading()) / self.sigma_theta;
                (-0.5 * (dx * dx + dy * dy + dtheta * dtheta)).exp()
            })
            .fold(self.floor, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{PoseSigma, Symmetry};
    use crate::pipeline::{Hypothesis, Priors};

    /// The placement alone, without the floor (whose own tests are in the parent module).
    fn placement() -> Priors {
        Priors { placement: Some(PlacementPrior::penalty_return()), min_share: 0.0, ..Priors::default() }
    }

    fn twins(pose: FieldPose) -> Vec<Hypothesis> {
        let sigma = PoseSigma { x: 0.3, y: 0.3, theta: 0.1 };
        [pose, Symmetry::PointReflection.apply(&pose)]
            .into_iter()
            .map(|pose| Hypothesis { pose, weight: 0.5, sigma, lines: None })
            .collect()
    }

    #[test]
    fn the_own_half_twin_wins_after_a_penalty() {
        // The network, 40 cm and 10° off, cannot tell the two halves apart.
        let seen = FieldPose::new(-2.9, -3.2, 80f64.to_radians()).unwrap();
        let mut hypotheses = twins(Symmetry::PointReflection.apply(&seen));
        placement().apply(&mut hypotheses);
        assert!(hypotheses[0].pose.distance_to(&seen) < 1e-9);
        assert!(hypotheses[0].weight > 0.99, "{}", hypotheses[0].weight);
        assert!((hypotheses.iter().map(|h| h.weight).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_prior_moves_no_pose_and_leaves_far_hypotheses_to_the_camera() {
        let far = FieldPose::new(1.0, 0.5, 0.0).unwrap();
        let mut hypotheses = twins(far);
        hypotheses[0].weight = 0.7;
        hypotheses[1].weight = 0.3;
        let poses: Vec<FieldPose> = hypotheses.iter().map(|h| h.pose).collect();
        placement().apply(&mut hypotheses);
        assert_eq!(hypotheses.iter().map(|h| h.pose).collect::<Vec<_>>(), poses);
        assert!((hypotheses[0].weight - 0.7).abs() < 1e-9, "both at the floor: the camera's weights stay");
    }
}
