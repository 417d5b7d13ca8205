//! The metrics themselves: pure functions over (truth, prediction) pairs.

use serde::Serialize;

use super::TruthMetrics;
use crate::geometry::angle::angle_distance;
use crate::geometry::{FieldPose, FoldClass, Representation, Symmetry};
use crate::pipeline::Hypothesis;
use crate::refine::LineCheck;
use crate::relocaliser::Prediction;

/// One evaluated frame: the truth and what the model said.
#[derive(Clone, Debug)]
pub struct Sample {
    /// The robot's true ground pose.
    pub truth: FieldPose,
    /// The camera's head yaw for this frame, radians.
    pub head_yaw: f64,
    /// The decoded prediction.
    pub prediction: Prediction,
}

/// The errors of one frame, in the three forms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evaluation {
    /// The robot's true pose.
    pub truth: FieldPose,
    /// The hypothesis closest to the truth.
    pub closest: FieldPose,
    /// Folded prediction vs folded truth: (metres, degrees).
    pub oracle: (f64, f64),
    /// Heaviest hypothesis vs truth.
    pub modelled: (f64, f64),
    /// Closest hypothesis vs truth.
    pub best_of_set: (f64, f64),
    /// Mean over fold bits of |probability − true bit|.
    pub fold_error: Option<f64>,
    /// Distance of the true (folded) pose from the representation's fold boundary, metres.
    pub distance_to_cut: Option<f64>,
    /// The frame's predicted position standard deviation (lower is more confident).
    pub position_sigma: f64,
}

impl Sample {
    /// Scores this frame.
    pub fn evaluate(&self) -> Evaluation {
        let representation = self.prediction.folded.representation();
        // The network predicts the camera's ground pose; fold the truth the same way.
        let camera_truth =
            FieldPose::new(self.truth.x(), self.truth.y(), self.truth.heading() + self.head_yaw)
                .expect("finite truth");
        let (folded_truth, class) = representation.fold(&camera_truth);
        let folded = &self.prediction.folded;
        let oracle = (
            (folded.x() - folded_truth.x()).hypot(folded.y() - folded_truth.y()),
            angle_distance(folded.heading(), folded_truth.heading()).to_degrees(),
        );
        let hypotheses = self.prediction.hypotheses();
        let modelled = pose_error(&hypotheses[0].pose, &self.truth);
        let closest = hypotheses
            .iter()
            .min_by(|a, b| a.pose.distance_to(&self.truth).total_cmp(&b.pose.distance_to(&self.truth)))
            .expect("at least one hypothesis");
        let best_of_set = pose_error(&closest.pose, &self.truth);
        let bits = representation.fold_bits();
        let fold_error = (bits > 0).then(|| {
            let FoldClass(class_bits) = class;
            self.prediction
                .fold_probabilities
                .iter()
                .enumerate()
                .map(|(index, p)| (p - f64::from((class_bits >> index) & 1)).abs())
                .sum::<f64>()
                / bits as f64
        });
        let distance_to_cut = match representation {
            Representation::Full => None,
            Representation::HalfPoint => Some(folded_truth.x().abs()),
            Representation::HalfLine => Some(folded_truth.y().abs()),
            Representation::Quarter => Some(folded_truth.x().abs().min(folded_truth.y().abs())),
        };
        Evaluation {
            truth: self.truth,
            closest: closest.pose,
            oracle,
            modelled,
            best_of_set,
            fold_error,
            distance_to_cut,
            position_sigma: self.prediction.position_sigma,
        }
    }
}

/// Location (metres) and heading (degrees) error of `pose` against `truth`.
pub(super) fn pose_error(pose: &FieldPose, truth: &FieldPose) -> (f64, f64) {
    (pose.distance_to(truth), angle_distance(pose.heading(), truth.heading()).to_degrees())
}

/// One evaluated burst: the fused hypotheses against the true pose of the standing robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BurstEvaluation {
    /// Heaviest fused hypothesis vs truth: (metres, degrees).
    pub modelled: (f64, f64),
    /// Closest fused hypothesis vs truth.
    pub best_of_set: (f64, f64),
    /// The heaviest hypothesis' position spread, √(σx² + σy²) (lower is more confident).
    pub position_sigma: f64,
}

impl BurstEvaluation {
    /// Scores a burst's hypotheses (heaviest first, at least one) against the robot's true pose.
    pub fn new(truth: &FieldPose, hypotheses: &[Hypothesis]) -> Self {
        let errors: Vec<(f64, f64)> =
            hypotheses.iter().map(|hypothesis| pose_error(&hypothesis.pose, truth)).collect();
        let heaviest = &hypotheses[0];
        Self {
            modelled: errors[0],
            best_of_set: *errors.iter().min_by(|a, b| a.0.total_cmp(&b.0)).expect("at least one hypothesis"),
            position_sigma: heaviest.sigma.x.hypot(heaviest.sigma.y),
        }
    }
}

/// A hypothesis this close to the truth (metres, degrees) counts as found.
pub const FOUND: (f64, f64) = (0.05, 1.0);
/// Fewest line points for a burst to count as one the lines can settle (the refinement's own minimum).
pub const LINE_POINTS: usize = 12;

/// A hypothesis's σ is honest about a truth within this many of them.
pub const SPREADS: f64 = 3.0;

/// Whether `truth` lies within [`SPREADS`] σ of `hypothesis` along x, y and heading.
fn within_spread(hypothesis: &Hypothesis, truth: &FieldPose) -> bool {
    let sigma = &hypothesis.sigma;
    (hypothesis.pose.x() - truth.x()).abs() <= SPREADS * sigma.x
        && (hypothesis.pose.y() - truth.y()).abs() <= SPREADS * sigma.y
        && angle_distance(hypothesis.pose.heading(), truth.heading()) <= SPREADS * sigma.theta
}

/// One burst after line refinement: its errors and what the lines did to its heaviest hypothesis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefinedEvaluation {
    /// The refined hypotheses against the truth (`None`: there were none).
    pub errors: Option<BurstEvaluation>,
    /// What the lines did to the heaviest hypothesis (`None` if it was never checked).
    pub check: Option<LineCheck>,
    /// Line points the burst had.
    pub points: usize,
    /// Whether some hypothesis lies within [`FOUND`] of the truth.
    pub found: bool,
    /// Whether the heaviest hypothesis lies within [`FOUND`] of the truth or of its point twin.
    pub heaviest_right: bool,
    /// Whether some hypothesis holds the truth or its point twin within [`SPREADS`] of its σ in x, y
    /// and heading (the σ the hypotheses claim is honest).
    pub within_spread: bool,
}

impl RefinedEvaluation {
    /// A burst with no hypothesis at all (no network, and no place fits its `points` line points).
    pub fn nothing(points: usize) -> Self {
        Self { errors: None, check: None, points, found: false, heaviest_right: false, within_spread: false }
    }

    /// Scores a refined burst's hypotheses (heaviest first, at least one) against the robot's true pose.
    pub fn new(truth: &FieldPose, hypotheses: &[Hypothesis]) -> Self {
        let close = |pose: &FieldPose, truth: &FieldPose| {
            let (metres, degrees) = pose_error(pose, truth);
            metres <= FOUND.0 && degrees <= FOUND.1
        };
        let twin = Symmetry::PointReflection.apply(truth);
        let heaviest = &hypotheses[0];
        Self {
            errors: Some(BurstEvaluation::new(truth, hypotheses)),
            check: heaviest.lines.map(|lines| lines.check),
            points: heaviest.lines.map_or(0, |lines| lines.points),
            found: hypotheses.iter().any(|h| close(&h.pose, truth)),
            heaviest_right: close(&heaviest.pose, truth) || close(&heaviest.pose, &twin),
            within_spread: hypotheses.iter().any(|h| within_spread(h, truth) || within_spread(h, &twin)),
        }
    }
}

/// Errors after line refinement, over all bursts (frames when not fused) and over those the lines fixed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RefinedMetrics {
    /// Bursts (or frames) evaluated.
    pub bursts: usize,
    /// Share whose heaviest hypothesis the lines fixed fully (`refined`).
    pub refined_share: f64,
    /// Share fitted along one line family only (`partial`).
    pub partial_share: f64,
    /// Share with too few line points (`unrefined`).
    pub unrefined_share: f64,
    /// Share whose heaviest hypothesis the lines contradicted.
    pub contradicted_share: f64,
    /// Share whose heaviest hypothesis is one of several places the lines fit (`ambiguous`).
    pub ambiguous_share: f64,
    /// Bursts with at least [`LINE_POINTS`] line points.
    pub with_lines: usize,
    /// Of those, the share with a hypothesis within 5 cm and 1° of the truth.
    pub found_share_with_lines: f64,
    /// Bursts whose heaviest hypothesis is `refined` but neither the truth nor its point twin lies
    /// within 5 cm and 1° of it, as a share of the `refined` bursts.
    pub wrong_refined_share: f64,
    /// Of the bursts with at least [`LINE_POINTS`] line points, the share where no hypothesis holds
    /// the truth (or its twin) within 3 σ: all of them, and by the heaviest hypothesis's verdict.
    pub beyond_spread: BeyondSpread,
    /// Heaviest hypothesis vs truth, all bursts.
    pub modelled: ErrorStats,
    /// Closest hypothesis vs truth, all bursts.
    pub best_of_set: ErrorStats,
    /// Closest hypothesis vs truth where the lines fixed the pose.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub where_refined: Option<ErrorStats>,
    /// The lines at the true pose (`replay --check-truth`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_truth: Option<TruthMetrics>,
}

/// Shares of bursts with lines whose hypotheses' σ all miss the truth (see
/// [`RefinedMetrics::beyond_spread`]); a share is 0 where no burst had that verdict.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BeyondSpread {
    /// All bursts with lines.
    pub with_lines: f64,
    /// Those whose heaviest hypothesis is `refined`.
    pub refined: f64,
    /// Those whose heaviest hypothesis is `partial`.
    pub partial: f64,
    /// Those whose heaviest hypothesis is `ambiguous`.
    pub ambiguous: f64,
}

impl BeyondSpread {
    fn of(evaluations: &[RefinedEvaluation]) -> Self {
        let with_lines: Vec<&RefinedEvaluation> =
            evaluations.iter().filter(|e| e.points >= LINE_POINTS).collect();
        let share = |verdict: Option<LineCheck>| {
            let chosen: Vec<&&RefinedEvaluation> =
                with_lines.iter().filter(|e| verdict.is_none() || e.check == verdict).collect();
            let beyond = chosen.iter().filter(|e| !e.within_spread).count();
            if chosen.is_empty() { 0.0 } else { beyond as f64 / chosen.len() as f64 }
        };
        Self {
            with_lines: share(None),
            refined: share(Some(LineCheck::Refined)),
            partial: share(Some(LineCheck::Partial)),
            ambiguous: share(Some(LineCheck::Ambiguous)),
        }
    }
}

impl RefinedMetrics {
    /// Summarises refined evaluations; `None` if there are none.
    pub fn summarise(evaluations: &[RefinedEvaluation]) -> Option<Self> {
        if evaluations.is_empty() {
            return None;
        }
        let share = |check: LineCheck| {
            evaluations.iter().filter(|e| e.check == Some(check)).count() as f64 / evaluations.len() as f64
        };
        let with_lines = evaluations.iter().filter(|e| e.points >= LINE_POINTS).count();
        let ratio = |count: usize, of: usize| if of == 0 { 0.0 } else { count as f64 / of as f64 };
        let refined: Vec<(f64, f64)> = evaluations
            .iter()
            .filter(|e| e.check == Some(LineCheck::Refined))
            .filter_map(|e| e.errors.map(|errors| errors.best_of_set))
            .collect();
        let errors: Vec<&BurstEvaluation> = evaluations.iter().filter_map(|e| e.errors.as_ref()).collect();
        Some(Self {
            bursts: evaluations.len(),
            refined_share: share(LineCheck::Refined),
            partial_share: share(LineCheck::Partial),
            unrefined_share: share(LineCheck::Unrefined),
            contradicted_share: share(LineCheck::Contradicted),
            ambiguous_share: share(LineCheck::Ambiguous),
            with_lines,
            found_share_with_lines: ratio(
                evaluations.iter().filter(|e| e.points >= LINE_POINTS && e.found).count(),
                with_lines,
            ),
            wrong_refined_share: ratio(
                evaluations
                    .iter()
                    .filter(|e| e.check == Some(LineCheck::Refined) && !e.heaviest_right)
                    .count(),
                refined.len(),
            ),
            beyond_spread: BeyondSpread::of(evaluations),
            modelled: ErrorStats::of(&errors.iter().map(|e| e.modelled).collect::<Vec<_>>(), &[]),
            best_of_set: ErrorStats::of(&errors.iter().map(|e| e.best_of_set).collect::<Vec<_>>(), &[]),
            where_refined: (!refined.is_empty()).then(|| ErrorStats::of(&refined, &[])),
            at_truth: None,
        })
    }
}

/// Errors of fused bursts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BurstMetrics {
    /// Bursts evaluated.
    pub bursts: usize,
    /// Heaviest fused hypothesis vs truth.
    pub modelled: ErrorStats,
    /// Closest fused hypothesis vs truth.
    pub best_of_set: ErrorStats,
    /// Best-of-set errors over the 50%, 80% and 100% most confident bursts.
    pub coverage: Vec<Coverage>,
}

impl BurstMetrics {
    /// Summarises burst evaluations; `None` if there are none.
    pub fn summarise(evaluations: &[BurstEvaluation]) -> Option<Self> {
        if evaluations.is_empty() {
            return None;
        }
        let column =
            |pick: fn(&BurstEvaluation) -> (f64, f64)| evaluations.iter().map(pick).collect::<Vec<_>>();
        let mut by_confidence: Vec<(f64, (f64, f64))> =
            evaluations.iter().map(|e| (e.position_sigma, e.best_of_set)).collect();
        by_confidence.sort_by(|a, b| a.0.total_cmp(&b.0));
        let errors: Vec<(f64, f64)> = by_confidence.iter().map(|(_, error)| *error).collect();
        Some(Self {
            bursts: evaluations.len(),
            modelled: ErrorStats::of(&column(|e| e.modelled), &[]),
            best_of_set: ErrorStats::of(&column(|e| e.best_of_set), &[]),
            coverage: Coverage::of(&errors),
        })
    }
}

/// Mean and median location (m) and heading (°) errors, and the mean fold error where there is one.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Frames counted.
    pub frames: usize,
    /// Mean location error, metres.
    pub location_mean_m: f64,
    /// Median location error, metres.
    pub location_median_m: f64,
    /// Mean heading error, degrees.
    pub heading_mean_deg: f64,
    /// Median heading error, degrees.
    pub heading_median_deg: f64,
    /// Mean |fold probability − true bit|; 0.5 is guessing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fold_error_mean: Option<f64>,
}

impl ErrorStats {
    fn of(errors: &[(f64, f64)], fold_errors: &[f64]) -> Self {
        let locations: Vec<f64> = errors.iter().map(|e| e.0).collect();
        let headings: Vec<f64> = errors.iter().map(|e| e.1).collect();
        Self {
            frames: errors.len(),
            location_mean_m: mean(&locations),
            location_median_m: median(&locations),
            heading_mean_deg: mean(&headings),
            heading_median_deg: median(&headings),
            fold_error_mean: (!fold_errors.is_empty()).then(|| mean(fold_errors)),
        }
    }
}

/// Median errors over the most confident share of frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Coverage {
    /// Share of frames kept, most confident first.
    pub fraction: f64,
    /// Best-of-set errors over those frames.
    pub best_of_set: ErrorStats,
}

impl Coverage {
    /// Coverage at 50%, 80% and 100% of best-of-set errors sorted most confident first.
    fn of(most_confident_first: &[(f64, f64)]) -> Vec<Self> {
        [0.5, 0.8, 1.0]
            .into_iter()
            .map(|fraction| {
                let kept = ((most_confident_first.len() as f64 * fraction).ceil() as usize).max(1);
                Coverage { fraction, best_of_set: ErrorStats::of(&most_confident_first[..kept], &[]) }
            })
            .collect()
    }
}

/// Errors for frames whose true pose lies within a band of distances from the fold boundary.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CutBand {
    /// Band start, metres from the boundary.
    pub from_m: f64,
    /// Band end, metres (infinite for the last band).
    pub to_m: f64,
    /// Oracle errors within the band.
    pub oracle: ErrorStats,
}

/// A whole evaluation, as written by `--metrics-json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metrics {
    /// Frames evaluated.
    pub frames: usize,
    /// Folded prediction vs folded truth.
    pub oracle: ErrorStats,
    /// Heaviest hypothesis vs truth.
    pub modelled: ErrorStats,
    /// Closest hypothesis vs truth.
    pub best_of_set: ErrorStats,
    /// Oracle errors by distance of the truth from the fold boundary.
    pub by_distance_to_cut: Vec<CutBand>,
    /// Best-of-set errors over the 50%, 80% and 100% most confident frames.
    pub coverage: Vec<Coverage>,
    /// Fused bursts, when the replay fused them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bursts: Option<BurstMetrics>,
    /// After line refinement, when the replay refined.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refined: Option<RefinedMetrics>,
    /// Which twin the bursts' heaviest hypotheses chose, when the replay applied priors.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub twins: Option<super::TwinMetrics>,
}

/// Distance bands from the fold boundary, metres.
const CUT_BANDS: [(f64, f64); 4] = [(0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, f64::INFINITY)];

impl Metrics {
    /// Summarises per-frame and per-burst evaluations; `None` if there are no frames.
    pub fn summarise(
        evaluations: &[Evaluation],
        bursts: &[BurstEvaluation],
        refined: &[RefinedEvaluation],
    ) -> Option<Self> {
        if evaluations.is_empty() {
            return None;
        }
        let fold_errors: Vec<f64> = evaluations.iter().filter_map(|e| e.fold_error).collect();
        let column = |pick: fn(&Evaluation) -> (f64, f64), subset: &[&Evaluation]| {
            subset.iter().map(|e| pick(e)).collect::<Vec<_>>()
        };
        let all: Vec<&Evaluation> = evaluations.iter().collect();
        let by_distance_to_cut = CUT_BANDS
            .iter()
            .filter_map(|&(from, to)| {
                let band: Vec<&Evaluation> = evaluations
                    .iter()
                    .filter(|e| e.distance_to_cut.is_some_and(|d| d >= from && d < to))
                    .collect();
                (!band.is_empty()).then(|| CutBand {
                    from_m: from,
                    to_m: to,
                    oracle: ErrorStats::of(&column(|e| e.oracle, &band), &[]),
                })
            })
            .collect();
        let mut by_confidence = all.clone();
        by_confidence.sort_by(|a, b| a.position_sigma.total_cmp(&b.position_sigma));
        let coverage = Coverage::of(&column(|e| e.best_of_set, &by_confidence));
        Some(Self {
            frames: evaluations.len(),
            oracle: ErrorStats::of(&column(|e| e.oracle, &all), &fold_errors),
            modelled: ErrorStats::of(&column(|e| e.modelled, &all), &fold_errors),
            best_of_set: ErrorStats::of(&column(|e| e.best_of_set, &all), &[]),
            by_distance_to_cut,
            coverage,
            bursts: BurstMetrics::summarise(bursts),
            refined: RefinedMetrics::summarise(refined),
            twins: None,
        })
    }

    /// The thesis-style table, for people.
    pub fn table(&self) -> String {
        let row = |name: &str, stats: &ErrorStats| {
            format!(
                "{:<12} {:>8.1}cm {:>8.1}cm {:>9.2}° {:>9.2}° {:>8}\n",
                name,
                100.0 * stats.location_mean_m,
                100.0 * stats.location_median_m,
                stats.heading_mean_deg,
                stats.heading_median_deg,
                stats.fold_error_mean.map_or("-".to_string(), |e| format!("{e:.3}")),
            )
        };
        let mut text = format!(
            "{:<12} {:>10} {:>10} {:>10} {:>10} {:>8}\n",
            "form", "loc mean", "loc med", "head mean", "head med", "fold"
        );
        text += &row("oracle", &self.oracle);
        text += &row("modelled", &self.modelled);
        text += &row("best-of-set", &self.best_of_set);
        let mut counts = format!("{} frames", self.frames);
        if let Some(bursts) = &self.bursts {
            text += &row("burst model", &bursts.modelled);
            text += &row("burst best", &bursts.best_of_set);
            counts += &format!(", {} bursts", bursts.bursts);
        }
        if let Some(refined) = &self.refined {
            text += &row("lines model", &refined.modelled);
            text += &row("lines best", &refined.best_of_set);
            if let Some(where_refined) = &refined.where_refined {
                text += &row("  refined", where_refined);
            }
            counts += &format!(", lines: {}", refined.verdicts());
            if let Some(at_truth) = &refined.at_truth {
                counts += &format!("\n{}", at_truth.line());
            }
        }
        if let Some(twins) = &self.twins {
            counts += &format!("\n{}", twins.line());
        }
        text + &counts
    }
}

impl RefinedMetrics {
    /// The verdict shares and what the lines found, in one line for people.
    pub fn verdicts(&self) -> String {
        format!(
            "{:.0}% refined, {:.0}% partial, {:.0}% ambiguous, {:.0}% unrefined, {:.0}% contradicted; \
             with >= {LINE_POINTS} line points ({}): {:.1}% found within 5 cm / 1°; {:.1}% of refined wrong; \
             the truth beyond 3 σ of every hypothesis: {:.1}% (refined {:.1}%, partial {:.1}%, ambiguous {:.1}%)",
            100.0 * self.refined_share,
            100.0 * self.partial_share,
            100.0 * self.ambiguous_share,
            100.0 * self.unrefined_share,
            100.0 * self.contradicted_share,
            self.with_lines,
            100.0 * self.found_share_with_lines,
            100.0 * self.wrong_refined_share,
            100.0 * self.beyond_spread.with_lines,
            100.0 * self.beyond_spread.refined,
            100.0 * self.beyond_spread.partial,
            100.0 * self.beyond_spread.ambiguous,
        )
    }
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len().max(1) as f64
}

/// The median; for an even count, the mean of the two middle values (NaN if empty).
pub(crate) fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let middle = sorted.len() / 2;
    if sorted.len() % 2 == 0 { (sorted[middle - 1] + sorted[middle]) / 2.0 } else { sorted[middle] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Symmetry;
    use crate::relocaliser::RawOutput;

    fn sample(truth: FieldPose, predicted: FieldPose, probability: f32, sigma: f32) -> Sample {
        let (folded, _) = Representation::HalfPoint.fold(&predicted);
        let raw = RawOutput {
            position: [folded.x() as f32, folded.y() as f32],
            heading: [folded.heading().cos() as f32, folded.heading().sin() as f32],
            fold_probabilities: vec![probability],
            position_sigma: sigma,
            heading_kappa: 400.0,
        };
        Sample {
            truth,
            head_yaw: 0.0,
            prediction: Prediction::decode(&raw, Representation::HalfPoint, 0.0).unwrap(),
        }
    }

    #[test]
    fn a_confident_wrong_half_costs_modelled_but_not_best_of_set() {
        let truth = FieldPose::new(2.0, 1.0, 0.5).unwrap();
        let near = FieldPose::new(2.1, 1.0, 0.5).unwrap();
        // Truth is in the opponent half (bit 1), the model is sure of bit 0.
        let evaluation = sample(truth, near, 0.0, 0.2).evaluate();
        assert!((evaluation.oracle.0 - 0.1).abs() < 1e-6);
        assert!((evaluation.best_of_set.0 - 0.1).abs() < 1e-6);
        let twin = Symmetry::PointReflection.apply(&near);
        assert!((evaluation.modelled.0 - twin.distance_to(&truth)).abs() < 1e-6);
        assert!((evaluation.modelled.1 - 180.0).abs() < 1e-3);
        assert_eq!(evaluation.fold_error, Some(1.0));
        assert_eq!(evaluation.distance_to_cut, Some(2.0));
    }

    #[test]
    fn summary_reports_medians_bands_and_coverage() {
        let truth = FieldPose::new(-1.0, 0.0, 0.0).unwrap();
        let evaluations: Vec<Evaluation> = [0.1, 0.2, 0.3, 1.0]
            .iter()
            .enumerate()
            .map(|(i, offset)| {
                let predicted = FieldPose::new(-1.0, *offset, 0.0).unwrap();
                sample(truth, predicted, 0.5, (i + 1) as f32).evaluate()
            })
            .collect();
        let metrics = Metrics::summarise(&evaluations, &[], &[]).unwrap();
        assert_eq!(metrics.frames, 4);
        assert!((metrics.oracle.location_median_m - 0.25).abs() < 1e-6);
        assert!((metrics.oracle.location_mean_m - 0.4).abs() < 1e-6);
        assert_eq!(metrics.oracle.fold_error_mean, Some(0.5));
        assert_eq!(metrics.by_distance_to_cut.len(), 1);
        assert_eq!(metrics.by_distance_to_cut[0].from_m, 1.0);
        assert_eq!(metrics.coverage[0].best_of_set.frames, 2);
        assert!((metrics.coverage[0].best_of_set.location_median_m - 0.15).abs() < 1e-6);
        assert!(Metrics::summarise(&[], &[], &[]).is_none());
        assert!(metrics.bursts.is_none());
        assert!(metrics.table().contains("oracle"));
    }

    #[test]
    fn a_truth_beyond_three_sigma_of_every_hypothesis_is_counted_by_verdict() {
        use crate::geometry::PoseSigma;
        use crate::refine::LineEvidence;
        let truth = FieldPose::new(1.0, 2.0, 0.0).unwrap();
        let hypothesis = |x: f64, sigma_x: f64, check: LineCheck| Hypothesis {
            pose: FieldPose::new(x, 2.0, 0.0).unwrap(),
            weight: 1.0,
            sigma: PoseSigma { x: sigma_x, y: 0.02, theta: 0.01 },
            lines: Some(LineEvidence {
                check,
                points: 40,
                inlier_share: 1.0,
                unseen_share: None,
                places: None,
            }),
        };
        // Along x, 1 m off: honest with σ 0.5 m, not with 0.2 m; the truth's twin counts too.
        let honest = RefinedEvaluation::new(&truth, &[hypothesis(2.0, 0.5, LineCheck::Ambiguous)]);
        let overconfident = RefinedEvaluation::new(&truth, &[hypothesis(2.0, 0.2, LineCheck::Ambiguous)]);
        let twin = Symmetry::PointReflection.apply(&truth);
        let at_twin = Hypothesis { pose: twin, ..hypothesis(0.0, 0.01, LineCheck::Refined) };
        let refined = RefinedEvaluation::new(&truth, &[at_twin]);
        assert!(honest.within_spread && !overconfident.within_spread && refined.within_spread);
        let beyond = BeyondSpread::of(&[honest, overconfident, refined, RefinedEvaluation::nothing(5)]);
        assert_eq!(
            beyond,
            BeyondSpread { with_lines: 1.0 / 3.0, refined: 0.0, partial: 0.0, ambiguous: 0.5 }
        );
    }
}
