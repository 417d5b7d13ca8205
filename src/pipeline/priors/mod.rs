//! Game and team context that tells the point-symmetric twins apart: where the rules put a robot
//! back after a penalty ([`placement`]), the team's belief from before a fall or a pick-up
//! ([`belief`]), the robot's own half ([`own_half`]), and the robot's own ball against the team's
//! ([`ball`]).
//!
//! Priors only re-weight: no pose or σ changes. Each prior gives every hypothesis a likelihood; they
//! combine as independent evidence (their product times the weight the network and the lines gave),
//! and a floor keeps a wrong prior from making a right hypothesis vanish: no hypothesis ends below
//! `min(its weight before the priors, min_share)`. All of it is pure maths over plain values.
//!
//! The priors that name poses (the belief, the placements) also hand them to the field lines as
//! guesses ([`Priors::guesses`]), beside the network's hypotheses: where the network is lost but the
//! robot is where the team believed, the lines find the place there. A guess the lines do not support
//! adds nothing, so a prior still cannot put a hypothesis where the image does not.

pub mod ball;
pub mod belief;
pub mod own_half;
pub mod placement;
pub mod simulate;

use serde::Serialize;

pub use ball::BallPrior;
pub use belief::BeliefPrior;
pub use own_half::OwnHalfPrior;
pub use placement::PlacementPrior;

use super::Hypothesis;
use crate::refine::Guess;

/// Default floor: after the priors every hypothesis keeps at least this share of the weight (or the
/// share it had before them, if that was less).
pub const DEFAULT_MIN_SHARE: f64 = 0.1;

/// The context of one burst: which priors apply, and the floor.
#[derive(Clone, Debug, PartialEq)]
pub struct Priors {
    /// The penalty-return placement (the robot was put back by a referee).
    pub placement: Option<PlacementPrior>,
    /// The team's pose estimate from before the event.
    pub belief: Option<BeliefPrior>,
    /// The robot is on its own half (x < 0), e.g. the goalkeeper.
    pub own_half: Option<OwnHalfPrior>,
    /// The robot's own ball observation against the team's ball.
    pub ball: Option<BallPrior>,
    /// No hypothesis ends below `min(its weight before the priors, min_share)`; in [0, 0.5].
    pub min_share: f64,
}

impl Default for Priors {
    fn default() -> Self {
        Self { placement: None, belief: None, own_half: None, ball: None, min_share: DEFAULT_MIN_SHARE }
    }
}

/// Which prior a factor came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PriorKind {
    /// [`PlacementPrior`].
    PenaltyReturn,
    /// [`BeliefPrior`].
    Belief,
    /// [`OwnHalfPrior`].
    OwnHalf,
    /// [`BallPrior`].
    Ball,
    /// The floor lifted a hypothesis the other priors pushed below its minimum share.
    Floor,
}

impl PriorKind {
    /// The name on the wire.
    pub fn name(self) -> &'static str {
        match self {
            PriorKind::PenaltyReturn => "penalty_return",
            PriorKind::Belief => "belief",
            PriorKind::OwnHalf => "own_half",
            PriorKind::Ball => "ball",
            PriorKind::Floor => "floor",
        }
    }
}

/// What one prior did: its factor for each hypothesis, in the order of the re-weighted hypotheses.
/// Factors are relative (the largest is 1); for the floor, the factor it multiplied a weight by.
#[derive(Clone, Debug, PartialEq)]
pub struct AppliedPrior {
    /// The prior.
    pub kind: PriorKind,
    /// One factor per hypothesis.
    pub factors: Vec<f64>,
}

/// What the priors of a burst did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PriorReport {
    /// The priors that applied, in the order penalty return, belief, own half, ball, floor.
    pub applied: Vec<AppliedPrior>,
    /// Each hypothesis' weight before the priors, in the order of the re-weighted hypotheses.
    pub before: Vec<f64>,
}

impl PriorReport {
    /// Whether any prior applied.
    pub fn is_empty(&self) -> bool {
        self.applied.is_empty()
    }

    /// The applied priors' names joined by `+` (e.g. `belief+own_half`), `None` when none applied:
    /// the message's `prior` key.
    pub fn names(&self) -> Option<String> {
        let names: Vec<&str> = self.applied.iter().map(|applied| applied.kind.name()).collect();
        (!names.is_empty()).then(|| names.join("+"))
    }
}

impl Priors {
    /// Whether no prior is set (the floor alone does nothing).
    pub fn is_empty(&self) -> bool {
        self.placement.is_none() && self.belief.is_none() && self.own_half.is_none() && self.ball.is_none()
    }

    /// The poses the context names, for the field lines to check: the belief (widened by its age) and
    /// the placements.
    pub fn guesses(&self) -> Vec<Guess> {
        let belief = self.belief.iter().map(BeliefPrior::guess);
        belief.chain(self.placement.iter().flat_map(PlacementPrior::guesses)).collect()
    }

    /// Each set prior with its likelihood of every hypothesis, relative to the likeliest (whose factor
    /// is 1). Compared as logarithms, so that a prior far from every hypothesis still prefers the
    /// nearest instead of underflowing to a tie; a prior that rules every hypothesis out says nothing.
    fn factors(&self, hypotheses: &[Hypothesis]) -> Vec<AppliedPrior> {
        let mut applied = Vec::new();
        let mut add = |kind, log_likelihood: &dyn Fn(&Hypothesis) -> f64| {
            let raw: Vec<f64> = hypotheses
                .iter()
                .map(|h| Some(log_likelihood(h)).filter(|l| !l.is_nan()).unwrap_or(f64::NEG_INFINITY))
                .collect();
            let largest = raw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let factors =
                raw.iter().map(|l| if largest.is_finite() { (l - largest).exp() } else { 1.0 }).collect();
            applied.push(AppliedPrior { kind, factors });
        };
        if let Some(prior) = &self.placement {
            add(PriorKind::PenaltyReturn, &|h| prior.likelihood(&h.pose).ln());
        }
        if let Some(prior) = &self.belief {
            add(PriorKind::Belief, &|h| prior.log_likelihood(h));
        }
        if let Some(prior) = &self.own_half {
            add(PriorKind::OwnHalf, &|h| prior.likelihood(&h.pose).ln());
        }
        if let Some(prior) = &self.ball {
            add(PriorKind::Ball, &|h| prior.likelihood(h).ln());
        }
        applied
    }

    /// Re-weights `hypotheses` (poses and σ untouched), sorts them heaviest first and says what each
    /// prior did. Without priors the hypotheses stay as they are and the report is empty.
    pub fn apply(&self, hypotheses: &mut [Hypothesis]) -> PriorReport {
        if self.is_empty() || hypotheses.is_empty() {
            return PriorReport::default();
        }
        let mut applied = self.factors(hypotheses);
        let before: Vec<f64> = hypotheses.iter().map(|h| h.weight).collect();
        let likelihood: Vec<f64> = (0..hypotheses.len())
            .map(|index| applied.iter().map(|prior| prior.factors[index]).product())
            .collect();
        let (after, floored) = reweight(&before, &likelihood, self.min_share);
        if let Some(lifted) = floored {
            applied.push(AppliedPrior { kind: PriorKind::Floor, factors: lifted });
        }
        hypotheses.iter_mut().zip(&after).for_each(|(h, &weight)| h.weight = weight);
        let mut order: Vec<usize> = (0..hypotheses.len()).collect();
        order.sort_by(|&a, &b| after[b].total_cmp(&after[a]));
        let sorted: Vec<Hypothesis> = order.iter().map(|&index| hypotheses[index]).collect();
        hypotheses.copy_from_slice(&sorted);
        let reorder = |values: &[f64]| order.iter().map(|&index| values[index]).collect::<Vec<f64>>();
        applied.iter_mut().for_each(|prior| prior.factors = reorder(&prior.factors));
        PriorReport { applied, before: reorder(&before) }
    }
}

/// The posterior weights `before × likelihood`, normalised, with the floor: no weight ends below
/// `min(before, min_share)`. Weights held at their floor take exactly it; the others share the rest in
/// proportion to their posterior. Returns the weights and, when the floor lifted any, the factor it
/// applied to each weight (1 where it did nothing). `before` sums to 1; `min_share` lies in [0, 0.5].
pub fn reweight(before: &[f64], likelihood: &[f64], min_share: f64) -> (Vec<f64>, Option<Vec<f64>>) {
    let posterior: Vec<f64> = before.iter().zip(likelihood).map(|(w, l)| w * l).collect();
    let total: f64 = posterior.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return (before.to_vec(), None);
    }
    let posterior: Vec<f64> = posterior.iter().map(|p| p / total).collect();
    let floors: Vec<f64> = before.iter().map(|w| w.min(min_share)).collect();
    let mut held = vec![false; before.len()];
    let mut weights = posterior.clone();
    // Each round holds at least one more weight at its floor, so this ends within len rounds.
    loop {
        let held_mass: f64 = floors.iter().zip(&held).filter(|(_, held)| **held).map(|(f, _)| f).sum();
        let free_mass: f64 = posterior.iter().zip(&held).filter(|(_, held)| !**held).map(|(p, _)| p).sum();
        let scale = if free_mass > 0.0 { (1.0 - held_mass) / free_mass } else { 0.0 };
        for index in 0..weights.len() {
            weights[index] = if held[index] { floors[index] } else { posterior[index] * scale };
        }
        let below: Vec<usize> =
            (0..weights.len()).filter(|&i| !held[i] && weights[i] < floors[i] * (1.0 - 1e-12)).collect();
        if below.is_empty() {
            break;
        }
        below.into_iter().for_each(|index| held[index] = true);
    }
    if !held.iter().any(|&held| held) {
        return (weights, None);
    }
    let lifted = weights.iter().zip(&posterior).map(|(w, p)| if *p > 0.0 { w / p } else { 1.0 }).collect();
    (weights, Some(lifted))
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::geometry::{FieldPose, PoseSigma, Symmetry};

    fn twins(pose: FieldPose, weight: f64) -> Vec<Hypothesis> {
        let sigma = PoseSigma { x: 0.3, y: 0.3, theta: 0.1 };
        [(pose, weight), (Symmetry::PointReflection.apply(&pose), 1.0 - weight)]
            .into_iter()
            .map(|(pose, weight)| Hypothesis { pose, weight, sigma, lines: None })
            .collect()
    }

    fn pose(x: f64, y: f64, theta_deg: f64) -> FieldPose {
        FieldPose::new(x, y, theta_deg.to_radians()).unwrap()
    }

    #[test]
    fn no_priors_change_nothing_and_report_nothing() {
        let mut hypotheses = twins(pose(-2.0, 1.0, 30.0), 0.3);
        let report = Priors::default().apply(&mut hypotheses);
        assert!(report.is_empty());
        assert_eq!(report.names(), None);
        assert_eq!(hypotheses, twins(pose(-2.0, 1.0, 30.0), 0.3), "not even re-sorted");
    }

    #[test]
    fn a_right_belief_picks_the_right_twin_and_the_report_says_how() {
        let truth = pose(1.5, -2.0, 120.0);
        let mut hypotheses = twins(Symmetry::PointReflection.apply(&truth), 0.5);
        let belief = BeliefPrior::new(pose(1.9, -1.6, 100.0), PoseSigma { x: 0.5, y: 0.5, theta: 0.5 }, 0.5);
        let priors =
            Priors { belief: Some(belief), own_half: Some(OwnHalfPrior::default()), ..Priors::default() };
        let report = priors.apply(&mut hypotheses);
        assert!(hypotheses[0].pose.distance_to(&truth) < 1e-9);
        assert!(hypotheses[0].weight > 0.85, "{}", hypotheses[0].weight);
        assert_eq!(report.names().as_deref(), Some("belief+own_half+floor"));
        assert_eq!(report.before, [0.5, 0.5]);
        assert_eq!(report.applied[0].factors[0], 1.0, "factors in the order of the sorted hypotheses");
        assert!(report.applied[0].factors[1] < 1e-6);
        assert!(report.applied[1].factors[0] < report.applied[1].factors[1], "own half disagrees");
    }

    #[test]
    fn a_flipped_belief_leaves_the_right_twin_its_floor() {
        let truth = pose(-1.0, 2.0, -45.0);
        let mut hypotheses = twins(truth, 0.5);
        let flipped = Symmetry::PointReflection.apply(&truth);
        let belief = BeliefPrior::new(flipped, PoseSigma { x: 0.2, y: 0.2, theta: 0.2 }, 0.0);
        Priors { belief: Some(belief), ..Priors::default() }.apply(&mut hypotheses);
        let right = hypotheses.iter().find(|h| h.pose.distance_to(&truth) < 1e-9).unwrap();
        assert!((right.weight - DEFAULT_MIN_SHARE).abs() < 1e-12, "{}", right.weight);
    }

    #[test]
    fn a_belief_far_from_both_twins_still_prefers_the_nearer() {
        // Lines that locked onto a wrong place: both twins lie many σ from the belief, where the
        // Gaussian itself underflows; the twin on the belief's side must still win.
        let mut hypotheses = twins(pose(1.4, 2.1, -33.0), 0.5);
        let belief = BeliefPrior::new(pose(0.0, 1.6, 57.0), PoseSigma { x: 0.05, y: 0.05, theta: 0.02 }, 0.0);
        Priors { belief: Some(belief), ..Priors::default() }.apply(&mut hypotheses);
        assert!(hypotheses[0].pose.x() > 0.0, "{hypotheses:?}");
        assert!(hypotheses[0].weight > 0.85, "{}", hypotheses[0].weight);
    }

    #[test]
    fn the_floor_never_lifts_what_the_lines_already_cut() {
        let (weights, lifted) = reweight(&[0.98, 0.02], &[1e-9, 1.0], 0.1);
        assert!((weights[0] - 0.1).abs() < 1e-12 && (weights[1] - 0.9).abs() < 1e-12, "{weights:?}");
        assert!(lifted.is_some());
        let (weights, lifted) = reweight(&[0.98, 0.02], &[1.0, 1e-9], 0.1);
        assert!((weights[1] - 0.02).abs() < 1e-12, "one the lines cut keeps what it had: {weights:?}");
        assert!(lifted.is_some());
        let (weights, lifted) = reweight(&[0.5, 0.5], &[1.0, 0.5], 0.1);
        assert!((weights[0] - 2.0 / 3.0).abs() < 1e-12 && lifted.is_none(), "above the floor: {weights:?}");
    }

    proptest! {
        #[test]
        fn weights_sum_to_one_the_floor_holds_and_no_pose_moves(
            raw in prop::collection::vec(0.001f64..1.0, 1..5),
            likelihood in prop::collection::vec(0.0f64..1.0, 5),
            min_share in 0.0f64..0.5,
            x in -4.5f64..4.5, y in -3.0f64..3.0, theta in -3.1f64..3.1,
        ) {
            let total: f64 = raw.iter().sum();
            let before: Vec<f64> = raw.iter().map(|w| w / total).collect();
            let (after, _) = reweight(&before, &likelihood[..before.len()], min_share);
            prop_assert!((after.iter().sum::<f64>() - 1.0).abs() < 1e-9);
            for (w, b) in after.iter().zip(&before) {
                prop_assert!(*w >= b.min(min_share) - 1e-9, "{after:?} from {before:?}");
            }

            let mut hypotheses = twins(FieldPose::new(x, y, theta).unwrap(), before[0].min(0.999));
            let poses: Vec<(FieldPose, PoseSigma)> = hypotheses.iter().map(|h| (h.pose, h.sigma)).collect();
            let belief = BeliefPrior::new(FieldPose::new(-x, y, 0.0).unwrap(), PoseSigma { x: 0.3, y: 0.3, theta: 0.3 }, 1.0);
            let priors = Priors { belief: Some(belief), own_half: Some(OwnHalfPrior::default()), min_share, ..Priors::default() };
            let report = priors.apply(&mut hypotheses);
            prop_assert!((hypotheses.iter().map(|h| h.weight).sum::<f64>() - 1.0).abs() < 1e-9);
            for h in &hypotheses {
                prop_assert!(poses.contains(&(h.pose, h.sigma)), "a pose or σ moved");
            }
            for (h, b) in hypotheses.iter().zip(&report.before) {
                prop_assert!(h.weight >= b.min(min_share) - 1e-9);
            }
        }
    }
}
