//! Telling the twins apart: per burst, whether the heaviest hypothesis lies on the true pose's side of
//! the point symmetry (nearer the truth than the truth's twin), how much weight the right side holds,
//! and whether the priors turned a right answer wrong or a wrong one right.

use serde::Serialize;

use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, Symmetry};
use crate::pipeline::Hypothesis;

/// Distance between poses, a radian of heading counted as a metre.
fn distance(a: &FieldPose, b: &FieldPose) -> f64 {
    a.distance_to(b) + angle_distance(a.heading(), b.heading())
}

/// One burst's twins.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwinEvaluation {
    /// The heaviest hypothesis after the priors is the right twin.
    pub right_after: bool,
    /// The heaviest before the priors was.
    pub right_before: bool,
    /// Weight of the hypotheses on the right side after the priors.
    pub right_weight: f64,
}

impl TwinEvaluation {
    /// Scores `hypotheses` (heaviest first, at least one) against `truth`; `before` holds their
    /// weights before the priors in the same order (empty when no prior applied).
    pub fn new(truth: &FieldPose, hypotheses: &[Hypothesis], before: &[f64]) -> Self {
        let twin = Symmetry::PointReflection.apply(truth);
        let right: Vec<bool> =
            hypotheses.iter().map(|h| distance(&h.pose, truth) < distance(&h.pose, &twin)).collect();
        let before: Vec<f64> = if before.len() == hypotheses.len() {
            before.to_vec()
        } else {
            hypotheses.iter().map(|h| h.weight).collect()
        };
        let heaviest_before = (0..before.len()).max_by(|&a, &b| before[a].total_cmp(&before[b])).unwrap_or(0);
        Self {
            right_after: right[0],
            right_before: right[heaviest_before],
            right_weight: hypotheses.iter().zip(&right).filter(|(_, r)| **r).map(|(h, _)| h.weight).sum(),
        }
    }
}

/// Twins over a replay's bursts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TwinMetrics {
    /// Bursts evaluated.
    pub bursts: usize,
    /// Share whose heaviest hypothesis is the right twin.
    pub right_heaviest: f64,
    /// The same before the priors.
    pub right_heaviest_before: f64,
    /// Share where the priors turned a right heaviest hypothesis into a wrong one.
    pub flipped_right_to_wrong: f64,
    /// Share where they turned a wrong one right.
    pub flipped_wrong_to_right: f64,
    /// Smallest weight left to the right side.
    pub right_weight_min: f64,
    /// Median weight of the right side.
    pub right_weight_median: f64,
    /// Share where the right side keeps at least 10% of the weight.
    pub right_weight_at_least_10pct: f64,
}

impl TwinMetrics {
    /// Summarises; `None` without bursts.
    pub fn summarise(evaluations: &[TwinEvaluation]) -> Option<Self> {
        if evaluations.is_empty() {
            return None;
        }
        let share = |pick: &dyn Fn(&TwinEvaluation) -> bool| {
            evaluations.iter().filter(|e| pick(e)).count() as f64 / evaluations.len() as f64
        };
        let weights: Vec<f64> = evaluations.iter().map(|e| e.right_weight).collect();
        Some(Self {
            bursts: evaluations.len(),
            right_heaviest: share(&|e| e.right_after),
            right_heaviest_before: share(&|e| e.right_before),
            flipped_right_to_wrong: share(&|e| e.right_before && !e.right_after),
            flipped_wrong_to_right: share(&|e| !e.right_before && e.right_after),
            right_weight_min: weights.iter().copied().fold(f64::INFINITY, f64::min),
            right_weight_median: super::median(&weights),
            right_weight_at_least_10pct: share(&|e| e.right_weight >= 0.1 - 1e-9),
        })
    }

    /// One line for people.
    pub fn line(&self) -> String {
        format!(
            "twins: right heaviest {:.1}% (before priors {:.1}%), right→wrong {:.1}%, wrong→right {:.1}%, \
             right weight min {:.3} median {:.3}, ≥ 0.1 in {:.1}%",
            100.0 * self.right_heaviest,
            100.0 * self.right_heaviest_before,
            100.0 * self.flipped_right_to_wrong,
            100.0 * self.flipped_wrong_to_right,
            self.right_weight_min,
            self.right_weight_median,
            100.0 * self.right_weight_at_least_10pct
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PoseSigma;

    fn hypothesis(pose: FieldPose, weight: f64) -> Hypothesis {
        Hypothesis { pose, weight, sigma: PoseSigma { x: 0.1, y: 0.1, theta: 0.1 }, lines: None }
    }

    #[test]
    fn a_prior_that_turns_the_heaviest_to_the_wrong_twin_is_counted() {
        let truth = FieldPose::new(-2.0, 1.0, 0.5).unwrap();
        let near = FieldPose::new(-1.8, 1.1, 0.6).unwrap();
        let twin = Symmetry::PointReflection.apply(&near);
        let flipped =
            TwinEvaluation::new(&truth, &[hypothesis(twin, 0.9), hypothesis(near, 0.1)], &[0.4, 0.6]);
        assert_eq!((flipped.right_after, flipped.right_before), (false, true));
        assert!((flipped.right_weight - 0.1).abs() < 1e-12);
        let plain = TwinEvaluation::new(&truth, &[hypothesis(near, 0.6), hypothesis(twin, 0.4)], &[]);
        let metrics = TwinMetrics::summarise(&[flipped, plain]).unwrap();
        assert_eq!((metrics.right_heaviest, metrics.flipped_right_to_wrong), (0.5, 0.5));
        assert_eq!(metrics.right_weight_min, 0.1);
    }
}
